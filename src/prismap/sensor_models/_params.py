"""Parameters every model shares (camera, map cell size, prior) and the per-ray quantities they derive."""

from dataclasses import dataclass

import numpy as np

from prismap._validate import check_positive, check_probability
from prismap.errors import PrismapInputError
from prismap.sensor_models._base import InverseSensorModel, check_cell_arrays


@dataclass(frozen=True, kw_only=True)
class RayModel(InverseSensorModel):
    """Shared configuration of every model in this package.

    Parameters
    ----------
    focal_baseline : float, pixel-metres
        ``f * b``: depth = focal_baseline / (disparity + doffs).
    doffs_px : float, pixels
        Disparity offset (Middlebury 2014); 0 for most rigs.
    voxel_size_m : float, metres
        The map's cell size (sets defaults such as the ideal model's alpha and PRISM's surface rate).
    p0 : float in (0, 1)
        Prior occupancy of a map cell: the environment's occupancy ratio (SENSOR_MODELS.md section 5).
    """

    focal_baseline: float
    doffs_px: float = 0.0
    voxel_size_m: float = 0.1
    p0: float = 0.05

    def __post_init__(self):
        object.__setattr__(self, "focal_baseline", check_positive(self.focal_baseline, "focal_baseline"))
        doffs = float(self.doffs_px)
        if not np.isfinite(doffs):
            raise PrismapInputError(f"`doffs_px` must be finite; got {self.doffs_px!r}")
        object.__setattr__(self, "doffs_px", doffs)
        object.__setattr__(self, "voxel_size_m", check_positive(self.voxel_size_m, "voxel_size_m"))
        object.__setattr__(self, "p0", check_probability(self.p0, "p0"))

    def _prepare(self, disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m):
        """Validated arrays plus the measured depth of each ray (+inf when ``d + doffs <= 0``)."""
        disparity, norm, rays, start, end = check_cell_arrays(
            disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m
        )
        if not np.all(np.isfinite(disparity)):
            raise PrismapInputError(f"{self.name}: `disparity_px` must be finite (drop invalid pixels first)")
        if norm.size and not np.all(norm >= 1.0 - 1e-12):
            raise PrismapInputError(f"{self.name}: `ray_norm` must be >= 1; got minimum {norm.min()!r}")
        return disparity, norm, rays, start, end, self._depth_hat(disparity)

    def _depth_hat(self, disparity):
        total = disparity + self.doffs_px
        with np.errstate(divide="ignore"):
            return np.where(total > 0, self.focal_baseline / np.maximum(total, 1e-300), np.inf)

    def _sigma_depth(self, depth_hat, sigma_px):
        """First-order depth noise ``z^2 sigma_d / (f b)`` (metres) per ray."""
        return np.maximum(depth_hat**2 * sigma_px / self.focal_baseline, 1e-300)
