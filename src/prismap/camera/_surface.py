"""Surface normals from one disparity image, by local plane fits in disparity space.

A plane ``n . P = h`` (camera frame) has the disparity ``d + doffs = (f b / h) n . ((u - cx)/f, (v - cy)/f, 1)``:
affine in the pixel coordinates. So a least-squares fit ``d + doffs = alpha u' + beta v' + gamma`` over a
window (``u' = u - cx``, ``v' = v - cy``) gives the plane's normal without ever forming depths, in the
domain where the stereo noise is uniform (disparity) rather than growing with depth squared. The window
sums are box filters (OpenCV), so a frame costs a few passes over the image.
"""

import cv2
import numpy as np

from prismap.errors import PrismapInputError

PLANE_WINDOW_PX = 7
"""Side of the square window of each plane fit (pixels)."""

MIN_WINDOW_SHARE = 0.5
"""Fewest valid pixels a window may hold for its fit (share of the window); fewer: no normal."""


def plane_normals(disparity_px, camera, *, window_px=PLANE_WINDOW_PX):
    """Unit normal of the surface at each pixel, camera frame, facing the camera.

    Parameters
    ----------
    disparity_px : (H, W) float, pixels, NaN or ``d + doffs <= 0`` = invalid
    camera : StereoCamera
    window_px : odd int >= 3, pixels
        Side of the window of each fit.

    Returns
    -------
    (H, W, 3) float64, camera frame
        ``n`` with ``|n| = 1`` and ``n . r <= 0`` for the pixel's ray ``r``; NaN where the pixel is invalid,
        its window holds fewer than :data:`MIN_WINDOW_SHARE` valid pixels, or their coordinates are
        degenerate (a line of pixels).

    Notes
    -----
    With ``d' = d + doffs`` fitted as ``alpha u' + beta v' + gamma`` and
    ``d' = (f b / h)(n_x u'/f + n_y v'/f + n_z)``, the normal is ``(alpha, beta, (d' - alpha u' - beta v') / f)``
    up to scale, with the pixel's own ``d'``. Across a depth discontinuity the fit mixes two surfaces and the normal leans
    toward grazing, which is what callers that bound the surface's extent want there.
    """
    disparity = np.asarray(disparity_px, dtype=np.float64)
    if disparity.ndim != 2:
        raise PrismapInputError(f"`disparity_px` must be an (H, W) image; got shape {disparity.shape}")
    if isinstance(window_px, bool) or int(window_px) != window_px or window_px < 3 or window_px % 2 == 0:
        raise PrismapInputError(f"`window_px` must be an odd integer >= 3; got {window_px!r}")
    shifted = disparity + camera.doffs_px
    valid = np.isfinite(shifted) & (shifted > 0)
    height, width = disparity.shape
    u = np.broadcast_to(np.arange(width, dtype=np.float64) - camera.cx_px, (height, width))
    v = np.broadcast_to(np.arange(height, dtype=np.float64)[:, None] - camera.cy_px, (height, width))
    weight = valid.astype(np.float64)
    d = np.where(valid, shifted, 0.0)
    size = (int(window_px), int(window_px))

    def window_sum(values):
        return cv2.boxFilter(np.ascontiguousarray(values), -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)

    n = window_sum(weight)
    safe_n = np.maximum(n, 1.0)
    mean_u, mean_v, mean_d = window_sum(u * weight) / safe_n, window_sum(v * weight) / safe_n, window_sum(d) / safe_n
    var_u = window_sum(u * u * weight) / safe_n - mean_u**2
    var_v = window_sum(v * v * weight) / safe_n - mean_v**2
    cov_uv = window_sum(u * v * weight) / safe_n - mean_u * mean_v
    cov_ud = window_sum(u * d) / safe_n - mean_u * mean_d
    cov_vd = window_sum(v * d) / safe_n - mean_v * mean_d
    det = var_u * var_v - cov_uv**2
    fitted = valid & (n >= MIN_WINDOW_SHARE * size[0] * size[1]) & (det > 1e-6)
    det = np.where(fitted, det, 1.0)
    alpha = (var_v * cov_ud - cov_uv * cov_vd) / det
    beta = (var_u * cov_vd - cov_uv * cov_ud) / det
    gamma = (d - alpha * u - beta * v) / camera.focal_px
    normal = np.stack([alpha, beta, gamma], axis=-1)
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    fitted &= length[..., 0] > 0
    normal = normal / np.where(length > 0, length, 1.0)
    normal = -normal  # before the flip n . r = d' / f > 0
    normal[~fitted] = np.nan
    return normal
