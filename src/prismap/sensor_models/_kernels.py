"""numba kernels of the inverse sensor models; called only by the wrappers in this package.

The wrappers validate and convert (contiguous float64 / int64); the kernels assume. PRISM works in log
space throughout: ``log C`` and ``log D = log(Z - C)`` are carried as logarithms so that nothing
underflows from 0.1 m to 200 m with surface rates up to 50 per metre.
"""

import math

import numba as nb
import numpy as np

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_LOG_W = np.log(_GL_W)
_SQRT_HALF = math.sqrt(0.5)


# --------------------------------------------------------------------------------------------- helpers


@nb.njit(cache=True)
def logaddexp(a, b):
    """``log(exp(a) + exp(b))``, exact for -inf arguments."""
    if a < b:
        a, b = b, a
    if b == -np.inf:
        return a
    return a + math.log1p(math.exp(b - a))


@nb.njit(cache=True)
def log1mexp(t):
    """``log(1 - exp(t))`` for ``t <= 0`` (``t > 0`` is treated as 0, giving -inf)."""
    if t >= 0.0:
        return -np.inf
    if t > -0.6931471805599453:
        return math.log(-math.expm1(t))
    return math.log1p(-math.exp(t))


@nb.njit(cache=True)
def normal_cdf(x):
    """Standard normal CDF."""
    return 0.5 * math.erfc(-x * _SQRT_HALF)


@nb.njit(cache=True)
def _logit(p):
    return math.log(p) - math.log1p(-p)


@nb.njit(cache=True)
def _sigmoid(x):
    if x >= 0.0:
        return 1.0 / (1.0 + math.exp(-x))
    e = math.exp(x)
    return e / (1.0 + e)


# ------------------------------------------------------------------------------------- classic models


@nb.njit(cache=True)
def ideal_cells(depth_hat, ray_norm, ray_of_cell, start, end, half_alpha, p_free, p_occ, p0):
    """Thrun's ideal model at the cell centre; distances along the ray."""
    n = start.size
    post = np.empty(n)
    inc = np.empty(n)
    logit_p0 = _logit(p0)
    l_free = _logit(p_free) - logit_p0
    l_occ = _logit(p_occ) - logit_p0
    for i in range(n):
        r = ray_of_cell[i]
        gap = (0.5 * (start[i] + end[i]) - depth_hat[r]) * ray_norm[r]
        if abs(gap) <= half_alpha:
            post[i], inc[i] = p_occ, l_occ
        elif gap < 0.0:
            post[i], inc[i] = p_free, l_free
        else:
            post[i], inc[i] = p0, 0.0
    return post, inc


@nb.njit(cache=True)
def hitmiss_cells(depth_hat, ray_of_cell, start, end, l_hit, l_miss, p0):
    """OctoMap: hit at the cell whose interval holds the measured depth, miss before, nothing after."""
    n = start.size
    post = np.empty(n)
    inc = np.empty(n)
    logit_p0 = _logit(p0)
    for i in range(n):
        z = depth_hat[ray_of_cell[i]]
        if start[i] <= z < end[i]:
            inc[i] = l_hit
        elif end[i] <= z:
            inc[i] = l_miss
        else:
            inc[i] = 0.0
        post[i] = _sigmoid(logit_p0 + inc[i])
    return post, inc


@nb.njit(cache=True)
def convolution_cells(depth_hat, sigma_depth, ray_norm, ray_of_cell, start, end, half_alpha, p_free, p_occ, p0):
    """Ideal profile convolved with N(0, sigma_s^2) along the ray, at the cell centre."""
    n = start.size
    post = np.empty(n)
    inc = np.empty(n)
    logit_p0 = _logit(p0)
    for i in range(n):
        r = ray_of_cell[i]
        sigma = sigma_depth[r] * ray_norm[r]
        gap = (depth_hat[r] - 0.5 * (start[i] + end[i])) * ray_norm[r]  # s^ - s
        below = normal_cdf((gap - half_alpha) / sigma)  # P(s + noise < s^ - alpha/2)
        inside = normal_cdf((gap + half_alpha) / sigma)
        p = p_free * below + p_occ * (inside - below) + p0 * (1.0 - inside)
        p = min(max(p, 1e-300), 1.0 - 1e-16)
        post[i] = p
        inc[i] = _logit(p) - logit_p0
    return post, inc


