"""A rectified stereo camera: pinhole intrinsics shared by both views, a baseline, a disparity offset."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from prismap._depth import depth_from_disparity, disparity_from_depth
from prismap._validate import as_float_array, check_positive
from prismap.errors import PrismapInputError

#: Focal lengths a camera may have, pixels: beyond them the depth of a pixel cannot be represented.
FOCAL_RANGE_PX = (1e-2, 1e6)
#: Baselines a camera may have, metres.
BASELINE_RANGE_M = (1e-6, 1e4)
#: ``focal_px * baseline_m``, the depth of a 1 px disparity, metres: depths from a sub-millimetre near
#: range to 1000 km at 1 px, so that depths, voxel keys and disparity search ranges stay finite and bounded.
DEPTH_AT_ONE_PIXEL_RANGE_M = (1e-6, 1e6)
#: Largest ``|cx_px|``, ``|cy_px|`` and ``|doffs_px|``, pixels: a hundred times the widest image
#: (``MAX_IMAGE_PIXELS``) takes; beyond it every pixel's ray or depth is degenerate.
MAX_OFFSET_PX = 1e6


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
        object.__setattr__(self, "focal_px", _check_range(self.focal_px, "focal_px", FOCAL_RANGE_PX, "px"))
        object.__setattr__(self, "baseline_m", _check_range(self.baseline_m, "baseline_m", BASELINE_RANGE_M, "m"))
        _check_range(
            self.focal_px * self.baseline_m,
            "focal_px * baseline_m (the depth of a 1 px disparity)",
            DEPTH_AT_ONE_PIXEL_RANGE_M,
            "m",
        )
        for name in ("cx_px", "cy_px", "doffs_px"):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise PrismapInputError(f"`{name}` must be finite; got {value!r}")
            if abs(value) >= MAX_OFFSET_PX:
                raise PrismapInputError(
                    f"`{name}` must lie in (-{MAX_OFFSET_PX:g}, {MAX_OFFSET_PX:g}) px (MAX_OFFSET_PX); got {value:g}"
                )
            object.__setattr__(self, name, value)
        for name in ("width", "height"):
            value = getattr(self, name)
            if value is not None:
                if int(value) != value or value <= 0:
                    raise PrismapInputError(f"`{name}` must be a positive integer; got {value!r}")
                object.__setattr__(self, name, int(value))
        if self.width is not None and self.doffs_px <= -self.width:
            raise PrismapInputError(
                f"`doffs_px` must be > -{self.width} px (minus the image width): no disparity "
                f"of the image gives a positive depth otherwise; got {self.doffs_px:g}"
            )

    @classmethod
    def from_kitti_projections(
        cls, P2: npt.ArrayLike, P3: npt.ArrayLike, *, width: int | None = None, height: int | None = None
    ) -> StereoCamera:
        """The camera of a KITTI rectified pair from its projection matrices (left = ``P2``).

        KITTI writes each rectified camera as ``P_i = K_i [I | t_i]`` relative to camera 0, so
        ``t_i = K_i^-1 P_i[:, 3]`` and the baseline is ``t_2x - t_3x`` (camera 3 lies at +x of
        camera 2). When ``t_z = 0`` this is ``(P2[0, 3] - P3[0, 3]) / f``; KITTI's ``t_z`` of a few
        millimetres shift the baseline by ~1 mm, so the exact form is used. ``P2[0, 3] != 0``
        (camera 2 is not camera 0) cancels in the difference.

        Parameters
        ----------
        P2, P3 : (3, 4) float, pixels / pixel-metres
            Rectified projection matrices of the left and right colour cameras (or any
            left/right pair, e.g. ``P0, P1``).
        width, height : int or None, pixels

        Returns
        -------
        StereoCamera
            ``doffs_px = P3[0, 2] - P2[0, 2]`` (0 for KITTI).
        """
        left = as_float_array(P2, "P2", shape=(3, 4), allow_nan=False)
        right = as_float_array(P3, "P3", shape=(3, 4), allow_nan=False)
        for name, P in (("P2", left), ("P3", right)):
            f = P[0, 0]
            if not (f > 0 and np.isclose(P[1, 1], f, rtol=1e-9) and P[0, 1] == 0 and np.allclose(P[2, :3], [0, 0, 1])):
                raise PrismapInputError(
                    f"`{name}` must be a rectified projection [f 0 cx tx; 0 f cy ty; 0 0 1 tz] with f > 0; "
                    f"got {P.tolist()}"
                )
        if not (np.isclose(left[0, 0], right[0, 0], rtol=1e-9) and np.isclose(left[1, 2], right[1, 2], rtol=1e-9)):
            raise PrismapInputError(
                "`P2` and `P3` must share the focal length and cy of one rectified pair; got "
                f"f = {left[0, 0]} vs {right[0, 0]}, cy = {left[1, 2]} vs {right[1, 2]}"
            )
        t_left = np.linalg.solve(left[:, :3], left[:, 3])
        t_right = np.linalg.solve(right[:, :3], right[:, 3])
        baseline = t_left[0] - t_right[0]
        if baseline <= 0:
            raise PrismapInputError(
                f"`P3` must be the right camera (baseline t2x - t3x > 0); got baseline {baseline:.6g} m"
            )
        return cls(
            focal_px=left[0, 0],
            cx_px=left[0, 2],
            cy_px=left[1, 2],
            baseline_m=baseline,
            doffs_px=right[0, 2] - left[0, 2],
            width=width,
            height=height,
        )

    @classmethod
    def from_middlebury_calib(cls, fields: Mapping[str, Any], *, source: str = "calib") -> StereoCamera:
        """The camera of a Middlebury 2014/2021 pair from its ``calib.txt`` fields.

        Parameters
        ----------
        fields : dict
            ``cam0``, ``cam1`` ((3, 3) intrinsics, pixels), ``doffs`` (pixels), ``baseline``
            (millimetres), ``width``, ``height`` (pixels); other keys are ignored.
        source : str
            Where the fields come from, for error messages.

        Returns
        -------
        StereoCamera
            ``f, cx, cy`` from ``cam0``, baseline in metres, ``doffs`` from the file.
        """
        missing = [key for key in ("cam0", "cam1", "doffs", "baseline", "width", "height") if key not in fields]
        if missing:
            raise PrismapInputError(f"{source}: missing field(s) {missing}; got {sorted(fields)}")
        cam0 = as_float_array(fields["cam0"], f"{source}: cam0", shape=(3, 3), allow_nan=False)
        cam1 = as_float_array(fields["cam1"], f"{source}: cam1", shape=(3, 3), allow_nan=False)
        if not (np.isclose(cam0[0, 0], cam1[0, 0], rtol=1e-6) and np.isclose(cam0[1, 2], cam1[1, 2], rtol=1e-6)):
            raise PrismapInputError(
                f"{source}: cam0 and cam1 must share f and cy (a rectified pair); "
                f"got {cam0.tolist()} and {cam1.tolist()}"
            )
        try:
            return cls(
                focal_px=cam0[0, 0],
                cx_px=cam0[0, 2],
                cy_px=cam0[1, 2],
                baseline_m=float(fields["baseline"]) / 1000.0,
                doffs_px=float(fields["doffs"]),
                width=float(fields["width"]),
                height=float(fields["height"]),
            )
        except (PrismapInputError, TypeError, ValueError) as exc:
            raise PrismapInputError(f"{source}: {exc}") from None

    @property
    def focal_baseline(self) -> float:
        """``f * b`` in pixel-metres: depth (m) = focal_baseline / (disparity + doffs)."""
        return self.focal_px * self.baseline_m

    @property
    def K(self) -> npt.NDArray[np.float64]:
        """(3, 3) float64 intrinsic matrix of the left camera."""
        return np.array([[self.focal_px, 0.0, self.cx_px], [0.0, self.focal_px, self.cy_px], [0.0, 0.0, 1.0]])

    def depth_from_disparity(self, disparity_px: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Depth ``z = f b / (d + doffs)`` (metres); NaN where ``d + doffs <= 0`` or ``d`` is not finite."""
        return depth_from_disparity(disparity_px, self.focal_baseline, self.doffs_px)

    def disparity_from_depth(self, depth_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Disparity ``d = f b / z - doffs`` (pixels); NaN where ``z <= 0`` or not finite."""
        return disparity_from_depth(depth_m, self.focal_baseline, self.doffs_px)

    def project(self, points_cam: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Pixel coordinates ``(u, v) = (f x / z + cx, f y / z + cy)`` of points in the left camera frame.

        The inverse of :meth:`pixel_rays` (pixel centres at integers). ``points_cam`` is ``(..., 3)``
        metres; returns two ``(...)`` float64 arrays, NaN for points not in front of the camera (``z <= 0``).
        """
        points = np.asarray(points_cam, dtype=np.float64)
        x, y, z = points[..., 0], points[..., 1], points[..., 2]
        in_front = z > 0
        safe_z = np.where(in_front, z, 1.0)
        u = np.where(in_front, self.focal_px * x / safe_z + self.cx_px, np.nan)
        v = np.where(in_front, self.focal_px * y / safe_z + self.cy_px, np.nan)
        return u, v

    def pixel_rays(self, shape: tuple[int, int] | None = None) -> npt.NDArray[np.float64]:
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

    def triangulate(self, disparity_px: npt.ArrayLike) -> npt.NDArray[np.float64]:
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


def _check_range(value, name, bounds, unit):
    """``check_positive(value)`` within ``bounds`` (inclusive), else raise naming ``name`` and the bounds."""
    number = check_positive(value, name)
    low, high = bounds
    if not low <= number <= high:
        raise PrismapInputError(
            f"`{name}` must lie in [{low:g}, {high:g}] {unit} (a representable depth range); got {number:g}"
        )
    return number
