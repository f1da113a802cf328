"""numba kernels of the variational matcher; called only by the checked wrappers in ``_variational.py``.

Every linear system here has one form, the normal equations of a quadratic energy on a pixel grid:

    a_p x_p + sum_{q ~ p} w_pq (x_p - x_q) = b_p

with a data coefficient ``a`` (H, W) >= 0, right-hand side ``b`` (H, W), horizontal edge weights
``wh`` (H, W-1) (``wh[i, j]`` joins (i, j) and (i, j+1)) and vertical ones ``wv`` (H-1, W)
(``wv[i, j]`` joins (i, j) and (i+1, j)). Kernels assume C-contiguous float32 arrays of matching
shapes; the wrappers guarantee it. No fastmath: the inputs are finite, but we keep IEEE semantics.
"""

import numba
import numpy as np

PENALTY_TICHONOV = 0
PENALTY_CHARBONNIER = 1
PENALTY_PERONA_MALIK = 2


@numba.njit(cache=True)
def jacobi_sweep(x, a, b, wh, wv, omega, out):
    """One damped Jacobi sweep of the system above: ``out = (1-omega) x + omega D^-1 (b + N x)``.

    Pixels with no coefficient at all (``a = 0`` and no edges) keep their value.
    """
    height, width = x.shape
    for i in range(height):
        for j in range(width):
            num = np.float64(b[i, j])
            den = np.float64(a[i, j])
            if j > 0:
                w = wh[i, j - 1]
                num += w * x[i, j - 1]
                den += w
            if j < width - 1:
                w = wh[i, j]
                num += w * x[i, j + 1]
                den += w
            if i > 0:
                w = wv[i - 1, j]
                num += w * x[i - 1, j]
                den += w
            if i < height - 1:
                w = wv[i, j]
                num += w * x[i + 1, j]
                den += w
            if den > 0.0:
                out[i, j] = (1.0 - omega) * x[i, j] + omega * num / den
            else:
                out[i, j] = x[i, j]


@numba.njit(cache=True)
def jacobi(x, a, b, wh, wv, n_sweeps, omega):
    """``n_sweeps`` Jacobi sweeps starting from ``x`` (not modified); returns the new iterate."""
    current = x.copy()
    scratch = np.empty_like(x)
    for _ in range(n_sweeps):
        jacobi_sweep(current, a, b, wh, wv, omega, scratch)
        current, scratch = scratch, current
    return current


@numba.njit(cache=True)
def residual(x, a, b, wh, wv):
    """``b - A x`` of the system above, (H, W) float32."""
    height, width = x.shape
    r = np.empty_like(x)
    for i in range(height):
        for j in range(width):
            xp = np.float64(x[i, j])
            ax = a[i, j] * xp
            if j > 0:
                ax += wh[i, j - 1] * (xp - x[i, j - 1])
            if j < width - 1:
                ax += wh[i, j] * (xp - x[i, j + 1])
            if i > 0:
                ax += wv[i - 1, j] * (xp - x[i - 1, j])
            if i < height - 1:
                ax += wv[i, j] * (xp - x[i + 1, j])
            r[i, j] = b[i, j] - ax
    return r


