"""numba kernels of the inverse sensor models; called only by the wrappers in this package.

The wrappers validate and convert (contiguous float64 / int64); the kernels assume. Every kernel releases
the GIL (``nogil=True``), so the grid's model calls run beside its GIL-free casting. PRISM carries
``log C`` and ``log D = log(Z - C)`` as logarithms so that nothing underflows from 0.1 m to 200 m with
surface rates up to 50 per metre; the tabulated cell update exponentiates the smaller of the two and
combines in linear space, except near underflow. Its exp and log are :func:`exp_into` and
:func:`log_into`: polynomial (Cephes) routines in loops LLVM vectorises, since neither numpy's float64
exp/log nor numba's ``math.exp`` is SIMD on a CPU without AVX-512 (numba would need Intel's SVML).
"""

import math

import numba as nb
import numpy as np
from numba.core import types
from numba.extending import intrinsic

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_LOG_W = np.log(_GL_W)
_SQRT_HALF = math.sqrt(0.5)
_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}  # never nnan/ninf: NaN marks values not looked up


# --------------------------------------------------------------------------------------------- helpers


@nb.njit(cache=True, nogil=True)
def logaddexp(a, b):
    """``log(exp(a) + exp(b))``, exact for -inf arguments."""
    if a < b:
        a, b = b, a
    if not b - a >= _EXP_ZERO:  # exp(b - a) is 0 (libm's slow underflow path): nothing to add
        return a
    return a + math.log1p(math.exp(b - a))


@nb.njit(cache=True, nogil=True)
def log1mexp(t):
    """``log(1 - exp(t))`` for ``t <= 0`` (``t > 0`` is treated as 0, giving -inf)."""
    if t >= 0.0:
        return -np.inf
    if t > -0.6931471805599453:
        return math.log(-math.expm1(t))
    return math.log1p(-math.exp(t))


@nb.njit(cache=True, nogil=True)
def normal_cdf(x):
    """Standard normal CDF."""
    return 0.5 * math.erfc(-x * _SQRT_HALF)


@nb.njit(cache=True, nogil=True)
def _logit(p):
    return math.log(p) - math.log1p(-p)


@nb.njit(cache=True, nogil=True)
def _sigmoid(x):
    if x >= 0.0:
        return 1.0 / (1.0 + math.exp(-x))
    e = math.exp(x)
    return e / (1.0 + e)


# ------------------------------------------------------------------------------ vectorisable exp, log
# Cephes' exp and log (S. L. Moshier, "Methods and programs for mathematical functions", 1989): range
# reduction by bit operations on the float64 representation, then a rational approximation. Written
# without calls and with selects instead of branches, so that a loop over an array of them vectorises
# (4 lanes with AVX2). ``error_model="numpy"``: numba's default checks every division for zero, a branch
# that stops the vectoriser. Never inline them into a fastmath function: reassociation turns the rounding
# ``(y / ln 2 + shifter) - shifter`` into ``y / ln 2`` and undoes the two-constant (Cody-Waite) reduction.


def _bitcast(source, target):
    """An intrinsic reinterpreting the bits of a ``source`` scalar as a ``target`` one (no instruction)."""

    @intrinsic
    def cast(typingctx, x):
        if x != source:
            return None

        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(target))

        return target(source), codegen

    return cast


_float_bits = _bitcast(types.float64, types.int64)
"""The IEEE-754 bits of a float64 as an int64."""
_bits_float = _bitcast(types.int64, types.float64)
"""The float64 whose IEEE-754 bits are the given int64."""


_LOG2E = 1.4426950408889634
_SHIFTER = 6755399441055744.0  # 1.5 * 2^52: adding it rounds to an integer held in the low mantissa bits
_LN2_HI = 6.93145751953125e-1  # ln 2 = _LN2_HI + _LN2_LO, _LN2_HI with a short mantissa (exact n * _LN2_HI)
_LN2_LO = 1.42860682030941723212e-6
_EXP_ZERO = -745.1332191019412  # below: exp rounds to 0
_EXP_MAX = 709.782712893384  # above: exp overflows
_EXP_NORMAL = -708.3964185322641  # below: exp is subnormal or 0, which added to a sum >= 1 changes nothing


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def fast_exp(x):
    """``exp(x)`` to 2 ulp (Cephes' Pade form on ``|r| <= ln(2) / 2``, ``x = n ln 2 + r``), subnormal results
    rounded once; 0 below -745.13, inf above 709.78, NaN for NaN."""
    y = min(max(x, _EXP_ZERO), _EXP_MAX)
    t = y * _LOG2E + _SHIFTER
    n = t - _SHIFTER  # round(y / ln 2)
    r = (y - n * _LN2_HI) - n * _LN2_LO
    rr = r * r
    p = r * ((1.26177193074810590878e-4 * rr + 3.02994407707441961300e-2) * rr + 9.99999999999999999910e-1)
    q = ((3.00198505138664455042e-6 * rr + 2.52448340349684104192e-3) * rr + 2.27265548208155028766e-1) * rr + 2.0
    k = _float_bits(t) - _float_bits(_SHIFTER)  # n as an integer, in [-1075, 1024]
    half = k >> 1  # 2^n as 2^half 2^(k - half): both normal at either end of the range
    out = (1.0 + 2.0 * p / (q - p)) * _bits_float((half + 1023) << 52) * _bits_float((k - half + 1023) << 52)
    out = 0.0 if x < _EXP_ZERO else out
    out = np.inf if x > _EXP_MAX else out
    return x if x != x else out


_SUBNORMAL_SCALE = 18014398509481984.0  # 2^54
_MANTISSA = 0x000FFFFFFFFFFFFF
_HALF_EXPONENT = 0x3FE0000000000000  # the exponent bits of 0.5
_EXPONENT_AS_FLOAT = 0x4330000000000000  # the bits of 2^52: OR an integer below 2^52 in, subtract 2^52
_TWO_52 = 4503599627370496.0
_SQRT_HALF_EXACT = 0.70710678118654752440


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def fast_log(x):
    """``log(x)`` to 2 ulp for every positive float64, subnormals included (Cephes' rational form on the
    mantissa in ``[sqrt(1/2), sqrt(2))``); -inf at 0, inf at inf, NaN below 0 and for NaN."""
    sub = x < 2.2250738585072014e-308
    b = _float_bits(x * _SUBNORMAL_SCALE if sub else x)
    # the exponent as a float without an int64 -> float64 conversion (AVX2 has none for packed int64)
    e = _bits_float(((b >> 52) & 0x7FF) | _EXPONENT_AS_FLOAT) - (_TWO_52 + 1022.0) - (54.0 if sub else 0.0)
    m = _bits_float((b & _MANTISSA) | _HALF_EXPONENT)  # x = m 2^e, m in [0.5, 1)
    low = m < _SQRT_HALF_EXACT
    e = e - 1.0 if low else e
    m = (m + m - 1.0) if low else (m - 1.0)
    z = m * m
    p = ((((1.01875663804580931796e-4 * m + 4.97494994976747001425e-1) * m + 4.70579119878881725854e0) * m
          + 1.44989225341610930846e1) * m + 1.79368678507819816313e1) * m + 7.70838733755885391666e0
    q = ((((m + 1.12873587189167450590e1) * m + 4.52279145837532221105e1) * m + 8.29875266912776603211e1) * m
         + 7.11544750618563894466e1) * m + 2.31251620126765340583e1
    y = m * (z * p / q) - e * 2.121944400546905827679e-4 - 0.5 * z
    out = (m + y) + e * 0.693359375
    if not (x > 0.0 and x < np.inf):
        out = -np.inf if x == 0.0 else (x if x == np.inf else np.nan)
    return out


@nb.njit(cache=True, nogil=True, error_model="numpy")
def exp_into(x, out, n):
    """``out[:n] = exp(x[:n])`` by :func:`fast_exp` (a vectorised loop)."""
    for i in range(n):
        out[i] = fast_exp(x[i])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def log_into(x, out, n):
    """``out[:n] = log(x[:n])`` by :func:`fast_log` (a vectorised loop)."""
    for i in range(n):
        out[i] = fast_log(x[i])


# ------------------------------------------------------------------------------------- classic models


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True, inline="always")
def _log_sum_exp_add(best, total, v):
    """One step of a streaming log-sum-exp: the sum so far is ``exp(best) * total``; add ``exp(v)``."""
    if v > best:
        return v, (total * math.exp(best - v) if best - v > _EXP_NORMAL else 0.0) + 1.0
    return best, total + (math.exp(v - best) if v - best > _EXP_NORMAL else 0.0)


@nb.njit(cache=True, nogil=True)
def log_likelihood(u, shift, log_wn, means, sigmas):
    """``log g``: the mixture density of the error ``u - shift`` (``u`` = true disparity + 0, pixels)."""
    best = -np.inf
    total = 0.0
    for j in range(means.size):
        t = (u - shift - means[j]) / sigmas[j]
        best, total = _log_sum_exp_add(best, total, log_wn[j] - 0.5 * t * t)
    return best + math.log(total)


