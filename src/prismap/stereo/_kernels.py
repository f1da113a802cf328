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
def linearise_data_term(left, right, right_dx, disparity, out_a, out_b):
    """Data term of one warp: coefficients of ``(I_r(x - d) - I_l(x))^2`` linearised at ``d0``.

    With ``I_w = I_r(x - d0)`` and ``g = dI_r/dx (x - d0)`` (linear interpolation along the row),
    ``I_r(x - d) ~ I_w - g (d - d0)``, whose squared residual has normal-equation coefficients
    ``a = g^2`` and ``b = g^2 d0 + g (I_w - I_l)``. Pixels whose match falls outside the right image
    get ``a = b = 0``: the smoothness term fills them in.
    """
    height, width = left.shape
    for i in range(height):
        for j in range(width):
            d0 = disparity[i, j]
            u = j - d0
            if u < 0.0 or u > width - 1:
                out_a[i, j] = 0.0
                out_b[i, j] = 0.0
                continue
            k = min(int(np.floor(u)), width - 2)
            t = u - k
            warped = (1.0 - t) * right[i, k] + t * right[i, k + 1]
            grad = (1.0 - t) * right_dx[i, k] + t * right_dx[i, k + 1]
            out_a[i, j] = grad * grad
            out_b[i, j] = grad * grad * d0 + grad * (warped - left[i, j])


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
def block_matching_search(left, right, d_min, d_max, radius):
    """Winner-take-all disparity over integer ``d`` in [d_min, d_max] by box-summed absolute difference.

    The cost of ``d`` at (i, j) is the mean of ``|I_l(x) - I_r(x - d)|`` over the ``(2 radius + 1)^2``
    window, counting only window pixels whose match lies inside the right image. Used once, on the
    coarsest pyramid level, to start the variational refinement near the right basin.
    """
    height, width = left.shape
    best_cost = np.full((height, width), np.inf, dtype=np.float32)
    best = np.full((height, width), np.float32(d_min), dtype=np.float32)
    diff = np.empty((height, width), dtype=np.float32)
    valid = np.empty((height, width), dtype=np.float32)
    col_d = np.empty((height, width), dtype=np.float32)
    col_v = np.empty((height, width), dtype=np.float32)
    for d in range(d_min, d_max + 1):
        for i in range(height):
            for j in range(width):
                k = j - d
                if 0 <= k < width:
                    diff[i, j] = abs(left[i, j] - right[i, k])
                    valid[i, j] = 1.0
                else:
                    diff[i, j] = 0.0
                    valid[i, j] = 0.0
        # box sum: vertical pass, then horizontal pass with the cost comparison
        for j in range(width):
            for i in range(height):
                sd = 0.0
                sv = 0.0
                for k in range(max(i - radius, 0), min(i + radius + 1, height)):
                    sd += diff[k, j]
                    sv += valid[k, j]
                col_d[i, j] = sd
                col_v[i, j] = sv
        for i in range(height):
            for j in range(width):
                sd = 0.0
                sv = 0.0
                for k in range(max(j - radius, 0), min(j + radius + 1, width)):
                    sd += col_d[i, k]
                    sv += col_v[i, k]
                if sv > 0.0:
                    cost = sd / sv
                    if cost < best_cost[i, j]:
                        best_cost[i, j] = cost
                        best[i, j] = d
    return best