@numba.njit(cache=True)
def restrict_sum(x):
    """Sum over 2x2 blocks (the transpose of piecewise-constant prolongation); odd edges pad with 0."""
    height, width = x.shape
    out = np.zeros(((height + 1) // 2, (width + 1) // 2), dtype=x.dtype)
    for i in range(height):
        for j in range(width):
            out[i // 2, j // 2] += x[i, j]
    return out


@numba.njit(cache=True)
def coarsen_edges(wh, wv, height, width):
    """Galerkin coarse edge weights for piecewise-constant prolongation onto 2x2 blocks.

    A coarse edge carries the sum of the fine edges that cross its block boundary; fine edges inside
    one block drop out, since a constant correction does not stretch them.
    """
    coarse_h = (height + 1) // 2
    coarse_w = (width + 1) // 2
    wh_c = np.zeros((coarse_h, max(coarse_w - 1, 0)), dtype=wh.dtype)
    wv_c = np.zeros((max(coarse_h - 1, 0), coarse_w), dtype=wv.dtype)
    for i in range(height):
        for jc in range(coarse_w - 1):
            wh_c[i // 2, jc] += wh[i, 2 * jc + 1]
    for ic in range(coarse_h - 1):
        for j in range(width):
            wv_c[ic, j // 2] += wv[2 * ic + 1, j]
    return wh_c, wv_c


@numba.njit(cache=True)
def add_prolonged(x, coarse):
    """``x += P coarse`` with piecewise-constant prolongation (each coarse value fills its 2x2 block)."""
    height, width = x.shape
    for i in range(height):
        for j in range(width):
            x[i, j] += coarse[i // 2, j // 2]


@numba.njit(cache=True)
def _cubic_weights(t):
    """Keys' cubic convolution weights (a = -0.5, Catmull-Rom) of the samples at -1, 0, 1, 2 for offset t."""
    t2 = t * t
    t3 = t2 * t
    return (
        -0.5 * t3 + t2 - 0.5 * t,
        1.5 * t3 - 2.5 * t2 + 1.0,
        -1.5 * t3 + 2.0 * t2 + 0.5 * t,
        0.5 * t3 - 0.5 * t2,
    )


@numba.njit(cache=True)
def linearise_data_term(left, right, right_dx, disparity, eps2, out_a, out_b):
    """Data term of one warp: normal-equation coefficients of ``sum_k psi_k(r_k^2)`` linearised at ``d0``.

    ``left``, ``right``, ``right_dx`` are (K, H, W) feature stacks (brightness, gradients, ...) and
    the right stack's x-derivative. Per channel, with ``w = F_r(x - d0)`` and ``g = dF_r/dx (x - d0)``
    (cubic convolution along the row, edge samples replicated: linear interpolation would bias
    sub-pixel disparities towards integers), ``F_r(x - d) ~ w - g (d - d0)``: the residual
    ``r = w - F_l`` enters with weight ``psi'(r^2)`` lagged at ``d0``, so ``a += psi' g^2`` and
    ``b += psi' (g^2 d0 + g r)``. ``psi'`` is ``1 / sqrt(1 + r^2 / eps2)`` (Charbonnier), or 1 when
    ``eps2`` is 0 (quadratic). Pixels whose match falls outside the right image get ``a = b = 0``:
    the smoothness term fills them in.
    """
    channels, height, width = left.shape
    for i in range(height):
        for j in range(width):
            d0 = disparity[i, j]
            u = j - d0
            if u < 0.0 or u > width - 1:
                out_a[i, j] = 0.0
                out_b[i, j] = 0.0
                continue
            k = min(int(np.floor(u)), width - 2)
            c0, c1, c2, c3 = _cubic_weights(u - k)
            k0 = max(k - 1, 0)
            k3 = min(k + 2, width - 1)
            a = 0.0
            b = 0.0
            for c in range(channels):
                warped = c0 * right[c, i, k0] + c1 * right[c, i, k] + c2 * right[c, i, k + 1] + c3 * right[c, i, k3]
                grad = (
                    c0 * right_dx[c, i, k0]
                    + c1 * right_dx[c, i, k]
                    + c2 * right_dx[c, i, k + 1]
                    + c3 * right_dx[c, i, k3]
                )
                r = warped - left[c, i, j]
                weight = 1.0 if eps2 == 0.0 else 1.0 / np.sqrt(1.0 + r * r / eps2)
                a += weight * grad * grad
                b += weight * (grad * grad * d0 + grad * r)
            out_a[i, j] = a
            out_b[i, j] = b


@numba.njit(cache=True)
def smoothness_weights(disparity, fi, lam, penalty, out_wh, out_wv):
    """Edge weights ``fi * psi'(s^2)`` of the smoothness term, lagged at the current disparity.

    ``s`` is the disparity difference across the edge (pixels). ``psi'`` is 1 (Tichonov),
    ``1 / sqrt(1 + s^2 / lam^2)`` (Charbonnier) or ``1 / (1 + s^2 / lam^2)`` (Perona-Malik).
    """
    height, width = disparity.shape
    inv_lam2 = 1.0 / (lam * lam)
    for i in range(height):
        for j in range(width):
            for direction in range(2):
                if direction == 0:
                    if j == width - 1:
                        continue
                    s = disparity[i, j + 1] - disparity[i, j]
                else:
                    if i == height - 1:
                        continue
                    s = disparity[i + 1, j] - disparity[i, j]
                if penalty == PENALTY_TICHONOV:
                    g = 1.0
                elif penalty == PENALTY_CHARBONNIER:
                    g = 1.0 / np.sqrt(1.0 + s * s * inv_lam2)
                else:
                    g = 1.0 / (1.0 + s * s * inv_lam2)
                if direction == 0:
                    out_wh[i, j] = fi * g
                else:
                    out_wv[i, j] = fi * g


@numba.njit(cache=True)
def census_transform(image, radius):
    """Census signature of each pixel: one bit per window neighbour, set where it is darker than the centre.

    The window is ``(2 radius + 1)^2`` (``radius <= 3``, so the bits fit an int64); neighbours outside
    the image count as the edge pixel (replicated border).
    """
    height, width = image.shape
    out = np.zeros((height, width), dtype=np.int64)
    for i in range(height):
        for j in range(width):
            centre = image[i, j]
            code = 0
            for di in range(-radius, radius + 1):
                ii = min(max(i + di, 0), height - 1)
                for dj in range(-radius, radius + 1):
                    if di == 0 and dj == 0:
                        continue
                    jj = min(max(j + dj, 0), width - 1)
                    code = (code << 1) | (1 if image[ii, jj] < centre else 0)
            out[i, j] = code
    return out


@numba.njit(cache=True)
def _popcount(value):
    count = 0
    while value:
        value &= value - 1
        count += 1
    return count


@numba.njit(cache=True)
def census_cost_volume(census_left, census_right, d_min, n_disp, outside_cost):
    """(H, W, D) float32 Hamming distance between left census at x and right census at x - d.

    ``d = d_min + k`` for ``k < n_disp``; matches outside the right image cost ``outside_cost``.
    """
    height, width = census_left.shape
    cost = np.empty((height, width, n_disp), dtype=np.float32)
    for i in range(height):
        for j in range(width):
            for k in range(n_disp):
                jj = j - (d_min + k)
                if 0 <= jj < width:
                    cost[i, j, k] = _popcount(census_left[i, j] ^ census_right[i, jj])
                else:
                    cost[i, j, k] = outside_cost
    return cost


@numba.njit(cache=True)
def aggregate_paths(cost, p1, p2):
    """Semi-global aggregation (Hirschmuller 2008) of a (H, W, D) cost volume along 8 straight paths.

    Along each path direction ``r``: ``L(p, d) = C(p, d) + min(L(p-r, d), L(p-r, d+-1) + p1,
    min_k L(p-r, k) + p2) - min_k L(p-r, k)``; the result is the sum over the paths.
    """
    height, width, n_disp = cost.shape
    total = np.zeros_like(cost)
    path = np.empty_like(cost)
    for di in range(-1, 2):
        for dj in range(-1, 2):
            if di == 0 and dj == 0:
                continue
            for step_i in range(height):
                i = step_i if di >= 0 else height - 1 - step_i
                for step_j in range(width):
                    j = step_j if dj >= 0 else width - 1 - step_j
                    pi = i - di
                    pj = j - dj
                    if pi < 0 or pi >= height or pj < 0 or pj >= width:
                        for k in range(n_disp):
                            path[i, j, k] = cost[i, j, k]
                    else:
                        best_prev = path[pi, pj, 0]
                        for k in range(1, n_disp):
                            best_prev = min(best_prev, path[pi, pj, k])
                        for k in range(n_disp):
                            value = min(path[pi, pj, k], best_prev + p2)
                            if k > 0:
                                value = min(value, path[pi, pj, k - 1] + p1)
                            if k < n_disp - 1:
                                value = min(value, path[pi, pj, k + 1] + p1)
                            path[i, j, k] = cost[i, j, k] + value - best_prev
                    for k in range(n_disp):
                        total[i, j, k] += path[i, j, k]
    return total


@numba.njit(cache=True)
def winner_take_all(cost, d_min):
    """Disparity of least cost per pixel, refined by the parabola through it and its two neighbours."""
    height, width, n_disp = cost.shape
    out = np.empty((height, width), dtype=np.float32)
    for i in range(height):
        for j in range(width):
            best = 0
            for k in range(1, n_disp):
                if cost[i, j, k] < cost[i, j, best]:
                    best = k
            offset = 0.0
            if 0 < best < n_disp - 1:
                before = cost[i, j, best - 1]
                after = cost[i, j, best + 1]
                curvature = before - 2.0 * cost[i, j, best] + after
                if curvature > 0.0:
                    offset = 0.5 * (before - after) / curvature
            out[i, j] = d_min + best + offset
    return out