@nb.njit(cache=True)
def andert_cells(depth_hat, sigma_depth, ray_norm, ray_of_cell, start, end, eta, p_min, p_max, p0):
    """Andert's profile evaluated at ``clip(s^, a, c)``; increments on the even-odds scale."""
    n = start.size
    post = np.empty(n)
    inc = np.empty(n)
    logit_p0 = _logit(p0)
    norm = 1.0 / math.sqrt(2.0 * math.pi)
    for i in range(n):
        r = ray_of_cell[i]
        z_hat = depth_hat[r]
        sigma = sigma_depth[r] * ray_norm[r]
        z = min(max(z_hat, start[i]), end[i])
        gap = (z - z_hat) * ray_norm[r]
        base = p_min if gap <= 0.0 else 0.5
        peak = min(0.5 + eta * norm / sigma, p_max)
        p = base + (peak - base) * math.exp(-0.5 * (gap / sigma) ** 2)
        inc[i] = _logit(p)
        post[i] = _sigmoid(logit_p0 + inc[i])
    return post, inc


# ---------------------------------------------------------------------------------------------- PRISM
# A ray is described by ``shift = d^ + doffs`` (pixels) and its surface rate ``lam`` (per metre of depth).
# The integration coordinate ``x(z) = lam*z - ku/z`` with ``ku = f*b / sigma_min`` grows by one unit per
# e-fold of the prior ``q`` and per narrowest sigma of disparity, so panels of fixed x-width resolve both.


@nb.njit(cache=True)
def log_likelihood(u, shift, log_wn, means, sigmas):
    """``log g``: the mixture density of the error ``u - shift`` (``u`` = true disparity + 0, pixels)."""
    best = -np.inf
    total = 0.0
    for j in range(means.size):
        t = (u - shift - means[j]) / sigmas[j]
        v = log_wn[j] - 0.5 * t * t
        if v > best:
            total = total * math.exp(best - v) + 1.0
            best = v
        else:
            total += math.exp(v - best)
    return best + math.log(total)


@nb.njit(cache=True)
def _log_sup_tail(z, z_max, fb, shift, log_wn, means, sigmas):
    """Log of an upper bound of ``g`` on true depths ``[z, z_max]`` (sum of per-component maxima)."""
    u_hi = fb / z
    u_lo = fb / z_max
    best = -np.inf
    total = 0.0
    for j in range(means.size):
        mode = min(max(shift + means[j], u_lo), u_hi)
        t = (mode - shift - means[j]) / sigmas[j]
        v = log_wn[j] - 0.5 * t * t
        if v > best:
            total = total * math.exp(best - v) + 1.0
            best = v
        else:
            total += math.exp(v - best)
    return best + math.log(total)


@nb.njit(cache=True)
def x_of_z(z, lam, ku):
    return lam * z - ku / z


@nb.njit(cache=True)
def z_of_x(x, lam, ku):
    root = math.sqrt(x * x + 4.0 * lam * ku)
    if x >= 0.0:
        return (x + root) / (2.0 * lam)
    return 2.0 * ku / (root - x)


@nb.njit(cache=True)
def _log_panel(z1, z2, lam, z0, fb, shift, log_wn, means, sigmas):
    """Log of ``int_{z1}^{z2} q g dz`` by 8-point Gauss-Legendre (one panel)."""
    half = 0.5 * (z2 - z1)
    if half <= 0.0:
        return -np.inf
    mid = 0.5 * (z1 + z2)
    best = -np.inf
    total = 0.0
    log_lam = math.log(lam)
    for i in range(8):
        z = mid + half * _GL_X[i]
        v = _GL_LOG_W[i] + log_lam - lam * (z - z0) + log_likelihood(fb / z, shift, log_wn, means, sigmas)
        if v > best:
            total = total * math.exp(best - v) + 1.0
            best = v
        else:
            total += math.exp(v - best)
    return best + math.log(total) + math.log(half)


@nb.njit(cache=True)
def log_integral(z1, z2, lam, ku, hq, z0, fb, shift, log_wn, means, sigmas):
    """Log of ``int_{z1}^{z2} q g dz`` with panels of x-width at most ``hq``."""
    if z2 <= z1:
        return -np.inf
    x1 = x_of_z(z1, lam, ku)
    x2 = x_of_z(z2, lam, ku)
    n = max(1, int(math.ceil((x2 - x1) / hq)))
    out = -np.inf
    za = z1
    for k in range(1, n + 1):
        zb = z2 if k == n else z_of_x(x1 + (x2 - x1) * k / n, lam, ku)
        out = logaddexp(out, _log_panel(za, zb, lam, z0, fb, shift, log_wn, means, sigmas))
        za = zb
    return out