@nb.njit(cache=True, nogil=True)
def _log_sup_tail(z, z_max, fb, shift, log_wn, means, sigmas):
    """Log of an upper bound of ``g`` on true depths ``[z, z_max]`` (sum of per-component maxima)."""
    u_hi = fb / z
    u_lo = fb / z_max
    best = -np.inf
    total = 0.0
    for j in range(means.size):
        mode = min(max(shift + means[j], u_lo), u_hi)
        t = (mode - shift - means[j]) / sigmas[j]
        best, total = _log_sum_exp_add(best, total, log_wn[j] - 0.5 * t * t)
    return best + math.log(total)


@nb.njit(cache=True, nogil=True)
def x_of_z(z, lam, ku):
    return lam * z - ku / z


@nb.njit(cache=True, nogil=True)
def z_of_x(x, lam, ku):
    root = math.sqrt(x * x + 4.0 * lam * ku)
    if x >= 0.0:
        return (x + root) / (2.0 * lam)
    return 2.0 * ku / (root - x)


@nb.njit(cache=True, nogil=True)
def _log_panel_moments(z1, z2, lam, z0, fb, shift, log_wn, means, sigmas):
    """Logs of ``int_{z1}^{z2} (z - z0)^k q g dz``, k = 0, 1, 2, by 8-point Gauss-Legendre (one panel)."""
    half = 0.5 * (z2 - z1)
    if half <= 0.0:
        return -np.inf, -np.inf, -np.inf
    mid = 0.5 * (z1 + z2)
    best = -np.inf
    m0 = m1 = m2 = 0.0
    log_lam = math.log(lam)
    for i in range(8):
        z = mid + half * _GL_X[i]
        s = z - z0
        v = _GL_LOG_W[i] + log_lam - lam * s + log_likelihood(fb / z, shift, log_wn, means, sigmas)
        if v > best:
            scale = math.exp(best - v)
            m0 *= scale
            m1 *= scale
            m2 *= scale
            best = v
            e = 1.0
        else:
            e = math.exp(v - best)
        m0 += e
        m1 += e * s
        m2 += e * s * s
    base = best + math.log(half)
    return base + math.log(m0), base + math.log(m1), base + math.log(m2)


@nb.njit(cache=True, nogil=True)
def _log_panel(z1, z2, lam, z0, fb, shift, log_wn, means, sigmas):
    """Log of ``int_{z1}^{z2} q g dz`` by 8-point Gauss-Legendre (one panel)."""
    return _log_panel_moments(z1, z2, lam, z0, fb, shift, log_wn, means, sigmas)[0]


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
def prism_march(shift, lam, z0, z_max, fb, ku, hq, log_far, log_eps_bound, lam_slack, i_min, log_wn, means, sigmas):
    """Cumulative evidence of one (d^, lam) on the x-grid of spacing ``hq`` from ``z0``.

    Returns ``z`` (nodes); ``log_c`` (n, 3): logs of ``C`` and of its moments ``int_{z0}^{z} (t - z0)^k q g dt``
    (k = 1, 2) at the nodes, not normalised; ``log_d`` (n, 3): the same beyond ``z`` (the far measurement
    counted as a mass at ``z_max``); ``log Z``; the log of the far term ``e^{-lam (z_max - z0)} g_far``
    (-inf when the march stopped early); and the index of the first node from which every later cell's
    increment is bounded by epsilon (``log_eps_bound`` = ``log(expm1(epsilon))``) for every rate within a
    factor ``1 +- lam_slack`` of ``lam``. The march stops (not before node ``i_min``) once the remaining
    evidence is below e^-40 of ``C``.
    """
    return _march(shift, lam, z0, z0, np.full(3, -np.inf), np.zeros(3, dtype=np.int64), hq, z_max, fb, ku, hq,
                  log_far, log_eps_bound, lam_slack, i_min, 1, log_wn, means, sigmas)[:6]


@nb.njit(cache=True, nogil=True, inline="always")
def _march_x(i, x0, counts, h_wide, h):
    """x of node ``i`` of a march from ``x0`` whose panels are ``counts[0]`` of ``h_wide``, ``counts[1]`` of
    ``h``, ``counts[2]`` of ``h_wide``, then ``h``."""
    widths = (h_wide, h, h_wide)
    x = x0
    for r in range(3):
        if i <= counts[r]:
            return x + i * widths[r]
        x += counts[r] * widths[r]
        i -= counts[r]
    return x + i * h


_MARCH_BLOCK = 16
"""Panels a march evaluates at once (:func:`_log_panel_block`): 288 exps in vectorised loops for a 3-component
mixture; the march's stop wastes at most this many less one."""
_MARCH_GL = 6
"""Gauss-Legendre points of a march's panel: on half a narrowest sigma (or, in a broad segment, a quarter of the
widest sigma, at most half a prior e-fold) the rule's relative error is below about 1e-10 where the integrand
matters, and below 5e-8 ten sigmas out (the direct method's 8 points on half as wide panels are the reference)."""
_MARCH_GL_X, _MARCH_GL_W = np.polynomial.legendre.leggauss(_MARCH_GL)
_MARCH_GL_LOG_W = np.log(_MARCH_GL_W)


