"""A rectified stereo camera: pinhole intrinsics shared by both views, a baseline, a disparity offset."""

from dataclasses import dataclass

import numpy as np

from prismap._validate import as_float_array, check_positive
from prismap.errors import PrismapInputError


@dataclass(frozen=True)
class StereoCamera:
    """Rectified stereo pair, left camera as reference (SENSOR_MODELS.md section 1).

    Parameters
    ----------
    focal_px : float, pixels
    cx_px, cy_px : float, pixels
        Principal point of the left (reference) image.
    baseline_m : float, metres, > 0
    doffs_px : float, pixels
        Disparity offset ``cx_right - cx_left`` (Middlebury 2014); 0 for most rigs.
    width, height : int or None, pixels
        Image size, when known.
    """

    focal_px: float
    cx_px: float
    cy_px: float
    baseline_m: float
    doffs_px: float = 0.0
    width: int | None = None
    height: int | None = None

    def __post_init__(self):
        object.__setattr__(self, "focal_px", check_positive(self.focal_px, "focal_px"))
        object.__setattr__(self, "baseline_m", check_positive(self.baseline_m, "baseline_m"))
        for name in ("cx_px", "cy_px", "doffs_px"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise PrismapInputError(f"`{name}` must be finite; got {value!r}")
            object.__setattr__(self, name, value)
        for name in ("width", "height"):
            value = getattr(self, name)
            if value is not None:
                if int(value) != value or value <= 0:
                    raise PrismapInputError(f"`{name}` must be a positive integer; got {value!r}")
                object.__setattr__(self, name, int(value))

    @property
    def focal_baseline(self):
        """``f * b`` in pixel-metres: depth (m) = focal_baseline / (disparity + doffs)."""
        return self.focal_px * self.baseline_m

    @property
    def K(self):
        """(3, 3) float64 intrinsic matrix of the left camera."""
        return np.array([[self.focal_px, 0.0, self.cx_px], [0.0, self.focal_px, self.cy_px], [0.0, 0.0, 1.0]])

    def depth_from_disparity(self, disparity_px):
        """Depth ``z = f b / (d + doffs)`` (metres); NaN where ``d + doffs <= 0`` or ``d`` is not finite."""
        d = np.asarray(disparity_px, dtype=np.float64) + self.doffs_px
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = self.focal_baseline / d
        return np.where(np.isfinite(d) & (d > 0), depth, np.nan)

    def disparity_from_depth(self, depth_m):
        """Disparity ``d = f b / z - doffs`` (pixels); NaN where ``z <= 0`` or not finite."""
        z = np.asarray(depth_m, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            disparity = self.focal_baseline / z - self.doffs_px
        return np.where(np.isfinite(z) & (z > 0), disparity, np.nan)

    def pixel_rays(self, shape=None):
        """Rays ``((u - cx)/f, (v - cy)/f, 1)`` of every pixel, camera frame: (H, W, 3) float64.

        ``shape`` is ``(H, W)``; it defaults to the camera's own ``(height, width)``.
        """
        height, width = self._shape(shape)
        u = (np.arange(width, dtype=np.float64) - self.cx_px) / self.focal_px
        v = (np.arange(height, dtype=np.float64) - self.cy_px) / self.focal_px
        rays = np.empty((height, width, 3))
        rays[..., 0] = u[None, :]
        rays[..., 1] = v[:, None]
        rays[..., 2] = 1.0
        return rays

    def triangulate(self, disparity_px):
        """3-D points of a whole disparity map (thesis eq. 3.8), left-camera frame, metres.

        Parameters
        ----------
        disparity_px : (H, W) float, pixels, NaN or <= -doffs = invalid

        Returns
        -------
        points_cam : (H, W, 3) float64, metres, camera frame; NaN at invalid pixels.
        """
        disparity = as_float_array(disparity_px, "disparity_px", ndim=2)
        depth = self.depth_from_disparity(disparity)
        return self.pixel_rays(disparity.shape) * depth[..., None]

    def _shape(self, shape):
        if shape is None:
            if self.width is None or self.height is None:
                raise PrismapInputError("the camera has no image size: pass `shape=(H, W)`")
            return self.height, self.width
        height, width = (int(s) for s in shape)
        return height, width