@nb.njit(cache=True)
def _log_q_g(z, lam, z0, fb, shift, log_wn, means, sigmas):
    return math.log(lam) - lam * (z - z0) + log_likelihood(fb / z, shift, log_wn, means, sigmas)


@nb.njit(cache=True)
def prism_march(shift, lam, z0, z_max, fb, ku, hq, log_far, log_eps_bound, i_min, log_wn, means, sigmas):
    """Cumulative evidence of one (d^, lam) on the x-grid of spacing ``hq`` from ``z0``.

    Returns ``z`` (nodes), ``log C`` and ``log D`` at the nodes (not normalised), ``log Z`` and the index of
    the first node from which every later cell's increment is bounded by epsilon (``log_eps_bound`` =
    ``log(expm1(epsilon))``). The march stops (not before node ``i_min``) once the remaining evidence is
    below e^-40 of ``C``.
    """
    x0 = x_of_z(z0, lam, ku)
    x_end = x_of_z(z_max, lam, ku)
    n_max = max(1, int(math.ceil((x_end - x0) / hq)))
    z = np.empty(n_max + 1)
    log_c = np.empty(n_max + 1)
    panel = np.empty(n_max + 1)
    z[0] = z0
    log_c[0] = -np.inf
    panel[0] = -np.inf
    i_infl = -1
    n = n_max
    tail = -np.inf
    log_far_w = -lam * (z_max - z0) + log_far
    for i in range(1, n_max + 1):
        z[i] = z_max if i == n_max else z_of_x(x0 + i * hq, lam, ku)
        panel[i] = _log_panel(z[i - 1], z[i], lam, z0, fb, shift, log_wn, means, sigmas)
        log_c[i] = logaddexp(log_c[i - 1], panel[i])
        bound = -lam * (z[i] - z0) + max(_log_sup_tail(z[i], z_max, fb, shift, log_wn, means, sigmas), log_far)
        if i_infl < 0 and bound - log_c[i] < log_eps_bound:
            i_infl = i
        if i < n_max and i >= i_min and bound - log_c[i] < -40.0:
            n = i
            tail = bound
            break
    if n == n_max:
        tail = log_far_w
        if i_infl < 0:
            i_infl = n_max
    log_d = np.empty(n + 1)
    log_d[n] = tail
    for i in range(n, 0, -1):
        log_d[i - 1] = logaddexp(log_d[i], panel[i])
    log_z = logaddexp(log_c[n], tail)
    return z[: n + 1], log_c[: n + 1], log_d, log_z, i_infl


@nb.njit(cache=True)
def combine(l_ca, l_da, l_cc, l_dc, lam_len):
    """Posterior and increment of a cell [a, c] from log C, log D at both ends (any common scale).

    ``P Z = p_c C(a) + (C(c) - C(a))`` and ``(1 - P) Z = (1 - p_c) C(a) + D(c)``; the difference
    ``C(c) - C(a) = D(a) - D(c)`` is taken from whichever side is larger-scale accurate.
    """
    log_pc = log1mexp(-lam_len)
    log_1mpc = -lam_len
    if l_cc < l_da:
        l_delta = l_cc + log1mexp(l_ca - l_cc)
    else:
        l_delta = l_da + log1mexp(l_dc - l_da)
    l_num = logaddexp(log_pc + l_ca, l_delta)
    l_den = logaddexp(log_1mpc + l_ca, l_dc)
    inc = (l_num - l_den) - (log_pc - log_1mpc)
    return _sigmoid(l_num - l_den), inc


@nb.njit(cache=True)
def log_tail(z, log_c_z, lam, ku, hq, z0, z_max, fb, shift, log_far, log_wn, means, sigmas):
    """``log D(z)``: evidence beyond ``z`` (far measurement included), marched until the rest is < e^-40."""
    tail = -np.inf
    acc = log_c_z
    x_start = x_of_z(z, lam, ku)
    x_end = x_of_z(z_max, lam, ku)
    za = z
    k = 1
    while za < z_max:
        zb = z_of_x(x_start + k * hq, lam, ku) if x_start + k * hq < x_end else z_max
        zb = min(zb, z_max)
        p = _log_panel(za, zb, lam, z0, fb, shift, log_wn, means, sigmas)
        tail = logaddexp(tail, p)
        acc = logaddexp(acc, p)
        za = zb
        k += 1
        bound = -lam * (za - z0) + max(_log_sup_tail(za, z_max, fb, shift, log_wn, means, sigmas), log_far)
        if za < z_max and bound - acc < -40.0:
            return logaddexp(tail, bound)
    return logaddexp(tail, -lam * (z_max - z0) + log_far)