_EXP_TERM_FLOOR = -700.0


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _exp_term(x):
    """``exp(x)`` (:func:`fast_exp`) for a term of a sum of at least 1: below e^-700 it is e^-700, which adds
    nothing to such a sum, instead of a subnormal or 0 (subnormal arithmetic costs about a hundred cycles)."""
    return fast_exp(max(x, _EXP_TERM_FLOOR))


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _log_panel_block(z, first, count, lam, z0, fb, shift, log_wn, means, inv_sigmas, out, scratch):
    """Logs of ``int_{z[i-1]}^{z[i]} (t - z0)^k q g dt`` (k = 0, 1, 2) into ``out[i]`` for ``count`` panels from
    ``i = first``, by :data:`_MARCH_GL`-point Gauss-Legendre, each panel's terms scaled by its largest one, in
    loops over all the block's points that LLVM vectorises (exps by :func:`_exp_term`). ``scratch``:
    (J + 5, _MARCH_GL _MARCH_BLOCK) float64, J = ``means.size``."""
    n_gl = _MARCH_GL
    n_pts = n_gl * count
    n_comp = means.size
    s = scratch[n_comp]
    u = scratch[n_comp + 1]
    base = scratch[n_comp + 2]
    top = scratch[n_comp + 3]
    w = scratch[n_comp + 4]
    for q in range(n_pts):
        i = first + q // n_gl
        half = 0.5 * (z[i] - z[i - 1])
        zq = z[i - 1] + half + half * _MARCH_GL_X[q % n_gl]
        s[q] = zq - z0
        u[q] = fb / zq - shift
        base[q] = _MARCH_GL_LOG_W[q % n_gl] - lam * s[q]
        top[q] = -np.inf
        w[q] = 0.0
    for j in range(n_comp):
        e = scratch[j]
        for q in range(n_pts):
            t = (u[q] - means[j]) * inv_sigmas[j]
            e[q] = base[q] + log_wn[j] - 0.5 * t * t
            top[q] = max(top[q], e[q])
    for p in range(count):  # each panel's largest term, at each of its points
        m = top[n_gl * p]
        for q in range(n_gl * p + 1, n_gl * (p + 1)):
            m = max(m, top[q])
        for q in range(n_gl * p, n_gl * (p + 1)):
            top[q] = m
    for j in range(n_comp):
        e = scratch[j]
        for q in range(n_pts):
            w[q] += _exp_term(e[q] - top[q])
    log_lam = math.log(lam)
    for p in range(count):
        m0 = m1 = m2 = 0.0
        for q in range(n_gl * p, n_gl * (p + 1)):
            ws = w[q] * s[q]
            m0 += w[q]
            m1 += ws
            m2 += ws * s[q]
        i = first + p
        out[i, 0], out[i, 1], out[i, 2] = m0, m1, m2
        base[p] = top[n_gl * p] + log_lam + math.log(0.5 * (z[i] - z[i - 1]))
    for i in range(first, first + count):
        for k in range(3):
            out[i, k] = fast_log(out[i, k])
    for p in range(count):
        for k in range(3):
            out[first + p, k] += base[p]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _log_sup_tail_block(z, first, count, z_max, fb, shift, log_wn, means, inv_sigmas, out, scratch):
    """:func:`_log_sup_tail` at ``z[first:first + count]`` into ``out[first:...]``, in vectorised loops (exps by
    :func:`_exp_term`); ``scratch`` as :func:`_log_panel_block`'s."""
    n_comp = means.size
    u_lo = fb / z_max
    top = scratch[n_comp]
    total = scratch[n_comp + 1]
    for q in range(count):
        top[q] = -np.inf
        total[q] = 0.0
    for j in range(n_comp):
        e = scratch[j]
        for q in range(count):
            mode = min(max(shift + means[j], u_lo), fb / z[first + q])
            t = (mode - shift - means[j]) * inv_sigmas[j]
            e[q] = log_wn[j] - 0.5 * t * t
            top[q] = max(top[q], e[q])
    for j in range(n_comp):
        e = scratch[j]
        for q in range(count):
            total[q] += _exp_term(e[q] - top[q])
    for q in range(count):
        out[first + q] = top[q] + fast_log(total[q])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _log_cumsum_block(terms, out, first, count, step, scratch):
    """``out[i] = log(e^out[i - step] + e^terms[i'])`` row by row (3 columns each) for ``count`` rows ``i = first,
    first + step, ...`` (``step`` +1 or -1; ``i' = i`` forward, ``i + 1`` backward: a cumulative log-sum-exp
    either way): in linear space against each column's largest value, exps and logs in vectorised loops, where
    no finite value of the block lies more than e^690 below that largest (nothing underflows), else by
    :func:`logaddexp` row by row. ``scratch``: (3 count,) float64 or longer."""
    shift_in = 0 if step > 0 else 1
    top = np.empty(3)
    for k in range(3):
        top[k] = out[first - step, k]
    for j in range(count):
        i = first + j * step + shift_in
        for k in range(3):
            top[k] = max(top[k], terms[i, k])
    linear = True
    for k in range(3):
        floor = top[k] - 690.0
        if top[k] == -np.inf or (out[first - step, k] > -np.inf and out[first - step, k] < floor):
            linear = False
        for j in range(count):
            v = terms[first + j * step + shift_in, k]
            if v > -np.inf and v < floor:
                linear = False
    if not linear:
        for j in range(count):
            i = first + j * step
            for k in range(3):
                out[i, k] = logaddexp(out[i - step, k], terms[i + shift_in, k])
        return
    for j in range(count):
        i = first + j * step + shift_in
        for k in range(3):
            scratch[3 * j + k] = fast_exp(terms[i, k] - top[k])
    for k in range(3):
        acc = fast_exp(out[first - step, k] - top[k])
        for j in range(count):
            acc += scratch[3 * j + k]
            scratch[3 * j + k] = acc
    for q in range(3 * count):
        scratch[q] = fast_log(scratch[q])
    for j in range(count):
        for k in range(3):
            out[first + j * step, k] = top[k] + scratch[3 * j + k]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _march(shift, lam, z0, z_start, log_c_start, counts, h_wide, z_max, fb, ku, hq, log_far, log_eps_bound,
           lam_slack, i_min, far_ratio, log_wn, means, sigmas):
    """:func:`prism_march` from ``z_start``, where the moments of C are ``log_c_start`` (3,), on panels of
    x-width ``h_wide`` (``counts[0]``: a table's broad front), ``hq`` (``counts[1]``), ``h_wide``
    (``counts[2]``: its broad back), then ``hq`` (:func:`_march_x`), and with ``far_ratio > 1`` from the first
    node of that last run past the influence node (``i_far``, -1 if none) panels about ``far_ratio`` times
    wider to the end, a multiple of 4 of them, all of one width ``h_far``, and the march stops only on every 4th
    of them (a table's back: 4 equal intervals from ``i_far``). Past the influence depth ``D < (e^eps - 1) C``,
    so ``D``'s relative error there (below about 2e-3 on panels of x-width 2 a narrow component 5 sigmas
    away, far less elsewhere) moves a cell's increment by a thousandth of it. Panels and tail bounds are
    evaluated :data:`_MARCH_BLOCK` at a time (:func:`_log_panel_block`, :func:`_log_sup_tail_block`), the
    running sums and the stop node by node. Returns :func:`prism_march`'s values, then ``i_far`` and ``h_far``."""
    x0 = x_of_z(z_start, lam, ku)
    x_end = x_of_z(z_max, lam, ku)
    last = counts[0] + counts[1] + counts[2]
    n_max = last + max(1, int(math.ceil((x_end - _march_x(last, x0, counts, h_wide, hq)) / hq)))
    fine_run = last if counts[2] > 0 else counts[0]  # first node of the run of hq panels that ends the march
    z = np.empty(n_max + 1)
    log_c = np.full((n_max + 1, 3), -np.inf)
    log_c[0] = log_c_start
    panel = np.full((n_max + 1, 3), -np.inf)
    sup = np.empty(n_max + 1)
    inv_sigmas = 1.0 / sigmas
    scratch = np.empty((means.size + 5, _MARCH_GL * _MARCH_BLOCK))
    z[0] = z_start
    i_infl = -1
    i_far = -1
    x_far = h_far = hq
    n = n_max
    stopped = False
    tail = -np.inf
    slack = -math.log1p(-lam_slack)  # a rate lam (1 - s) has C(a) >= (1 - s) C(a; lam)
    first = 1
    while first <= n_max and not stopped:
        count = min(_MARCH_BLOCK, n_max + 1 - first)
        for i in range(first, first + count):
            if i == n_max:
                z[i] = z_max
            elif i_far >= 0:
                z[i] = z_of_x(x_far + (i - i_far) * h_far, lam, ku)
            else:
                z[i] = z_of_x(_march_x(i, x0, counts, h_wide, hq), lam, ku)
        _log_panel_block(z, first, count, lam, z0, fb, shift, log_wn, means, inv_sigmas, panel, scratch)
        _log_sup_tail_block(z, first, count, z_max, fb, shift, log_wn, means, inv_sigmas, sup, scratch)
        _log_cumsum_block(panel, log_c, first, count, 1, scratch[0])
        following = first + count
        for i in range(first, first + count):
            bound = -lam * (z[i] - z0) + max(sup[i], log_far)
            if i_infl < 0 and bound + lam_slack * lam * (z[i] - z0) + slack - log_c[i, 0] < log_eps_bound:
                i_infl = i
            if (i < n_max and i >= i_min and (i_far < 0 or (i - i_far) % 4 == 0)
                    and bound - log_c[i, 0] < -40.0):
                n = i
                tail = bound
                stopped = True
                break
            if far_ratio > 1 and i_far < 0 and 0 <= i_infl < i and i >= fine_run:
                x_i = _march_x(i, x0, counts, h_wide, hq)
                if x_end - x_i >= 8.0 * far_ratio * hq:  # room to spare in the arrays
                    i_far = i
                    x_far = x_i
                    n_far = 4 * int(math.ceil((x_end - x_i) / (4.0 * far_ratio * hq)))
                    h_far = (x_end - x_i) / n_far
                    n_max = n = i + n_far
                    following = i + 1
                    break
        first = following
    log_far_w = -np.inf
    if not stopped:
        tail = log_far_w = -lam * (z_max - z0) + log_far
        if i_infl < 0:
            i_infl = n_max
    log_d = np.empty((n + 1, 3))
    log_s = math.log(z[n] - z0)
    for k in range(3):
        log_d[n, k] = tail + k * log_s
    for last_row in range(n - 1, -1, -_MARCH_BLOCK):
        _log_cumsum_block(panel, log_d, last_row, min(_MARCH_BLOCK, last_row + 1), -1, scratch[0])
    log_z = logaddexp(log_c[n, 0], tail)
    return z[: n + 1], log_c[: n + 1], log_d, log_z, log_far_w, i_infl, i_far, h_far


@nb.njit(cache=True, nogil=True)
def _rate_derivatives(log_m, log_far, lam, z_far):
    """First and second derivatives of ``log Q`` in ``log lam`` from the logs of Q's moments (``log_m`` (3,)).

    ``Q = J + F``: ``J = int lam e^{-lam s} g`` has moments ``M_k``; the far term ``F = e^{-lam L} g_far``
    (``L = z_far``, log -inf when absent) carries no factor ``lam``. For one mass at ``s``,
    ``J' = J (1 - lam s)`` and ``J'' = J (1 - 3 lam s + lam^2 s^2)``; ``F' = -lam L F``,
    ``F'' = (lam^2 L^2 - lam L) F``.
    """
    far = math.exp(log_far - log_m[0])
    m1 = lam * math.exp(log_m[1] - log_m[0])
    m2 = lam * lam * math.exp(log_m[2] - log_m[0])
    lam_l = lam * z_far
    j = 1.0 - far
    m1 -= far * lam_l
    m2 -= far * lam_l * lam_l
    first = j - m1 - far * lam_l
    second = j - 3.0 * m1 + m2 + far * (lam_l * lam_l - lam_l)
    return first, second - first * first


@nb.njit(cache=True, nogil=True)
def _rate_columns(slope, first, second, z_1, z_2, lam_s):
    """A node's three rate columns for ``log(Q/Z)`` (Q is C or D): its first log(lam)-derivative, that one's
    x-derivative, and its second log(lam)-derivative.

    ``first``, ``second`` are Q's own (:func:`_rate_derivatives`), ``z_1``, ``z_2`` Z's, ``slope`` is
    ``d log Q/dx`` and ``lam_s = lam (z - z0)``. As ``dQ/dz = +-q g`` and ``d log(q g)/d log lam = 1 - lam s``
    at fixed z, ``d first/dx = slope (1 - lam s - first)`` (Z's derivatives do not depend on z): the exact
    slope, so that the first-order term is cubic Hermite in x like the value, and a short cell's share
    ``C(c) - C(a)`` follows the rate where ``log C`` grows slowly (in front of the measurement), where the
    secant slope of a linear interpolation is off by up to 25 % of it.
    """
    return first - z_1, slope * (1.0 - lam_s - first), second - z_2


_STEEP = 0.02
"""Bound on ``|phi''| / phi'^2`` (``phi = log(q g)``), the relative error of the endpoint asymptotic of C that
a table's coarse front uses."""

