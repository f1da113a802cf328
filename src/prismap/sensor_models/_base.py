"""The one interface every inverse sensor model (ISM) implements, and the name -> model registry.

A model sees rays, never voxels. A *ray* is one pixel's measurement: its measured disparity ``d^``
(pixels) and its ray norm ``|r| = |((u-cx)/f, (v-cy)/f, 1)|``. The *cells* a ray crosses are given by
their depth interval ``[depth_start_m, depth_end_m]`` along that ray (depth = camera z, metres; the
distance along the ray is ``depth * |r|``) and the index of the ray they belong to. Cells are flat
arrays so a whole frame (hundreds of thousands of rays, millions of cells) is one call.

Every model returns, per cell, the posterior ``P(m = 1 | d^)`` and the log-odds increment the map adds
(SENSOR_MODELS.md section 3): ``logit(P) - logit(prior of that cell)``. A cell the measurement says
nothing about gets increment 0.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array
from prismap.errors import PrismapInputError


class InverseSensorModel(ABC):
    """Base class: ``cell_posteriors`` on flat cell arrays, ``influence_depth`` per ray.

    Subclasses are built from the camera's ``focal_baseline`` (f*b, pixel-metres) and ``doffs_px``,
    the map's voxel size and prior ``p0``, plus their own parameters; the map refuses a model whose
    ``p0`` or ``voxel_size_m`` differ from its own. A model conditioned on a per-ray class accepts the
    keyword ``ray_class`` ((R,) int32, -1 = no class) in :meth:`cell_posteriors` and
    :meth:`influence_depth`; the grid passes it only when the frame has classes, and never to a hit/miss
    model. A model with ``takes_voxel_overhang`` accepts the keyword ``voxel_overhang_m`` ((R,) float64,
    metres along each ray: how far before its surface a voxel can still hold part of it, see
    ``prismap.camera.voxel_overhang_m``) in :meth:`cell_posteriors` and :meth:`influence_depth`. A model with
    ``takes_map_prior`` accepts the keyword ``map_log_odds`` ((C,) float64: each cell's voxel's log-odds in the map
    before this frame) in :meth:`cell_posteriors`; only
    integrators that cast whole rays (ray mode) give it. The grid may call :meth:`cell_posteriors` from
    two threads at once (on different rays), so a model that caches must guard its cache.
    """

    name = "base"
    default_policy = "mean"
    """Name of the per-frame policy the map uses with this model by default (the grid owns the policies)."""
    error_model_use = None
    """What the model takes from a matcher's error model: ``"mixture"`` (the whole Gaussian mixture, as
    ``error_model``), ``"sigma"`` (its dominant sigma, as ``sigma_px``) or None (nothing)."""
    measurement = "disparity"
    """What the first argument of :meth:`cell_posteriors` and :meth:`influence_depth` holds: ``"disparity"``
    (pixels) or ``"range"`` (metres along the ray); the map refuses a batch of another kind."""
    takes_voxel_overhang = False
    """Whether :meth:`cell_posteriors` uses the keyword ``voxel_overhang_m`` (the grid computes it only then)."""
    takes_map_prior = False
    """Whether :meth:`cell_posteriors` needs the keyword ``map_log_odds`` (the grid looks it up only then)."""

    @abstractmethod
    def cell_posteriors(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        ray_of_cell: npt.ArrayLike,
        depth_start_m: npt.ArrayLike,
        depth_end_m: npt.ArrayLike,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Posterior and log-odds increment of every cell.

        Parameters
        ----------
        disparity_px : (R,) float64, pixels, measured disparity of each ray (finite)
        ray_norm : (R,) float64, ``|r|`` of each ray (>= 1)
        ray_of_cell : (C,) int64, index into the ray arrays
        depth_start_m, depth_end_m : (C,) float64, metres, the cell's depth interval on its ray

        Returns
        -------
        posterior : (C,) float64 in [0, 1]
        increment_log : (C,) float64, ``logit(posterior) - logit(cell prior)``
        """

    @abstractmethod
    def influence_depth(self, disparity_px: npt.ArrayLike, ray_norm: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Depth (metres) beyond which the measurement no longer changes a cell, per ray: (R,) float64.

        Ray casting stops there (or at the map's max range, whichever is nearer).
        """

    @abstractmethod
    def with_extra_noise(self, sigma_px: float) -> InverseSensorModel:
        """A copy whose disparity noise is widened by ``N(0, sigma_px^2)`` (robot pose uncertainty)."""

    def hit_miss_increments(self) -> tuple[float, float] | None:
        """``(l_hit, l_miss)`` log-odds if this model is a hit/miss model, else None (the default).

        A hit/miss model gives ``l_miss`` to every cell ending at or before the ray's
        :meth:`influence_depth`, ``l_hit`` to the cell holding it, and nothing beyond. The grid then adds
        these increments while it casts the rays, without calling :meth:`cell_posteriors` (no per-cell
        arrays); every other model returns None.
        """
        return None


def check_cell_arrays(disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m):
    """Validate and convert the arguments of :meth:`InverseSensorModel.cell_posteriors`."""
    disparity = as_float_array(disparity_px, "disparity_px", ndim=1)
    norm = as_float_array(ray_norm, "ray_norm", shape=(disparity.size,))
    start = as_float_array(depth_start_m, "depth_start_m", ndim=1)
    end = as_float_array(depth_end_m, "depth_end_m", shape=(start.size,))
    rays = np.ascontiguousarray(ray_of_cell, dtype=np.int64)
    if rays.shape != start.shape:
        raise PrismapInputError(f"`ray_of_cell` must have shape {start.shape}; got {rays.shape}")
    if rays.size and (rays.min() < 0 or rays.max() >= disparity.size):
        raise PrismapInputError(
            f"`ray_of_cell` must index {disparity.size} rays; got values in [{rays.min()}, {rays.max()}]"
        )
    return disparity, norm, rays, start, end


_REGISTRY = {}

_Model = TypeVar("_Model", bound=type[InverseSensorModel])


def register_model(cls: _Model) -> _Model:
    """Class decorator: make ``cls`` available to :func:`make_sensor_model` under ``cls.name``."""
    _REGISTRY[cls.name] = cls
    return cls


def model_names() -> tuple[str, ...]:
    """Names accepted by :func:`make_sensor_model`, in registration order."""
    return tuple(_REGISTRY)


def model_defaults(name: str) -> dict[str, Any]:
    """The default of every public parameter of the model called ``name`` that is a plain number, string or
    None: what a run without that parameter uses (recorded in run fingerprints, so a changed default is a
    changed run)."""
    try:
        cls = _REGISTRY[name]
    except KeyError:
        raise PrismapInputError(f"unknown sensor model {name!r}; expected one of {list(_REGISTRY)}") from None
    return {
        f.name: f.default
        for f in dataclasses.fields(cls)
        if f.init and not f.name.startswith("_") and isinstance(f.default, (bool, int, float, str, type(None)))
    }


def error_model_use(name: str) -> str | None:
    """What the model called ``name`` takes from an error model (its class's ``error_model_use``)."""
    try:
        return _REGISTRY[name].error_model_use
    except KeyError:
        raise PrismapInputError(f"unknown sensor model {name!r}; expected one of {list(_REGISTRY)}") from None


def make_sensor_model(name: str, **params: Any) -> InverseSensorModel:
    """Build the model called ``name`` (``ideal``, ``hitmiss``, ``convolution``, ``andert``, ``prism``...)."""
    try:
        cls = _REGISTRY[name]
    except KeyError:
        raise PrismapInputError(f"unknown sensor model {name!r}; expected one of {list(_REGISTRY)}") from None
    return cls(**params)