@nb.njit(cache=True)
def prism_direct_cells(
    shift, lam, order, ray_start, start, end, z0, z_max, fb, ku, hq, log_far, log_wn, means, sigmas
):
    """Continuous PRISM by quadrature, ray by ray: exact C and D at every distinct cell boundary.

    ``order`` sorts cells by ray; the cells of ray ``r`` are ``order[ray_start[r]:ray_start[r + 1]]``.
    """
    n = start.size
    post = np.empty(n)
    inc = np.empty(n)
    for r in range(shift.size):
        lo, hi = ray_start[r], ray_start[r + 1]
        if hi == lo:
            continue
        m = hi - lo
        bounds = np.empty(2 * m)
        for k in range(m):
            i = order[lo + k]
            bounds[2 * k] = min(max(start[i], z0), z_max)
            bounds[2 * k + 1] = min(max(end[i], z0), z_max)
        bounds = np.unique(bounds)
        nb_ = bounds.size
        log_c = np.empty(nb_)
        panels = np.empty(nb_)
        log_c[0] = log_integral(z0, bounds[0], lam[r], ku, hq, z0, fb, shift[r], log_wn, means, sigmas)
        panels[0] = -np.inf
        for k in range(1, nb_):
            panels[k] = log_integral(bounds[k - 1], bounds[k], lam[r], ku, hq, z0, fb, shift[r], log_wn, means, sigmas)
            log_c[k] = logaddexp(log_c[k - 1], panels[k])
        tail = log_tail(bounds[nb_ - 1], log_c[nb_ - 1], lam[r], ku, hq, z0, z_max, fb, shift[r], log_far[r],
                        log_wn, means, sigmas)
        log_d = np.empty(nb_)
        log_d[nb_ - 1] = tail
        for k in range(nb_ - 1, 0, -1):
            log_d[k - 1] = logaddexp(log_d[k], panels[k])
        for k in range(m):
            i = order[lo + k]
            a = min(max(start[i], z0), z_max)
            c = min(max(end[i], z0), z_max)
            if c <= a:
                post[i] = -math.expm1(-lam[r] * max(end[i] - start[i], 0.0))
                inc[i] = 0.0
                continue
            ia = np.searchsorted(bounds, a)
            ic = np.searchsorted(bounds, c)
            post[i], inc[i] = combine(log_c[ia], log_d[ia], log_c[ic], log_d[ic], lam[r] * (c - a))
    return post, inc


@nb.njit(cache=True)
def _locate(z, lam, ku, x0, inv_h, length):
    """Node index and fraction of depth ``z`` on a table's x-grid (scalars only: no array refcounts)."""
    s = (x_of_z(z, lam, ku) - x0) * inv_h
    i = min(max(int(s), 0), length - 2)
    return i, min(max(s - i, 0.0), 1.0)


@nb.njit(cache=True)
def _hermite(f, h, v0, d0, v1, d1):
    """Cubic Hermite on [0, 1] with node derivatives ``d0, d1`` per unit x (scaled by the step ``h``)."""
    f2 = f * f
    f3 = f2 * f
    return ((2.0 * f3 - 3.0 * f2 + 1.0) * v0 + (f3 - 2.0 * f2 + f) * h * d0
            + (3.0 * f2 - 2.0 * f3) * v1 + (f3 - f2) * h * d1)


@nb.njit(cache=True)
def _one_minus_exp_neg(x):
    """``1 - exp(-x)`` for ``x >= 0``; a Taylor series below 0.1 (error < 3e-17 relative) saves an exp."""
    if x >= 0.1:
        return -math.expm1(-x)
    term = x
    total = x
    for k in range(2, 10):
        term *= -x / k
        total += term
    return total


@nb.njit(cache=True)
def combine_fast(l_ca, l_da, l_cc, l_dc, lam_len):
    """:func:`combine` in linear space (4 transcendentals); falls back to it when a value nears underflow."""
    if min(min(l_ca, l_da), min(l_cc, l_dc)) < -600.0:
        return combine(l_ca, l_da, l_cc, l_dc, lam_len)
    p_c = _one_minus_exp_neg(lam_len)
    c_a = math.exp(l_ca)
    d_c = math.exp(l_dc)
    if l_cc < l_da:
        delta = max(math.exp(l_cc) - c_a, 0.0)
    else:
        delta = max(math.exp(l_da) - d_c, 0.0)
    num = p_c * c_a + delta
    den = (1.0 - p_c) * c_a + d_c
    if num <= 0.0 or den <= 0.0 or p_c <= 0.0:
        return combine(l_ca, l_da, l_cc, l_dc, lam_len)
    return num / (num + den), math.log((num * (1.0 - p_c)) / (den * p_c))