TABLE_COLUMNS = 10
"""Columns of a PRISM table node: log(C/Z), its x-derivative, its first log(lambda)-derivative and that one's
x-derivative, its second log(lambda)-derivative; then the same five for ``D = Z - C`` (from column
:data:`_D_COLUMN`). 40 bytes in float32."""
_D_COLUMN = TABLE_COLUMNS // 2


@nb.njit(cache=True, nogil=True)
def _log_qg_slope(z, lam, z0, fb, shift, log_wn, means, sigmas):
    """``log(q g)`` at depth ``z`` and its derivative in z (1/metre)."""
    u = fb / z
    best = -np.inf
    total = 0.0
    slope = 0.0  # sum of weights times d log N_j / du
    for j in range(means.size):
        t = (u - shift - means[j]) / sigmas[j]
        v = log_wn[j] - 0.5 * t * t
        if v > best:
            scale = math.exp(best - v)
            total *= scale
            slope *= scale
            best = v
            e = 1.0
        else:
            e = math.exp(v - best)
        total += e
        slope -= e * t / sigmas[j]
    return math.log(lam) - lam * (z - z0) + best + math.log(total), -lam - slope / total * fb / (z * z)


@nb.njit(cache=True, nogil=True)
def _log_c_asymptotic(z, lam, z0, fb, shift, log_wn, means, sigmas):
    """``log C(z)`` where ``q g`` rises steeply: ``C = q g / (d log(q g)/dz) (1 + O(phi''/phi'^2))``."""
    phi, phi_z = _log_qg_slope(z, lam, z0, fb, shift, log_wn, means, sigmas)
    return phi - math.log(phi_z)


_FAR_RATIO = 4
"""A table's march past its influence node: panels about this many times the fine width (:func:`_march`)."""

N_SEGMENTS = 6
"""Segments of a table's node grid, each uniform in x: coarse front, broad front, fine, broad back, fine, back."""


@nb.njit(cache=True, nogil=True)
def prism_table(shift, lam, z0, z_max, fb, ku, h, log_far, log_eps_bound, lam_slack, coarse_ratio, coarse_below,
                e_front, e_back, wide_ratio, wide_efolds, log_wn, means, sigmas):
    """The table of one (d^, lam): a node per march panel, every ``coarse_ratio``-th one where C/Z is tiny.

    Node columns (see :data:`TABLE_COLUMNS`): ``log(C/Z)``, ``d log(C/Z)/dx``, the first and second
    derivatives of ``log(C/Z)`` in ``log lam`` (from the moments, :func:`_rate_derivatives`), the first one
    followed by its x-derivative (:func:`_rate_columns`), and the same five for ``D = Z - C``. Nodes are uniform
    in x on each of :data:`N_SEGMENTS` segments: spacing
    ``H = coarse_ratio h`` up to ``x_split``; ``H_wide = wide_ratio h`` over the broad front (true
    disparities above ``shift + e_front``); ``h``; ``H_wide`` over the broad back (below ``shift + e_back``),
    both only where an interval spans at most ``wide_efolds`` prior e-folds; ``h``; then, from a node past
    the influence depth (beyond which only the cells that straddle it look up), four equal intervals to
    the end of the march. The march's panels are the node intervals (:data:`_MARCH_GL`-point Gauss-Legendre
    is exact far below the tolerance on half a narrowest sigma, and on a broad segment, where only the widest
    error component is not negligible, on a quarter of its sigma), and past the influence node, where only the
    four back intervals remain, :data:`_FAR_RATIO` times wider (:func:`_march`).

    Before ``x_split`` ``q g`` rises steeply (``|phi''| / phi'^2 < _STEEP``, ``phi = log(q g)``) and
    ``C/Z < e^coarse_below``: there ``C`` is its endpoint (Laplace) asymptotic ``q g / (q g)'`` (relative
    error about ``phi''/phi'^2``), all its mass at ``z``; quadrature starts at ``x_split``.

    Returns
    -------
    nodes : (N, TABLE_COLUMNS) float64
    meta : (3 N_SEGMENTS + 5,) float64
        Per segment its first x, its first row and its spacing; then ``z_end`` (last node), ``z_infl``,
        ``log Z`` and its first and second derivatives in ``log lam`` (a ray's ``log Z`` by the Taylor
        term of the nodes, for the look-ups that integrate on the spot at the ray's own rate).
    """
    h_coarse = coarse_ratio * h
    h_wide = wide_ratio * h
    x0 = x_of_z(z0, lam, ku)
    x_end = x_of_z(z_max, lam, ku)
    x_front = x0  # broad front: [x_split, x_front); broad back: [x_back_wide, x_lam)
    x_back_wide = x_lam = x_end
    if wide_ratio > 1:
        if h_wide > wide_efolds:  # an interval spans dz = h_wide / (lam + ku / z^2)
            x_lam = min(x_end, x_of_z(math.sqrt(ku / (lam * (h_wide / wide_efolds - 1.0))), lam, ku))
        u_front = shift + e_front
        u_back = shift + e_back
        if e_front == -np.inf or u_front <= fb / z_max:
            x_front = x_end
        elif u_front < np.inf:
            x_front = x_of_z(fb / u_front, lam, ku)
        if u_back == np.inf:
            x_back_wide = x0
        elif u_back > fb / z_max:
            x_back_wide = x_of_z(fb / u_back, lam, ku)
    x_front = min(x_front, x_lam, x_end - 4.0 * h_wide)  # the fine part keeps a few panels before z_max
    x_back_wide = min(x_back_wide, x_end - 2.0 * h)
    n_steep = 0  # coarse nodes after z0 where q g is steep
    while x0 + (n_steep + 2) * h_coarse < x_end:
        z = z_of_x(x0 + (n_steep + 1) * h_coarse, lam, ku)
        slope = _log_qg_slope(z, lam, z0, fb, shift, log_wn, means, sigmas)[1]
        curvature = (_log_qg_slope(z * (1.0 + 1e-5), lam, z0, fb, shift, log_wn, means, sigmas)[1]
                     - _log_qg_slope(z * (1.0 - 1e-5), lam, z0, fb, shift, log_wn, means, sigmas)[1]) / (2e-5 * z)
        if not slope > 0.0 or abs(curvature) > _STEEP * slope * slope:
            break
        n_steep += 1
    log_c_start = np.full(3, -np.inf)
    counts = np.zeros(3, dtype=np.int64)
    n_coarse = n_steep
    log_z = np.nan
    while True:  # once, or twice if the first Z shows the steep part reaching above e^coarse_below
        x_split = x0 + n_coarse * h_coarse
        z_split = z_of_x(x_split, lam, ku) if n_coarse > 0 else z0
        if n_coarse > 0:
            log_c = _log_c_asymptotic(z_split, lam, z0, fb, shift, log_wn, means, sigmas)
            log_s = math.log(z_split - z0)
            for k in range(3):
                log_c_start[k] = log_c + k * log_s
        counts[0] = max(int((x_front - x_split) / h_wide), 0)
        x_fine = x_split + counts[0] * h_wide
        counts[1] = max(int(math.ceil((x_back_wide - x_fine) / h)), 1)
        x_fine += counts[1] * h
        counts[2] = max(int((min(x_lam, x_end - h) - x_fine) / h_wide), 0)
        z, log_c, log_d, log_z, log_far_w, i_infl, i_far, h_far = _march(
            shift, lam, z0, z_split, log_c_start, counts, h_wide, z_max, fb, ku, h, log_far, log_eps_bound,
            lam_slack, counts[0] + 2, _FAR_RATIO, log_wn, means, sigmas,
        )
        fit = n_coarse
        while fit > 0 and _log_c_asymptotic(z_of_x(x0 + fit * h_coarse, lam, ku), lam, z0, fb, shift, log_wn,
                                            means, sigmas) - log_z >= coarse_below:
            fit -= 1
        if fit == n_coarse:
            break
        n_coarse = fit
    n = z.size - 1
    starts = np.array([0, counts[0], counts[0] + counts[1], counts[0] + counts[1] + counts[2]])  # march regions
    widths = np.array([h_wide, h, h_wide, h])
    last = 3
    while starts[last] >= n:
        last -= 1
    uniform = starts[last]  # first node of the uniform run of panels that ends the march
    for r in range(last - 1, -1, -1):
        if starts[r] < starts[r + 1]:
            if widths[r] != widths[last]:
                break
            uniform = starts[r]
    # fine up to a node past the influence depth, then 4 equal intervals to the end (on the march's nodes)
    first_back = max(min(i_infl + 1, n), uniform)
    back_width = widths[last]
    if i_far >= 0:  # the march's far panels: 4 equal intervals of them from i_far
        first_back = i_far
        back_width = h_far
    back = (n - first_back) // 4
    n_back = 4 if back > 0 else 0
    i_back = n - n_back * back
    z_far = z_max - z0 if log_far_w > -np.inf else z[-1] - z0
    log_total = np.empty(3)
    for k in range(3):
        log_total[k] = logaddexp(log_c[-1, k], log_d[-1, k])
    z_1, z_2 = _rate_derivatives(log_total, log_far_w, lam, z_far)
    nodes = np.empty((n_coarse + i_back + 1 + n_back, TABLE_COLUMNS))
    row_c = np.empty(3)
    row_d = np.empty(3)
    for row in range(nodes.shape[0]):
        slope_c = np.nan
        xi = x0 + row * h_coarse
        if 0 < row <= n_coarse:  # the slope of the asymptotic, also at x_split (the end of a coarse interval)
            slope_c = (_log_c_asymptotic(z_of_x(xi + 0.25 * h, lam, ku), lam, z0, fb, shift, log_wn, means, sigmas)
                       - _log_c_asymptotic(z_of_x(xi - 0.25 * h, lam, ku), lam, z0, fb, shift, log_wn, means,
                                           sigmas)) / (0.5 * h)
        if row < n_coarse:
            zi = z_of_x(xi, lam, ku) if row > 0 else z0
            row_c[:] = -np.inf
            if row > 0:
                log_c_z = _log_c_asymptotic(zi, lam, z0, fb, shift, log_wn, means, sigmas)
                log_s = math.log(zi - z0)
                for k in range(3):
                    row_c[k] = log_c_z + k * log_s
            for k in range(3):  # D = everything minus the (tiny) C
                row_d[k] = log_total[k] + log1mexp(row_c[k] - log_total[k])
        else:
            i = row - n_coarse if row <= n_coarse + i_back else i_back + (row - n_coarse - i_back) * back
            zi = z[i]
            row_c[:] = log_c[i]
            row_d[:] = log_d[i]
        log_qg = math.log(lam) - lam * (zi - z0) + log_likelihood(fb / zi, shift, log_wn, means, sigmas)
        dx_dz = lam + ku / (zi * zi)
        lam_s = lam * (zi - z0)
        nodes[row, 0] = row_c[0] - log_z
        if row_c[0] == -np.inf:
            nodes[row, 1:_D_COLUMN] = 0.0
        else:
            nodes[row, 1] = slope_c if not math.isnan(slope_c) else math.exp(log_qg - row_c[0]) / dx_dz
            c_1, c_2 = _rate_derivatives(row_c, -np.inf, lam, z_far)
            nodes[row, 2], nodes[row, 3], nodes[row, 4] = _rate_columns(nodes[row, 1], c_1, c_2, z_1, z_2, lam_s)
        d_1, d_2 = _rate_derivatives(row_d, log_far_w, lam, z_far)
        nodes[row, _D_COLUMN] = row_d[0] - log_z
        nodes[row, _D_COLUMN + 1] = -math.exp(log_qg - row_d[0]) / dx_dz
        nodes[row, _D_COLUMN + 2], nodes[row, _D_COLUMN + 3], nodes[row, _D_COLUMN + 4] = _rate_columns(
            nodes[row, _D_COLUMN + 1], d_1, d_2, z_1, z_2, lam_s)
    nodes[0, 2:_D_COLUMN] = nodes[1, 2:_D_COLUMN]
    meta = np.empty(3 * N_SEGMENTS + 5)
    x_march = x_of_z(z[0], lam, ku)
    meta[0], meta[N_SEGMENTS], meta[2 * N_SEGMENTS] = x0, 0, h_coarse
    for r in range(4):
        i = min(starts[r], i_back)
        meta[1 + r] = _march_x(i, x_march, counts, h_wide, h)
        meta[N_SEGMENTS + 1 + r] = n_coarse + i
        meta[2 * N_SEGMENTS + 1 + r] = widths[r]
    meta[N_SEGMENTS - 1] = _march_x(i_back, x_march, counts, h_wide, h)
    meta[2 * N_SEGMENTS - 1] = n_coarse + i_back
    meta[3 * N_SEGMENTS - 1] = max(back, 1) * back_width
    meta[3 * N_SEGMENTS:] = z[n], z[i_infl], log_z, z_1, z_2
    return nodes, meta


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True, inline="always")
def pass_through_log(inc, lam_len, m):
    """Posterior and increment of a cell that a ray passes with probability ``m`` when it is occupied.

    The cell's likelihood ratio ``R = e^inc`` (occupied, the surface stopping the ray, against free)
    becomes ``m + (1 - m) R``; the posterior follows with the cell's prior ``1 - e^-lam_len``.
    """
    thinned = logaddexp(math.log(m), math.log1p(-m) + inc)
    return _sigmoid(log1mexp(-lam_len) + lam_len + thinned), thinned


