"""Parameters every model shares (camera, map cell size, prior) and the per-ray quantities they derive."""

from dataclasses import dataclass

import numpy as np

from prismap._depth import depth_from_disparity
from prismap._validate import check_positive, check_probability
from prismap.errors import PrismapInputError
from prismap.sensor_models._base import InverseSensorModel, check_cell_arrays


@dataclass(frozen=True, kw_only=True)
class RayModel(InverseSensorModel):
    """Shared configuration of every model in this package.

    Parameters
    ----------
    focal_baseline : float, pixel-metres, or None
        ``f * b``: depth = focal_baseline / (disparity + doffs). Needed for disparities; a model of ranges
        takes none.
    doffs_px : float, pixels
        Disparity offset (Middlebury 2014); 0 for most rigs.
    measurement : {"disparity", "range"}, default "disparity"
        What the model's rays measure: a disparity (pixels), or a range (metres along the ray, from a LiDAR;
        only the models whose class lists it in :attr:`MEASUREMENTS`, those without disparity noise).
    voxel_size_m : float, metres
        The map's cell size (sets defaults such as the ideal model's alpha and PRISM's surface rate).
    p0 : float in (0, 1)
        Prior occupancy of a map cell: the environment's occupancy ratio (SENSOR_MODELS.md section 5).
    """

    MEASUREMENTS = ("disparity",)
    """The values of ``measurement`` this class takes."""

    focal_baseline: float | None = None
    doffs_px: float = 0.0
    voxel_size_m: float = 0.1
    p0: float = 0.05
    measurement: str = "disparity"

    def __post_init__(self):
        if self.measurement not in self.MEASUREMENTS:
            raise PrismapInputError(
                f"{self.name}: `measurement` must be one of {list(self.MEASUREMENTS)}; got {self.measurement!r}"
            )
        if self.measurement == "disparity" or self.focal_baseline is not None:
            object.__setattr__(self, "focal_baseline", check_positive(self.focal_baseline, "focal_baseline"))
        doffs = float(self.doffs_px)
        if not np.isfinite(doffs):
            raise PrismapInputError(f"`doffs_px` must be finite; got {self.doffs_px!r}")
        object.__setattr__(self, "doffs_px", doffs)
        object.__setattr__(self, "voxel_size_m", check_positive(self.voxel_size_m, "voxel_size_m"))
        object.__setattr__(self, "p0", check_probability(self.p0, "p0"))

    def _validated(self, disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m):
        """The arguments of :meth:`cell_posteriors` validated and converted: disparity, norm, rays, start, end."""
        disparity, norm, rays, start, end = check_cell_arrays(
            disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m
        )
        if not np.all(np.isfinite(disparity)):
            raise PrismapInputError(f"{self.name}: `disparity_px` must be finite (drop invalid pixels first)")
        if norm.size and not np.all(norm >= 1.0 - 1e-12):
            raise PrismapInputError(f"{self.name}: `ray_norm` must be >= 1; got minimum {norm.min()!r}")
        return disparity, norm, rays, start, end

    def _prepare(self, disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m):
        """:meth:`_validated` arrays plus the measured depth of each ray (+inf when ``d + doffs <= 0``)."""
        disparity, norm, rays, start, end = self._validated(
            disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m
        )
        return disparity, norm, rays, start, end, self._depth_hat(disparity, norm)

    def _depth_hat(self, measurement, ray_norm):
        """The measured depth of each ray (metres, +inf when ``d + doffs <= 0`` or the range is not > 0)."""
        if self.measurement == "range":
            return np.where(measurement > 0, measurement / ray_norm, np.inf)
        return depth_from_disparity(measurement, self.focal_baseline, self.doffs_px, invalid=np.inf)

    def _sigma_depth(self, depth_hat, sigma_px):
        """First-order depth noise ``z^2 sigma_d / (f b)`` (metres) per ray."""
        return np.maximum(depth_hat**2 * sigma_px / self.focal_baseline, 1e-300)