@nb.njit(cache=True)
def prism_table_cells(
    lam, tab_a, tab_b, weight_b, ray_of_cell, start, end, z0, z_max, fb, hq,
    t_lam, t_ku, t_x0, t_inv_h, t_off, t_len, t_z_end, t_z_infl, t_shift, t_log_z, t_log_far,
    nodes, log_wn, means, sigmas,
):
    """Tabulated PRISM: per cell, Hermite look-ups at both ends, linear in log(lambda) between two tables.

    ``nodes`` is (N, 4): normalised log C, its x-derivative, log D, its x-derivative (one cache line per
    node pair).

    Cells starting beyond the influence depth get increment 0; for a cell ending beyond the table (where
    the remaining evidence is below e^-40 of C), ``C(c) = Z`` and ``D(c)`` is integrated on the spot.
    """
    n = start.size
    post = np.empty(n)
    inc = np.empty(n)
    for i in range(n):
        r = ray_of_cell[i]
        ta = tab_a[r]
        tb = tab_b[r]
        w = weight_b[r]
        a = max(start[i], z0)
        c = min(end[i], z_max)
        z_end = min(t_z_end[ta], t_z_end[tb])
        if c <= a or a >= max(t_z_infl[ta], t_z_infl[tb]):
            post[i] = _one_minus_exp_neg(lam[r] * max(end[i] - start[i], 0.0))
            inc[i] = 0.0
            continue
        beyond = c > z_end
        c_in = min(c, z_end)
        lca = lda = lcc = ldc = 0.0
        for side in range(2):
            t = ta if side == 0 else tb
            wt = 1.0 - w if side == 0 else w
            if wt == 0.0:
                continue
            h = 1.0 / t_inv_h[t]
            k, f = _locate(a, t_lam[t], t_ku[t], t_x0[t], t_inv_h[t], t_len[t])
            o = t_off[t] + k
            lda += wt * _hermite(f, h, nodes[o, 2], nodes[o, 3], nodes[o + 1, 2], nodes[o + 1, 3])
            if k == 0:  # log C is -inf at z0: integrate the first interval
                if a > z0:
                    lca += wt * (log_integral(z0, a, t_lam[t], t_ku[t], hq, z0, fb, t_shift[t], log_wn, means, sigmas)
                                 - t_log_z[t])
                else:
                    lca = -np.inf
            else:
                lca += wt * _hermite(f, h, nodes[o, 0], nodes[o, 1], nodes[o + 1, 0], nodes[o + 1, 1])
            k, f = _locate(c_in, t_lam[t], t_ku[t], t_x0[t], t_inv_h[t], t_len[t])
            o = t_off[t] + k
            ldc += wt * _hermite(f, h, nodes[o, 2], nodes[o, 3], nodes[o + 1, 2], nodes[o + 1, 3])
            if k == 0:
                lcc += wt * (log_integral(z0, c_in, t_lam[t], t_ku[t], hq, z0, fb, t_shift[t], log_wn, means, sigmas)
                             - t_log_z[t])
            else:
                lcc += wt * _hermite(f, h, nodes[o, 0], nodes[o, 1], nodes[o + 1, 0], nodes[o + 1, 1])
        if beyond:  # the rest is below e^-40 of C: integrate it on the spot (rate of table a)
            lcc = 0.0
            ldc = log_tail(c, t_log_z[ta], t_lam[ta], t_ku[ta], hq, z0, z_max, fb, t_shift[ta], t_log_far[ta],
                           log_wn, means, sigmas) - t_log_z[ta]
        post[i], inc[i] = combine_fast(lca, lda, lcc, ldc, lam[r] * (c - a))
    return post, inc


@nb.njit(cache=True)
def prism_log_evidence(shift, lam, z0, z_max, fb, ku, hq, log_far, log_wn, means, sigmas):
    """``log Z`` (the marginal density of each measured disparity, 1/pixel) for every ray."""
    out = np.empty(shift.size)
    for r in range(shift.size):
        out[r] = prism_march(shift[r], lam[r], z0, z_max, fb, ku, hq, log_far[r], 0.0, 0, log_wn, means, sigmas)[3]
    return out
