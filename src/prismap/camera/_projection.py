"""3-D points into a camera's left image as disparity: sparse with occlusion handling, or fitted at pixel centres.

Points seen from another origin than the camera's (a LiDAR beside it, another frame of the sequence) include
points the camera cannot see: hidden behind a nearer surface. Projected alone, such a point can land on a
pixel no nearer point covers (the scan is sparse), and its disparity there would be wrong. A point is
therefore kept only when no projected point within ``occlusion_window_px`` pixels has a disparity larger than
its own by more than ``disparity_margin_px``: a z-buffer whose cells are the window, not the pixel
(:func:`visible_points`; a LiDAR scan's sparse disparity is :func:`prismap.io.points_to_disparity`).

Disparity on a plane is affine in the pixel coordinates (``camera/_surface.py``), so dense points from
another frame give the disparity at each pixel centre exactly on planar patches by a least-squares affine
fit of the points around it (:func:`fitted_disparity`); rounding each point to its nearest pixel instead
would err by the disparity gradient times up to half a pixel.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.ndimage import maximum_filter

from prismap._validate import as_float_array, check_integer, check_positive
from prismap.camera._stereo_camera import StereoCamera

OCCLUSION_WINDOW_PX = 2
"""Half-width (pixels) of the window in which a nearer point hides a farther one."""

DISPARITY_MARGIN_PX = 1.0
"""Disparity (pixels) by which a point may lie behind the nearest point of its window and still be seen."""

MIN_FIT_POINTS = 4
"""Fewest points around a pixel for its affine fit (three fix the plane; one more checks it)."""


def project_points(
    points_cam: npt.ArrayLike, camera: StereoCamera, shape: tuple[int, int]
) -> tuple[
    npt.NDArray[np.float64],
    npt.NDArray[np.int64],
    npt.NDArray[np.int64],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
]:
    """The points in front of the camera that fall inside an image of ``shape`` (H, W).

    Returns
    -------
    depth : (M,) float64, metres
    row, col : (M,) int64, the nearest pixel (centres at integers)
    u, v : (M,) float64, the exact image coordinates, pixels
    """
    points = as_float_array(points_cam, "points_cam", shape=(None, 3), allow_nan=False)
    height, width = shape
    u, v = camera.project(points)
    col, row = np.floor(u + 0.5), np.floor(v + 0.5)
    inside = np.isfinite(u) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
    return points[inside, 2], row[inside].astype(np.int64), col[inside].astype(np.int64), u[inside], v[inside]


def visible_points(
    disparity: np.ndarray,
    row: np.ndarray,
    col: np.ndarray,
    shape: tuple[int, int],
    *,
    occlusion_window_px: int = OCCLUSION_WINDOW_PX,
    disparity_margin_px: float = DISPARITY_MARGIN_PX,
) -> npt.NDArray[np.bool_]:
    """Which projected points no nearer point within the window hides (module docstring).

    Parameters
    ----------
    disparity : (N,) float, pixels
        The points' disparities in this camera (larger = nearer).
    row, col : (N,) int, the points' nearest pixels inside an image of ``shape``
    shape : (H, W)
    occlusion_window_px : int >= 0
        0 keeps the nearest point of each pixel (a plain z-buffer) and every point within the margin of it.
    disparity_margin_px : float > 0, pixels
        A point is hidden by a point of its window whose disparity exceeds its own by more than this. A
        margin in disparity, not in depth, lets a surface seen at a grazing angle (a road ahead) keep its
        points: its disparity changes by a fraction of a pixel per pixel, its depth by more every pixel
        farther away.

    Returns
    -------
    (N,) bool
    """
    window = check_integer(
        occlusion_window_px, "occlusion_window_px", expected="an integer >= 0", condition=lambda n: n >= 0
    )
    margin = check_positive(disparity_margin_px, "disparity_margin_px")
    buffer = np.full(shape, -np.inf)
    np.maximum.at(buffer, (row, col), disparity)
    if window:
        buffer = maximum_filter(buffer, size=2 * window + 1, mode="constant", cval=-np.inf)
    return disparity >= buffer[row, col] - margin


def fitted_disparity(
    points_cam: npt.ArrayLike,
    camera: StereoCamera,
    shape: tuple[int, int],
    *,
    max_residual_px: float = 0.5,
    occlusion_window_px: int = 0,
    disparity_margin_px: float = DISPARITY_MARGIN_PX,
) -> npt.NDArray[np.float64]:
    """Disparity at each pixel centre from dense 3-D points (another frame's), by a local affine fit.

    The visible points (:func:`visible_points`) whose nearest pixel is the pixel or one of its 8 neighbours are
    fitted by ``d = a + b x + c y`` (``x, y`` their offsets from the pixel centre, pixels; ``d`` their
    exact disparity in this camera); ``a`` is the pixel's disparity. Exact on planes; a pixel whose fit
    leaves a root-mean-square residual above ``max_residual_px`` (points of two surfaces, or noisy points)
    or has fewer than :data:`MIN_FIT_POINTS` points gets none.

    Parameters
    ----------
    points_cam : (N, 3) float, metres, this camera's frame
    camera : StereoCamera
    shape : (H, W)
    max_residual_px : float > 0, pixels
    occlusion_window_px, disparity_margin_px
        See :func:`visible_points`; dense points need no window (a farther surface showing between
        them mixes into fits whose residual rejects them), so the default is the per-pixel test.

    Returns
    -------
    (H, W) float64, pixels, NaN where no fit is accepted.
    """
    max_residual = check_positive(max_residual_px, "max_residual_px")
    height, width = (int(s) for s in shape)
    depth, row, col, u, v = project_points(points_cam, camera, (height, width))
    d = camera.disparity_from_depth(depth)
    keep = visible_points(
        d, row, col, (height, width), occlusion_window_px=occlusion_window_px, disparity_margin_px=disparity_margin_px
    )
    d, row, col, u, v = d[keep], row[keep], col[keep], u[keep], v[keep]
    sums = np.zeros((10, height * width))  # n, x, y, xx, xy, yy, d, dx, dy, dd
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            r, c = row + dy, col + dx
            ok = (r >= 0) & (r < height) & (c >= 0) & (c < width)
            index = r[ok] * width + c[ok]
            x, y, value = u[ok] - c[ok], v[ok] - r[ok], d[ok]
            for k, term in enumerate(
                (np.ones_like(x), x, y, x * x, x * y, y * y, value, value * x, value * y, value * value)
            ):
                sums[k] += np.bincount(index, weights=term, minlength=height * width)
    n, sx, sy, sxx, sxy, syy, sd, sdx, sdy, sdd = sums
    normal = np.stack([np.stack([n, sx, sy], -1), np.stack([sx, sxx, sxy], -1), np.stack([sy, sxy, syy], -1)], -2)
    rhs = np.stack([sd, sdx, sdy], -1)
    det = np.linalg.det(normal)
    ok = (n >= MIN_FIT_POINTS) & (np.abs(det) > 1e-9 * np.maximum(n, 1.0) ** 3)
    out = np.full(height * width, np.nan)
    if ok.any():
        beta = np.linalg.solve(normal[ok], rhs[ok][..., None])[..., 0]
        sse = sdd[ok] - np.einsum("ij,ij->i", beta, rhs[ok])
        rms = np.sqrt(np.maximum(sse, 0.0) / n[ok])
        out[np.flatnonzero(ok)] = np.where(rms <= max_residual, beta[:, 0], np.nan)
    return out.reshape(height, width)