@nb.njit(cache=True, nogil=True)
def log_tail(z, log_c_z, lam, ku, hq, z0, z_max, fb, shift, log_far, log_wn, means, sigmas, log_rest=-40.0):
    """``log D(z)``: evidence beyond ``z`` (far measurement included), marched until the rest is below
    ``e^log_rest`` of ``C(z)`` plus the march so far."""
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
        if za < z_max and bound - acc < log_rest:
            return logaddexp(tail, bound)
    return logaddexp(tail, -lam * (z_max - z0) + log_far)


@nb.njit(cache=True, nogil=True)
def prism_direct_cells(
    shift, lam, order, ray_start, start, end, z0, z_max, fb, ku, hq, log_far, log_wn, means, sigmas, pass_through
):
    """Continuous PRISM by quadrature, ray by ray: exact C and D at every distinct cell boundary.

    ``pass_through``: the chance that a ray passes an occupied cell (:func:`pass_through_log`; 0: never).

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
            lam_len = lam[r] * (c - a)
            post[i], inc[i] = combine(log_c[ia], log_d[ia], log_c[ic], log_d[ic], lam_len)
            if pass_through > 0.0:
                post[i], inc[i] = pass_through_log(inc[i], lam_len, pass_through)
    return post, inc


_PACK_ROWS = 192
"""Rows a table :func:`prism_tables` makes room for at first (a street table has about 170)."""

META_COLUMNS = ("lam", *(f"x_{k}" for k in range(N_SEGMENTS)), *(f"row_{k}" for k in range(N_SEGMENTS)),
                *(f"h_{k}" for k in range(N_SEGMENTS)), "z_end", "z_infl", "log_z", "log_z_1", "log_z_2", "shift", "log_far",
                "offset", "length")
"""Columns of the per-table metadata matrix that :func:`prism_table_lookup` reads (one row per table): the
rate, :func:`prism_table`'s meta (per segment its first x, first row and spacing, then ``z_end``, ``z_infl``,
``log Z`` and its two derivatives in ``log lam``), then the shift, far term, first row and row count of its nodes."""
_LAM, _X, _ROW, _SPACING = 0, 1, 1 + N_SEGMENTS, 1 + 2 * N_SEGMENTS
_Z_END, _Z_INFL, _LOG_Z, _LOG_Z_1, _LOG_Z_2, _SHIFT, _LOG_FAR, _OFFSET, _LENGTH = range(1 + 3 * N_SEGMENTS,
                                                                                      10 + 3 * N_SEGMENTS)


@nb.njit(cache=True, nogil=True)
def prism_tables(shifts, lams, log_fars, z0, z_max, fb, ku, h, log_eps_bound, lam_slack, coarse_ratio, coarse_below,
                 e_front, e_back, wide_ratio, wide_efolds, log_wn, means, sigmas):
    """:func:`prism_table` of every ``(shifts[k], lams[k], log_fars[k])``, packed for the table cache.

    Returns ``nodes`` (N, :data:`TABLE_COLUMNS`) float32, every table's rows back to back (their rounding is
    far below ``TABLE_TOLERANCE``), and ``meta`` (K, ``len(META_COLUMNS)``) float64, one row per table
    (``offset``: its first row in ``nodes``). One call builds a batch without a Python step per table, each
    table packed as soon as it is built (its float64 rows reuse the memory of the one before: holding a whole
    batch in float64 first doubles its memory and page faults), into room for :data:`_PACK_ROWS` rows a table
    that grows by half when full; ``nodes`` may be a view of that room.
    """
    n_tables = shifts.size
    meta = np.empty((n_tables, _LENGTH + 1))
    packed = np.empty((_PACK_ROWS * n_tables, TABLE_COLUMNS), dtype=np.float32)
    total = 0
    for k in range(n_tables):
        nodes, table_meta = prism_table(shifts[k], lams[k], z0, z_max, fb, ku, h, log_fars[k], log_eps_bound,
                                        lam_slack, coarse_ratio, coarse_below, e_front, e_back, wide_ratio,
                                        wide_efolds, log_wn, means, sigmas)
        rows = nodes.shape[0]
        if total + rows > packed.shape[0]:
            grown = np.empty((max(total + rows, packed.shape[0] + packed.shape[0] // 2), TABLE_COLUMNS),
                             dtype=np.float32)
            grown[:total] = packed[:total]
            packed = grown
        packed[total : total + rows] = nodes
        meta[k, _LAM] = lams[k]
        meta[k, _X : _SHIFT] = table_meta
        meta[k, _SHIFT] = shifts[k]
        meta[k, _LOG_FAR] = log_fars[k]
        meta[k, _OFFSET] = total
        meta[k, _LENGTH] = rows
        total += rows
    return packed[:total], meta


@nb.njit(cache=True, nogil=True, inline="always")
def _locate(x, s, seg_x, seg_row, seg_inv, n_seg):
    """Row (from the table's first) of the node left of ``x``, the fraction to the next, and the segment:
    the last of the ``n_seg`` non-empty segments (``seg_x``, ``seg_row``, ``seg_inv``: first x, first row,
    inverse spacing; ``seg_row[n_seg]`` is the table's last row) that starts at or before ``x``, or the first.

    The search starts at segment ``s`` (the previous look-up's): along a ray, where x only grows, it costs
    a comparison or two.
    """
    while s > 0 and x < seg_x[s]:
        s -= 1
    while s + 1 < n_seg and x >= seg_x[s + 1]:
        s += 1
    v = (x - seg_x[s]) * seg_inv[s]
    k = min(max(int(v), 0), seg_row[s + 1] - seg_row[s] - 1)
    return seg_row[s] + k, min(max(v - k, 0.0), 1.0), s


@nb.njit(cache=True, nogil=True, inline="always")
def _interpolate(nodes, o, f, step, col, delta):
    """Column ``col`` at fraction ``f`` between rows ``o`` and ``o + 1``, for a rate ``e^delta`` times the table's.

    The value plus the first-order Taylor term in ``log lambda`` (column ``col + 2``) at each node, cubic
    Hermite in x with their x-derivatives (columns ``col + 1``, ``col + 3``), plus the second-order term
    (column ``col + 4``), linear in x (its factor ``delta^2 / 2`` is at most 1/800 at a half step of the rate
    grid).
    """
    g = 1.0 - f
    half = 0.5 * delta
    y_0 = nodes[o, col] + delta * nodes[o, col + 2]
    y_1 = nodes[o + 1, col] + delta * nodes[o + 1, col + 2]
    s_0 = nodes[o, col + 1] + delta * nodes[o, col + 3]
    s_1 = nodes[o + 1, col + 1] + delta * nodes[o + 1, col + 3]
    return ((1.0 + 2.0 * f) * g * g * y_0 + f * f * (3.0 - 2.0 * f) * y_1 + f * g * step * (g * s_0 - f * s_1)
            + half * delta * (g * nodes[o, col + 4] + f * nodes[o + 1, col + 4]))


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _cell_prior(x):
    """``(1 - e^-x, e^-x)`` for ``x >= 0``: below 0.2 a degree-8 series in Estrin form (relative error
    < 1e-11, no dependency chain), else through :func:`fast_exp`; both are computed and one selected, so
    that a loop over cells stays branch-free."""
    q = fast_exp(-x)
    x2 = x * x
    p = x * ((1.0 - 0.5 * x) + x2 * (1.0 / 6.0 - x * (1.0 / 24.0))
             + x2 * x2 * ((1.0 / 120.0 - x * (1.0 / 720.0)) + x2 * (1.0 / 5040.0 - x * (1.0 / 40320.0))))
    small = x < 0.2
    return (p if small else 1.0 - q), (1.0 - p if small else q)


@nb.njit(cache=True, nogil=True)
def combine_small(l_a, l_c, a_is_d, c_is_d, lam_len):
    """:func:`combine` from the log of the smaller of ``C/Z``, ``D/Z`` at each end (``*_is_d``: it is D's).

    The other one is ``log(1 - e^small)``. Far in front of the measurement (``C(c)/Z < e^-600``, so
    ``D/Z = 1`` to that precision) ``P Z = C(c) - e^{-lam_len} C(a)`` and ``(1 - P) Z = D(c)``: two
    transcendentals fewer than the general case.
    """
    if not c_is_d and l_c < -600.0 and lam_len > 0.0:
        l_ca = log1mexp(l_a) if a_is_d else l_a
        log_num = l_c + math.log1p(-math.exp(min(l_ca - l_c, 0.0) - lam_len))
        return math.exp(log_num), log_num - lam_len - log1mexp(-lam_len)
    other_a = log1mexp(l_a)
    other_c = log1mexp(l_c)
    return combine(other_a if a_is_d else l_a, l_a if a_is_d else other_a,
                   other_c if c_is_d else l_c, l_c if c_is_d else other_c, lam_len)


@nb.njit(cache=True, nogil=True)
def _log_c_first(z, steep, lam, ku, h, z0, fb, shift, log_wn, means, sigmas):
    """``log C(z)`` in a table's first interval (``z0 < z``, x-width ``h``): one Gauss-Legendre panel, as
    the table's march integrated that interval (8 points here, :data:`_MARCH_GL` there: they agree to about
    1e-10), or where ``q g`` rises steeply (``steep``: the interval
    is in the coarse front) the endpoint asymptotic with the start's cut, ``C = q g / phi' (1 -
    e^{-phi' (z - z0)})``, exact for an exponential ``q g``."""
    if not steep:
        return log_integral(z0, z, lam, ku, h, z0, fb, shift, log_wn, means, sigmas)
    phi, phi_z = _log_qg_slope(z, lam, z0, fb, shift, log_wn, means, sigmas)
    return phi - math.log(phi_z) + log1mexp(-phi_z * (z - z0))


_LOG_HALF = -0.6931471805599453
_LOG_QUARTER = 2.0 * _LOG_HALF
_SKIP = 4
"""``side`` flag of a cell the measurement does not change (empty, or beyond the influence depth)."""


@nb.njit(cache=True, nogil=True, fastmath=_FASTMATH)
def prism_table_lookup(lam, table, delta, ray_of_cell, start, end, stretch, lo, hi, z0, z_max, fb, ku, hq, meta,
                       nodes, log_wn, means, sigmas, l_a, l_c, side, lam_len):
    """First stage of tabulated PRISM on cells ``lo:hi``: per cell end, the log of the smaller of C/Z, D/Z.

    A cell is ``[start[i], end[i] + stretch[r]]`` (``stretch``: the ray's voxel overhang share, depth metres).
    Per ray one table (``table[r]``, the ray's rate ``e^delta[r]`` times the table's). A look-up
    interpolates ``log(C/Z)`` and, only where ``C/Z > 1/2``, ``log(D/Z)`` (``C/Z + D/Z = 1``); past a depth
    of the ray already found to have ``C/Z >= 1/2`` only ``log(D/Z)``, as ``C`` only grows. Writes
    ``l_a[j], l_c[j]`` (cell ``lo + j``) and ``side[j]`` (bit 0: ``l_a`` is D's, bit 1: ``l_c`` is D's, or
    :data:`_SKIP`: no change), and ``lam_len[j]``, the cell's prior rate times its length (of the part in
    ``[z0, z_max]``; a skipped cell's whole length). A cell starting where the previous one of the same ray ended reuses that
    look-up (ray casting emits cells in order; with a stretch no start is a previous end). A cell across
    ``C/Z = 1/2`` (``D`` the smaller at its end only) whose start has ``C/Z >= 1/4`` takes ``D`` at its start
    too, so that its share ``C(c) - C(a) = D(a) - D(c)`` is a difference within one column: with the Taylor
    terms in ``log lambda``, at a half step of the rate grid and where most of ``C`` lies many prior e-folds
    before the measurement, the table's ``C/Z + D/Z`` misses 1 by up to 1e-3, as much as a short cell's share
    there. A start with ``C/Z < 1/4`` keeps its ``C`` (accurate relative to itself, which a ``1 - D/Z`` is not
    near 0): that cell's share is above 1/4, and the miss is small against it. Cells starting
    beyond the influence depth are skipped; for a cell ending beyond the table (where the remaining
    evidence is below e^-40 of C), ``D(c)`` is integrated on the spot, and so is ``C`` in the table's first
    interval: both at the ray's own rate, over the ray's ``Z`` (the table's by the nodes' Taylor term, from
    the meta columns ``log_z_1``, ``log_z_2``), not the table's rate and ``Z``.
    """
    r_prev = -1
    c_prev = -1.0
    lcc = 0.0
    c_is_d = 0
    seg_x = np.empty(N_SEGMENTS)
    seg_h = np.empty(N_SEGMENTS)
    seg_inv = np.empty(N_SEGMENTS)
    seg_row = np.empty(N_SEGMENTS + 1, dtype=np.int64)
    lam_t = lam_r = z_end = z_infl = dl = shift = log_z = log_far = stretch_r = 0.0
    z_half = np.inf
    off = n_seg = s_a = s_c = 0
    steep = False
    for i in range(lo, hi):
        j = i - lo
        r = ray_of_cell[i]
        if r != r_prev:
            r_prev = r
            c_prev = -1.0
            t = table[r]
            dl = delta[r]
            lam_t = meta[t, _LAM]
            n_seg = 0  # the non-empty segments, in order
            for k in range(N_SEGMENTS):
                first = int(meta[t, _ROW + k])
                if (int(meta[t, _ROW + k + 1]) if k + 1 < N_SEGMENTS else int(meta[t, _LENGTH]) - 1) > first:
                    seg_x[n_seg] = meta[t, _X + k]
                    seg_row[n_seg] = first
                    seg_h[n_seg] = meta[t, _SPACING + k]
                    seg_inv[n_seg] = 1.0 / seg_h[n_seg]
                    n_seg += 1
            seg_row[n_seg] = int(meta[t, _LENGTH]) - 1
            steep = int(meta[t, _ROW + 1]) > 0  # a coarse front: C from its endpoint asymptotic there
            s_a = s_c = 0
            z_half = np.inf  # least depth of the ray known to have C/Z >= 1/2
            z_end = meta[t, _Z_END]
            z_infl = meta[t, _Z_INFL]
            shift = meta[t, _SHIFT]
            lam_r = lam[r]
            log_z = meta[t, _LOG_Z] + dl * (meta[t, _LOG_Z_1] + 0.5 * dl * meta[t, _LOG_Z_2])  # the ray's
            log_far = meta[t, _LOG_FAR]
            off = int(meta[t, _OFFSET])
            stretch_r = stretch[r]
        a = max(start[i], z0)
        c = min(end[i] + stretch_r, z_max)
        if c <= a or a >= z_infl:
            side[j] = _SKIP
            l_a[j] = l_c[j] = 0.0
            lam_len[j] = lam[r] * max(end[i] + stretch_r - start[i], 0.0)
            c_prev = -1.0
            continue
        lam_len[j] = lam[r] * (c - a)
        if a == c_prev:
            l_a[j] = lcc
            a_is_d = c_is_d
        else:
            k, f, s_a = _locate(lam_t * a - ku / a, s_a, seg_x, seg_row, seg_inv, n_seg)
            o = off + k
            a_is_d = 1
            if a >= z_half and k > 0:  # C is increasing: past a depth with C/Z >= 1/2, D is the smaller
                l_a[j] = _interpolate(nodes, o, f, seg_h[s_a], _D_COLUMN, dl)
            else:
                if k == 0:  # first interval: log C is -inf at z0
                    lca = -np.inf
                    if a > z0:
                        lca = _log_c_first(a, steep, lam_r, ku, seg_h[s_a], z0, fb, shift, log_wn, means, sigmas) - log_z
                else:
                    lca = _interpolate(nodes, o, f, seg_h[s_a], 0, dl)
                if lca < _LOG_HALF:
                    a_is_d = 0
                    l_a[j] = lca
                else:
                    l_a[j] = _interpolate(nodes, o, f, seg_h[s_a], _D_COLUMN, dl)
                    z_half = min(z_half, a)
        if c > z_end:
            lcc = log_tail(c, log_z, lam_r, ku, hq, z0, z_max, fb, shift, log_far, log_wn, means, sigmas) - log_z
            c_is_d = 1
        else:
            k, f, s_c = _locate(lam_t * c - ku / c, s_c, seg_x, seg_row, seg_inv, n_seg)
            o = off + k
            c_is_d = 1
            if c >= z_half and k > 0:
                lcc = _interpolate(nodes, o, f, seg_h[s_c], _D_COLUMN, dl)
            else:
                if k == 0:
                    lcc = _log_c_first(c, steep, lam_r, ku, seg_h[s_c], z0, fb, shift, log_wn, means, sigmas) - log_z
                else:
                    lcc = _interpolate(nodes, o, f, seg_h[s_c], 0, dl)
                if lcc < _LOG_HALF:
                    c_is_d = 0
                else:
                    lcc = _interpolate(nodes, o, f, seg_h[s_c], _D_COLUMN, dl)
                    z_half = min(z_half, c)
        if c_is_d and not a_is_d and l_a[j] >= _LOG_QUARTER:  # across C/Z = 1/2: see the docstring
            k, f, s_a = _locate(lam_t * a - ku / a, s_a, seg_x, seg_row, seg_inv, n_seg)
            l_a[j] = _interpolate(nodes, off + k, f, seg_h[s_a], _D_COLUMN, dl)
            a_is_d = 1
        l_c[j] = lcc
        side[j] = a_is_d + 2 * c_is_d
        c_prev = c


@nb.njit(cache=True, nogil=True, error_model="numpy")  # no fastmath: it inlines fast_exp
def prism_table_combine(lo, hi, l_a, l_c, e_a, e_c, side, lam_len, post, ratio, fix_index, fix_value, pass_through):
    """Second stage on cells ``lo:hi``: posterior (into ``post[lo:hi]``) and ``ratio[j]``, the increment's exp.

    ``e_a``, ``e_c`` are ``exp(l_a)``, ``exp(l_c)`` of :func:`prism_table_lookup` (:func:`exp_into`), so
    ``C/Z`` and ``D/Z`` at both ends are at hand in linear space: ``P Z = p_c C(a) + C(c) - C(a)``,
    ``(1 - P) Z = (1 - p_c) C(a) + D(c)`` and the increment is ``log(ratio)`` with
    ``ratio = P (1 - p_c) / ((1 - P) p_c)``, ``p_c = 1 - e^-lam_len``. A first, branch-free pass (it
    vectorises) does every cell so; a second one redoes the few it marked (``ratio`` -1): skipped cells
    (``ratio = 1``, the posterior the prior's) and cells near underflow (a log below -600 or
    ``lam_len > 40``), which go through :func:`combine_small`: ``ratio = 1``, listed in ``fix_index``
    (offset from ``lo``) and ``fix_value``. Returns how many. ``pass_through``: the chance that a ray passes an
    occupied cell, ``ratio -> m + (1 - m) ratio`` (:func:`pass_through_log`; 0: never, bit for bit).
    """
    for j in range(hi - lo):
        s = side[j]
        p_c, q_c = _cell_prior(lam_len[j])
        c_a = 1.0 - e_a[j] if s & 1 else e_a[j]
        c_c = 1.0 - e_c[j] if s & 2 else e_c[j]
        d_a = e_a[j] if s & 1 else 1.0 - e_a[j]  # the looked-up side as it is: D(c)/Z below 1e-16 of q_c C(a)/Z
        d_c = e_c[j] if s & 2 else 1.0 - e_c[j]  # would vanish in 1 - (1 - D/Z)
        # the cell's share C(c) - C(a) from the side that is small (accurate) at c
        delta = max(c_c - c_a, 0.0) if c_c < 0.5 else max(d_a - d_c, 0.0)
        num = p_c * c_a + delta
        den = q_c * c_a + d_c
        ok = ((s != _SKIP) & (min(l_a[j], l_c[j]) >= -600.0) & (lam_len[j] <= 40.0) & (num > 0.0) & (den > 0.0)
              & (p_c > 0.0))
        thinned = pass_through + (1.0 - pass_through) * ((num * q_c) / (den * p_c))  # = the ratio when m = 0
        post[lo + j] = num / (num + den) if pass_through == 0.0 else p_c * thinned / (p_c * thinned + q_c)
        ratio[j] = thinned if ok else -1.0
    n_fix = 0
    for j in range(hi - lo):
        if ratio[j] >= 0.0:
            continue
        ratio[j] = 1.0
        if side[j] == _SKIP:
            post[lo + j] = -math.expm1(-lam_len[j])
            continue
        post[lo + j], fix_value[n_fix] = combine_small(l_a[j], l_c[j], side[j] & 1, side[j] & 2, lam_len[j])
        if pass_through > 0.0:
            post[lo + j], fix_value[n_fix] = pass_through_log(fix_value[n_fix], lam_len[j], pass_through)
        fix_index[n_fix] = j
        n_fix += 1
    return n_fix


@nb.njit(cache=True, nogil=True)
def prism_table_cells(lam, table, delta, ray_of_cell, start, end, stretch, block, z0, z_max, fb, ku, hq, meta, nodes,
                      log_wn, means, sigmas, pass_through):
    """Tabulated PRISM on every cell ``[start[i], end[i] + stretch[r]]``: posterior and increment, (C,) each.

    Blocks of ``block`` cells go through :func:`prism_table_lookup`, :func:`exp_into` (both ends),
    :func:`prism_table_combine` and :func:`log_into`; the scratch arrays of a block stay in the core's
    cache and the GIL stays released for the whole call. ``pass_through``: see :func:`prism_table_combine`.
    """
    n = start.size
    post = np.empty(n)
    inc = np.empty(n)
    size = max(min(n, block), 1)
    l_a, l_c, e_a, e_c = np.empty(size), np.empty(size), np.empty(size), np.empty(size)
    lam_len, ratio, fix_value = np.empty(size), np.empty(size), np.empty(size)
    side = np.empty(size, dtype=np.int8)
    fix_index = np.empty(size, dtype=np.int64)
    for lo in range(0, n, size):
        hi = min(lo + size, n)
        m = hi - lo
        prism_table_lookup(lam, table, delta, ray_of_cell, start, end, stretch, lo, hi, z0, z_max, fb, ku, hq, meta,
                           nodes, log_wn, means, sigmas, l_a, l_c, side, lam_len)
        exp_into(l_a, e_a, m)
        exp_into(l_c, e_c, m)
        n_fix = prism_table_combine(lo, hi, l_a, l_c, e_a, e_c, side, lam_len, post, ratio, fix_index, fix_value,
                                    pass_through)
        log_into(ratio, inc[lo:hi], m)
        for k in range(n_fix):
            inc[lo + fix_index[k]] = fix_value[k]
    return post, inc


@nb.njit(cache=True, nogil=True)
def prism_log_evidence(shift, lam, z0, z_max, fb, ku, hq, log_far, log_wn, means, sigmas):
    """``log Z`` (the marginal density of each measured disparity, 1/pixel) for every ray."""
    out = np.empty(shift.size)
    for r in range(shift.size):
        out[r] = prism_march(shift[r], lam[r], z0, z_max, fb, ku, hq, log_far[r], 0.0, 0.0, 0, log_wn,
                               means, sigmas)[3]
    return out


@nb.njit(cache=True, nogil=True)
def table_keys(disparity, log_norm, disparity_step, lambda_step, key_l_span):
    """PRISM's table key of every ray and the distinct keys (first-seen order), by open addressing.

    ``key = rint(d / disparity_step) * key_l_span + min(rint(log|r| / lambda_step), key_l_span - 1)``.
    Returns ``unique (K,) int64`` and ``inverse (R,) int64`` (``unique[inverse] = key``); a hash table
    instead of a sort: O(R) for the ~300 k rays of a frame and their ~2 k keys.
    """
    n = disparity.size
    size = 64
    while size < 2 * n:
        size *= 2
    mask = size - 1
    slots = np.full(size, -1, dtype=np.int64)
    unique = np.empty(n, dtype=np.int64)
    inverse = np.empty(n, dtype=np.int64)
    k = 0
    for i in range(n):
        key = np.int64(np.rint(disparity[i] / disparity_step)) * key_l_span + min(
            np.int64(np.rint(log_norm[i] / lambda_step)), key_l_span - 1)
        h = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(32)) & mask
        while slots[h] >= 0 and unique[slots[h]] != key:
            h = (h + 1) & mask
        if slots[h] < 0:
            slots[h] = k
            unique[k] = key
            k += 1
        inverse[i] = slots[h]
    return unique[:k], inverse


# ------------------------------------------------------------------------------ PRISM with the map as prior
# Kaufman, Lee, Ai (ACC 2016): on one ray, cells with their own priors (the map's), the exact posterior of each
# given the measurement; docs/SENSOR_MODELS.md, "The map as prior".

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_NARROW_SIGMAS = 1e-3  # a cell narrower than this many sigmas of a component: midpoint rule for its average


@nb.njit(cache=True, nogil=True)
def log_ndtr(x):
    """``log Phi(x)`` of the standard normal, accurate in the lower tail (asymptotic series below -20)."""
    if x > -20.0:
        return math.log(0.5 * math.erfc(-x * _SQRT_HALF))
    r = 1.0 / (x * x)
    return -0.5 * x * x - math.log(-x) - _LOG_SQRT_2PI + math.log1p(r * (-1.0 + r * (3.0 - 15.0 * r)))


@nb.njit(cache=True, nogil=True)
def log_diff_ndtr(hi, lo):
    """``log(Phi(hi) - Phi(lo))`` for ``hi >= lo``, accurate in both tails (the upper one mirrored)."""
    if lo > 0.0:
        hi, lo = -lo, -hi
    log_hi = log_ndtr(hi)
    return log_hi + log1mexp(min(log_ndtr(lo) - log_hi, 0.0))


@nb.njit(cache=True, nogil=True)
def log_mean_g(u_lo, u_hi, shift, log_w, means, sigmas):
    """Log of ``g`` averaged over true disparities uniform in ``[u_lo, u_hi]`` (pixels; ``u_lo < u_hi``).

    A sum of normal-CDF differences over ``u_hi - u_lo``; a component for which the interval is narrower
    than :data:`_NARROW_SIGMAS` sigmas takes its density at the midpoint (the difference would cancel).
    """
    best = -np.inf
    total = 0.0
    width = u_hi - u_lo
    for j in range(means.size):
        s = sigmas[j]
        t_lo = (u_lo - shift - means[j]) / s
        t_hi = (u_hi - shift - means[j]) / s
        if t_hi - t_lo < _NARROW_SIGMAS:
            t = 0.5 * (t_lo + t_hi)
            v = log_w[j] - math.log(s) - _LOG_SQRT_2PI - 0.5 * t * t
        else:
            v = log_w[j] + log_diff_ndtr(t_hi, t_lo) - math.log(width)
        best, total = _log_sum_exp_add(best, total, v)
    return best + math.log(total)


@nb.njit(cache=True, nogil=True)
def _log_hit(log_survive, hazard, a, c, fb, shift, log_w, means, sigmas):
    """Log evidence of "the first surface lies in ``[a, c]``": survival to ``a``, the stretch's occupancy
    ``1 - e^-hazard`` and ``g`` averaged over its disparities; -inf for an empty stretch."""
    if c <= a or hazard <= 0.0:
        return -np.inf
    return log_survive + log1mexp(-hazard) + log_mean_g(fb / c, fb / a, shift, log_w, means, sigmas)


@nb.njit(cache=True, nogil=True)
def prism_map_prior_cells(shift, lam, order, ray_start, start, end, stretch, cell_rate, z0, z_max, fb, ku, hq,
                          log_rest, log_far, log_wn, log_w, means, sigmas, pass_through):
    """PRISM with per-cell priors on rays of consecutive cells: exact posterior and increment of every cell.

    The cells of ray ``r`` are ``order[ray_start[r]:ray_start[r + 1]]``, nearest first, each starting where
    the previous one ends (the wrapper checks); cell ``k`` covers depths ``[a_k, c_k]`` clipped to
    ``[z0, z_max]`` with surface rate ``cell_rate[k]`` (per metre of depth), so hazard
    ``h_k = cell_rate[k] (c_k - a_k)``, prior ``p_k = 1 - e^-h_k``, survival ``S_k = e^{-sum_{j<k} h_j}``,
    first-hit evidence ``T_k = S_k p_k L_k`` (``L_k``: :func:`log_mean_g` over the cell). Beyond the last cell
    the ray has the prior rate ``lam[r]`` (``log_tail`` on panels of x-width ``hq``, stopped where the rest is
    below ``e^log_rest`` of the evidence before; the far measurement included). With ``B_i`` the
    evidence of a first surface before cell ``i`` and ``A_i`` of one after it,
    ``P Z = p_i B_i + T_i`` and ``(1 - P) Z = (1 - p_i) B_i + A_i``: no difference of sums, so nothing cancels.
    ``stretch[r] > 0`` (depth metres; the voxel overhang share) makes cell ``i``'s event "a surface in
    ``[a_i, c_i + stretch]``" (cut at the ray's last cell): its hazard, hit and after-evidence then span
    the following cells, the one the stretch ends in split at its end. Increment ``logit(P) - logit(p_i)``,
    then ``pass_through`` (:func:`pass_through_log`). All in log space.
    """
    n = start.size
    post = np.empty(n)
    inc = np.empty(n)
    for r in range(shift.size):
        lo, hi = ray_start[r], ray_start[r + 1]
        m = hi - lo
        if m == 0:
            continue
        a = np.empty(m)
        c = np.empty(m)
        h = np.empty(m)
        log_s = np.empty(m + 1)  # survival to each cell's start; [m]: past the last cell
        t = np.empty(m)
        log_s[0] = 0.0
        for k in range(m):
            i = order[lo + k]
            a[k] = min(max(start[i], z0), z_max)
            c[k] = min(max(end[i], z0), z_max)
            h[k] = cell_rate[i] * max(c[k] - a[k], 0.0)
            t[k] = _log_hit(log_s[k], h[k], a[k], c[k], fb, shift[r], log_w, means, sigmas)
            log_s[k + 1] = log_s[k] - h[k]
        before = np.empty(m + 1)  # before[k]: evidence of a first surface in cells < k
        before[0] = -np.inf
        for k in range(m):
            before[k + 1] = logaddexp(before[k], t[k])
        tail = -np.inf
        if c[m - 1] < z_max:
            tail = log_tail(c[m - 1], before[m] - log_s[m], lam[r], ku, hq, c[m - 1], z_max, fb, shift[r], log_far[r],
                            log_wn, means, sigmas, log_rest)
        else:
            tail = log_far[r]
        after = np.empty(m + 1)  # after[k]: evidence of a first surface beyond cell k - 1 (cells >= k, tail)
        after[m] = log_s[m] + tail
        for k in range(m - 1, -1, -1):
            after[k] = logaddexp(after[k + 1], t[k])
        s_r = stretch[r]
        for k in range(m):
            i = order[lo + k]
            if h[k] <= 0.0:  # empty once clipped to [z0, z_max]: unchanged
                post[i] = -math.expm1(-cell_rate[i] * max(end[i] - start[i], 0.0))
                inc[i] = 0.0
                continue
            hazard, hit, beyond = h[k], t[k], after[k + 1]
            if s_r > 0.0:
                e = c[k] + s_r
                j = k + 1
                while j < m and c[j] <= e:  # cells wholly inside the stretch
                    hazard += h[j]
                    hit = logaddexp(hit, t[j])
                    j += 1
                beyond = after[j]
                if j < m and a[j] < e and h[j] > 0.0:  # the cell the stretch ends in, split at e
                    part = h[j] * (e - a[j]) / (c[j] - a[j])
                    hazard += part
                    hit = logaddexp(hit, _log_hit(log_s[j], part, a[j], e, fb, shift[r], log_w, means, sigmas))
                    beyond = logaddexp(after[j + 1],
                                       _log_hit(log_s[j] - part, h[j] - part, e, c[j], fb, shift[r], log_w, means,
                                                sigmas))
            log_p = log1mexp(-hazard)
            log_num = logaddexp(log_p + before[k], hit)
            log_den = logaddexp(-hazard + before[k], beyond)
            inc[i] = (log_num - log_den) - (log_p + hazard)
            post[i] = _sigmoid(log_num - log_den)
            if pass_through > 0.0:
                post[i], inc[i] = pass_through_log(inc[i], hazard, pass_through)
    return post, inc
