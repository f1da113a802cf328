"""One frame's measurements along rays from one origin (:class:`RayBatch`): what the map integrates."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from prismap.grid._floor_sampling import RayLevels
from prismap.grid._projectors import ImageProjection
from prismap.grid._sensor_model import SensorModel

MEASUREMENT_KINDS = ("disparity", "range")
"""What a :class:`RayBatch` measures along each ray: a stereo disparity (pixels) or a range (metres)."""


@dataclass(frozen=True)
class RayBatch:
    """One frame's measurements along rays, all from one origin: what the map integrates.

    The map knows nothing of the sensor that made them: a camera's disparity image becomes a batch on the
    camera side (:func:`prismap.camera.disparity_batch`), a LiDAR scan a batch of ranges.

    Attributes
    ----------
    origin_w : (3,) float64, metres, world frame, the sensor's origin
    rays_w : (R, 3) float64, world frame: the point at ray parameter ``t`` is ``origin_w + t * rays_w``
        (a camera's rays ``(x/z, y/z, 1)`` rotated into the world, so ``t`` is camera depth; unit vectors
        for ranges, so ``t`` is the range)
    measurement : (R,) float64, finite: disparity (pixels) or range (metres), as ``kind`` says
    ray_norm : (R,) float64, ``|rays_w|`` >= 1
    extra_noise_px : (R,) float64, pixels, or None; extra disparity noise per ray (pose uncertainty)
    ray_class : (R,) int32 or None; the error-model class of each ray, -1 = no class
    image : ImageProjection or None; needed by the projective integrator
    voxel_overhang_m : (R,) float64, metres along the ray, or None; how far before its surface a voxel the ray
        crosses can still hold part of that surface (:func:`prismap.camera.voxel_overhang_m`)
    kind : {"disparity", "range"}
        What ``measurement`` holds (:data:`MEASUREMENT_KINDS`); a sensor model takes the kinds it lists in
        its ``measurements``.
    levels : RayLevels or None; the rays' places in the image's nested sampling, which ray mode's floor sampling
        needs (:mod:`prismap.grid._floor_sampling`)
    """

    origin_w: np.ndarray
    rays_w: np.ndarray
    measurement: np.ndarray
    ray_norm: np.ndarray
    extra_noise_px: np.ndarray | None = None
    ray_class: np.ndarray | None = None
    image: ImageProjection | None = None
    voxel_overhang_m: np.ndarray | None = None
    kind: str = "disparity"
    levels: RayLevels | None = None

    def __len__(self):
        return self.measurement.size

    def subset(self, keep: np.ndarray) -> RayBatch:
        """The batch of the rays where ``keep`` ((R,) bool) holds; the image's ray index follows."""
        image = self.image
        if image is not None:
            new = np.full(keep.size, -1, dtype=np.int32)
            new[keep] = np.arange(int(keep.sum()), dtype=np.int32)
            flat = image.ray_index.reshape(-1)
            ray_index = (
                np.where(flat >= 0, new[np.maximum(flat, 0)], -1).astype(np.int32).reshape(image.ray_index.shape)
            )
            image = replace(image, ray_index=ray_index)
        return RayBatch(
            self.origin_w,
            np.ascontiguousarray(self.rays_w[keep]),
            self.measurement[keep],
            self.ray_norm[keep],
            _take(self.extra_noise_px, keep),
            _take(self.ray_class, keep),
            image,
            _take(self.voxel_overhang_m, keep),
            self.kind,
            None if self.levels is None else self.levels.subset(keep),
        )

    def class_kwargs(self, idx: np.ndarray | None, model: SensorModel) -> dict[str, Any]:
        """``{"ray_class": classes of rays idx}`` for a call of ``model``, or ``{}`` when the batch has no
        classes or the model is a hit/miss model (those ignore classes)."""
        if self.ray_class is None or model.hit_miss_increments() is not None:
            return {}
        return {"ray_class": self.ray_class if idx is None else self.ray_class[idx]}

    def cell_kwargs(self, idx: np.ndarray | None, model: SensorModel) -> dict[str, Any]:
        """:meth:`class_kwargs` plus ``{"voxel_overhang_m": ...}`` of rays idx when the batch has overhangs and
        ``model.takes_voxel_overhang``: the keywords of ``model.cell_posteriors``."""
        kwargs = self.class_kwargs(idx, model)
        if self.voxel_overhang_m is not None and model.takes_voxel_overhang:
            kwargs["voxel_overhang_m"] = take_rows(self.voxel_overhang_m, idx)
        return kwargs


def _take(array, idx):
    return None if array is None else array[idx]


def take_rows(array, idx):
    """Rows ``idx`` of ``array``, or all of it when ``idx`` is None (every ray of the batch)."""
    return array if idx is None else array[idx]
