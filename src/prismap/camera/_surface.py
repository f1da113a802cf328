"""Surface normals from one disparity image, by local plane fits in disparity space.

A plane ``n . P = h`` (camera frame) has the disparity ``d + doffs = (f b / h) n . ((u - cx)/f, (v - cy)/f, 1)``:
affine in the pixel coordinates. So a least-squares fit ``d + doffs = alpha u' + beta v' + gamma`` over a
window (``u' = u - cx``, ``v' = v - cy``) gives the plane's normal without ever forming depths, in the
domain where the stereo noise is uniform (disparity) rather than growing with depth squared. The window sums
come from summed-area tables (one numba pass over the image), then each fitted pixel costs a constant.
"""

from __future__ import annotations

import numba as nb
import numpy as np
import numpy.typing as npt

from prismap._validate import check_integer
from prismap.camera._stereo_camera import StereoCamera
from prismap.errors import PrismapInputError

PLANE_WINDOW_PX = 7
"""Side of the square window of each plane fit (pixels)."""

MIN_WINDOW_SHARE = 0.5
"""Fewest valid pixels a window may hold for its fit (share of the window); fewer: no normal."""


def plane_normals(
    disparity_px: npt.ArrayLike, camera: StereoCamera, *, window_px: int = PLANE_WINDOW_PX, subsample: int = 1
) -> npt.NDArray[np.float64]:
    """Unit normal of the surface at each (``subsample``-th) pixel, camera frame, facing the camera.

    Parameters
    ----------
    disparity_px : (H, W) float, pixels, NaN or ``d + doffs <= 0`` = invalid
    camera : StereoCamera
    window_px : odd int >= 3, pixels
        Side of the window of each fit (on the full image).
    subsample : int >= 1
        Fit at every ``subsample``-th pixel in both directions (as the grid subsamples rays).

    Returns
    -------
    (ceil(H / s), ceil(W / s), 3) float64, camera frame
        ``n`` with ``|n| = 1`` and ``n . r < 0`` for the pixel's ray ``r``; NaN where the pixel is invalid,
        its window holds fewer than :data:`MIN_WINDOW_SHARE` valid pixels (of its part inside the image), or
        their coordinates are degenerate (a line of pixels: every pixel of a one-row image, as
        ``prismap.sim.StereoScanner2D`` gives).

    Notes
    -----
    With ``d' = d + doffs`` fitted as ``alpha u' + beta v' + gamma`` and
    ``d' = (f b / h)(n_x u'/f + n_y v'/f + n_z)``, the normal is ``(alpha, beta, (d' - alpha u' - beta v') / f)``
    up to scale, with the pixel's own ``d'``. Across a depth discontinuity the fit mixes two surfaces and the
    normal leans toward grazing, which is what callers that bound the surface's extent want there.
    """
    disparity = np.asarray(disparity_px, dtype=np.float64)
    if disparity.ndim != 2:
        raise PrismapInputError(f"`disparity_px` must be an (H, W) image; got shape {disparity.shape}")
    if isinstance(window_px, bool) or int(window_px) != window_px or window_px < 3 or window_px % 2 == 0:
        raise PrismapInputError(f"`window_px` must be an odd integer >= 3; got {window_px!r}")
    check_integer(subsample, "subsample", expected="an integer >= 1", condition=lambda n: n >= 1)
    return _plane_normals(
        np.ascontiguousarray(disparity),
        float(camera.focal_px),
        float(camera.cx_px),
        float(camera.cy_px),
        float(camera.doffs_px),
        int(window_px) // 2,
        int(subsample),
        MIN_WINDOW_SHARE,
    )


@nb.njit(cache=True, nogil=True)
def _plane_normals(disparity, f, cx, cy, doffs, half, step, min_share):
    """Least-squares plane ``d' = alpha u' + beta v' + gamma`` over each window, as a unit normal facing the camera.

    The window sums (count, u, v, d', u^2, v^2, u v, u d', v d' of the valid pixels) come from summed-area
    tables, so a fit costs the same whatever the window; the (co)variances are differences of means, which do
    not depend on where the coordinates start. The tables' rows are made as the fits reach them and kept for one
    window (row ``r`` at ``r % depth``, a pixel's nine sums side by side), so they stay in the cache.
    """
    height, width = disparity.shape
    depth = 2 * half + 2  # a window's rows y0..y1 of the table, y1 - y0 <= 2 half + 1
    table = np.empty((depth, width + 1, 9))
    table[0] = 0.0
    made = 0  # table rows 0..made are made
    row = np.empty(9)
    rows, cols = (height + step - 1) // step, (width + step - 1) // step
    out = np.full((rows, cols, 3), np.nan)
    s = np.empty(9)
    for i in range(rows):
        y = i * step
        y0, y1 = max(y - half, 0), min(y + half + 1, height)
        while made < y1:
            above, below = table[made % depth], table[(made + 1) % depth]
            below[0] = 0.0
            row[:] = 0.0
            for x in range(width):
                d = disparity[made, x] + doffs
                if d > 0:  # False for NaN
                    row[0] += 1.0
                    row[1] += x
                    row[2] += made
                    row[3] += d
                    row[4] += x * x
                    row[5] += made * made
                    row[6] += x * made
                    row[7] += x * d
                    row[8] += made * d
                for k in range(9):
                    below[x + 1, k] = above[x + 1, k] + row[k]
            made += 1
        top, bottom = table[y0 % depth], table[y1 % depth]
        for j in range(cols):
            x = j * step
            d0 = disparity[y, x] + doffs
            if not d0 > 0:
                continue
            x0, x1 = max(x - half, 0), min(x + half + 1, width)
            for k in range(9):
                s[k] = bottom[x1, k] - top[x1, k] - bottom[x0, k] + top[x0, k]
            n = s[0]
            if n < min_share * (y1 - y0) * (x1 - x0):
                continue
            mean_u, mean_v, mean_d = s[1] / n, s[2] / n, s[3] / n
            var_u = s[4] / n - mean_u * mean_u
            var_v = s[5] / n - mean_v * mean_v
            cov_uv = s[6] / n - mean_u * mean_v
            cov_ud = s[7] / n - mean_u * mean_d
            cov_vd = s[8] / n - mean_v * mean_d
            det = var_u * var_v - cov_uv * cov_uv
            if det <= 1e-6:
                continue
            alpha = (var_v * cov_ud - cov_uv * cov_vd) / det
            beta = (var_u * cov_vd - cov_uv * cov_ud) / det
            gamma = (d0 - alpha * (x - cx) - beta * (y - cy)) / f
            length = np.sqrt(alpha * alpha + beta * beta + gamma * gamma)
            out[i, j, 0] = -alpha / length  # before the flip n . r = d' / f > 0
            out[i, j, 1] = -beta / length
            out[i, j, 2] = -gamma / length
    return out
