"""numba kernels of PRISM's integration along one ray: the likelihood, Gauss-Legendre panels, and the march
that gives ``log C`` and ``log D = log(Z - C)`` and the moments of ``Q`` in the surface rate.

PRISM carries ``log C`` and ``log D`` as logarithms so that nothing underflows from 0.1 m to 200 m with
surface rates up to 50 per metre. The wrappers (``_prism``) validate and convert; the kernels assume.
"""

import math

import numba as nb
import numpy as np

from prismap.sensor_models._kernels_math import _EXP_NORMAL, fast_exp, fast_log, logaddexp

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_LOG_W = np.log(_GL_W)

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
def log_likelihood(u, shift, mixture):
    """``log g``: the mixture density of the error ``u - shift``.

    Parameters
    ----------
    u : float, pixels
        True disparity ``fb / z``, without ``doffs``.
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    mixture : Mixture
        The error mixture (:class:`~prismap.sensor_models._kernel_args.Mixture`).

    Returns
    -------
    float, log(1/pixel)
    """
    log_wn, means, sigmas = mixture
    best = -np.inf
    total = 0.0
    for j in range(means.size):
        t = (u - shift - means[j]) / sigmas[j]
        best, total = _log_sum_exp_add(best, total, log_wn[j] - 0.5 * t * t)
    return best + math.log(total)


@nb.njit(cache=True, nogil=True)
def _log_sup_tail(z, shift, geometry, mixture):
    """Log of an upper bound of ``g`` on true depths ``[z, z_max]`` (sum of per-component maxima).

    Parameters
    ----------
    z : float, metres of depth
        Start of the tail.
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    geometry : Geometry
        ``z_max`` and ``fb`` are read (:class:`~prismap.sensor_models._kernel_args.Geometry`).
    mixture : Mixture
        The error mixture.
    """
    log_wn, means, sigmas = mixture
    u_hi = geometry.fb / z
    u_lo = geometry.fb / geometry.z_max
    best = -np.inf
    total = 0.0
    for j in range(means.size):
        mode = min(max(shift + means[j], u_lo), u_hi)
        t = (mode - shift - means[j]) / sigmas[j]
        best, total = _log_sum_exp_add(best, total, log_wn[j] - 0.5 * t * t)
    return best + math.log(total)


@nb.njit(cache=True, nogil=True)
def x_of_z(z, lam, ku):
    """The integration coordinate ``x = lam z - ku / z`` (x units) of depth ``z`` (metres), for a surface rate
    ``lam`` (per metre of depth) and ``ku`` (pixel metres, :class:`~prismap.sensor_models._kernel_args.Geometry`)."""
    return lam * z - ku / z


@nb.njit(cache=True, nogil=True)
def z_of_x(x, lam, ku):
    """The depth (metres) of ``x``: the inverse of :func:`x_of_z`, in the form that does not cancel."""
    root = math.sqrt(x * x + 4.0 * lam * ku)
    if x >= 0.0:
        return (x + root) / (2.0 * lam)
    return 2.0 * ku / (root - x)


@nb.njit(cache=True, nogil=True)
def _log_panel_moments(z1, z2, lam, shift, geometry, mixture):
    """Logs of ``int_{z1}^{z2} (z - z0)^k q g dz``, k = 0, 1, 2, by 8-point Gauss-Legendre (one panel).

    Parameters
    ----------
    z1, z2 : float, metres of depth
        The panel; -inf each when ``z2 <= z1``.
    lam : float, per metre of depth
        Surface rate of the prior ``q(z) = lam e^{-lam (z - z0)}``.
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    geometry : Geometry
        ``z0`` and ``fb`` are read.
    mixture : Mixture
        The error mixture.
    """
    z0, fb = geometry.z0, geometry.fb
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
        v = _GL_LOG_W[i] + log_lam - lam * s + log_likelihood(fb / z, shift, mixture)
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
def _log_panel(z1, z2, lam, shift, geometry, mixture):
    """Log of ``int_{z1}^{z2} q g dz`` by 8-point Gauss-Legendre (one panel); parameters as
    :func:`_log_panel_moments`'s."""
    return _log_panel_moments(z1, z2, lam, shift, geometry, mixture)[0]


@nb.njit(cache=True, nogil=True)
def log_integral(z1, z2, lam, shift, hq, geometry, mixture):
    """Log of ``int_{z1}^{z2} q g dz`` with panels of x-width at most ``hq``.

    Parameters
    ----------
    z1, z2 : float, metres of depth
        The interval; -inf when ``z2 <= z1``.
    lam : float, per metre of depth
        Surface rate of the prior.
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    hq : float, x units
        Widest panel, in the coordinate of :func:`x_of_z`.
    geometry : Geometry
        ``z0``, ``fb`` and ``ku`` are read.
    mixture : Mixture
        The error mixture.
    """
    if z2 <= z1:
        return -np.inf
    ku = geometry.ku
    x1 = x_of_z(z1, lam, ku)
    x2 = x_of_z(z2, lam, ku)
    n = max(1, int(math.ceil((x2 - x1) / hq)))
    out = -np.inf
    za = z1
    for k in range(1, n + 1):
        zb = z2 if k == n else z_of_x(x1 + (x2 - x1) * k / n, lam, ku)
        out = logaddexp(out, _log_panel(za, zb, lam, shift, geometry, mixture))
        za = zb
    return out


@nb.njit(cache=True, nogil=True)
def prism_march(shift, lam, log_far, hq, log_eps_bound, lam_slack, i_min, geometry, mixture):
    """Cumulative evidence of one (d^, lam) on the x-grid of spacing ``hq`` from ``z0``.

    Parameters
    ----------
    shift : float, pixels
        The measured disparity plus ``doffs``.
    lam : float, per metre of depth
        Surface rate of the prior.
    log_far : float, log(1/pixel)
        Log density of the far measurement: ``g`` averaged over true disparities below ``fb / z_max``.
    hq : float, x units
        Panel width in the coordinate of :func:`x_of_z`.
    log_eps_bound : float, log
        ``log(expm1(epsilon))`` for the influence node's increment bound ``epsilon`` (log-odds).
    lam_slack : float, dimensionless
        The influence node holds for every rate within a factor ``1 +- lam_slack`` of ``lam``.
    i_min : int
        The march does not stop before this node.
    geometry : Geometry
        Depth range and disparity scales (:class:`~prismap.sensor_models._kernel_args.Geometry`).
    mixture : Mixture
        The error mixture.

    Returns
    -------
    z : (n,) float64, metres of depth
        The nodes.
    log_c : (n, 3) float64, log
        Logs of ``C`` and of its moments ``int_{z0}^{z} (t - z0)^k q g dt`` (k = 1, 2) at the nodes, not
        normalised.
    log_d : (n, 3) float64, log
        The same beyond ``z`` (the far measurement counted as a mass at ``z_max``).
    log_z : float, log(1/pixel)
        ``log Z``.
    log_far_w : float, log(1/pixel)
        The far term ``e^{-lam (z_max - z0)} g_far`` (-inf when the march stopped early).
    i_infl : (1,) int64
        The first node from which every later cell's increment is bounded by epsilon. The march stops (not
        before node ``i_min``) once the remaining evidence is below e^-40 of ``C``.
    """
    return _march(
        shift,
        lam,
        log_far,
        geometry.z0,
        np.full(3, -np.inf),
        np.zeros(1, dtype=np.int64),
        np.full(1, hq),
        hq,
        np.full(1, log_eps_bound),
        lam_slack,
        i_min,
        1,
        geometry,
        mixture,
    )[:6]


@nb.njit(cache=True, nogil=True, inline="always")
def _march_x(i, x0, counts, widths, h):
    """x of node ``i`` of a march from ``x0`` whose panels are ``counts[r]`` of width ``widths[r]`` for each
    leading run ``r`` in turn, then ``h``.

    Parameters
    ----------
    i : int
        Node index from the march's start.
    x0 : float, x units
        x of node 0.
    counts : (R,) int64
        Panels of the leading runs.
    widths : (R,) float64, x units
        Their panel widths.
    h : float, x units
        Panel width after them.
    """
    x = x0
    for r in range(counts.size):
        if i <= counts[r]:
            return x + i * widths[r]
        x += counts[r] * widths[r]
        i -= counts[r]
    return x + i * h


_MARCH_BLOCK = 16
"""Panels a march evaluates at once (:func:`_log_panel_block`): 288 exps in vectorised loops for a 3-component
mixture; the march's stop wastes at most this many less one."""
_MARCH_GL = 6
"""Gauss-Legendre points of a march's panel: on half a narrowest sigma (or, where only wider components matter, a
quarter of the narrowest of them, at most half a prior e-fold) the rule's relative error is below about 1e-10 where
the integrand matters, and below 5e-8 ten sigmas out (the direct method's 8 points on half as wide panels are the reference)."""
_MARCH_GL_X, _MARCH_GL_W = np.polynomial.legendre.leggauss(_MARCH_GL)
_MARCH_GL_LOG_W = np.log(_MARCH_GL_W)


_EXP_TERM_FLOOR = -700.0


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _exp_term(x):
    """``exp(x)`` (:func:`fast_exp`) for a term of a sum of at least 1: below e^-700 it is e^-700, which adds
    nothing to such a sum, instead of a subnormal or 0 (subnormal arithmetic costs about a hundred cycles)."""
    return fast_exp(max(x, _EXP_TERM_FLOOR))


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _log_panel_block(z, first, count, lam, shift, geometry, mixture, inv_sigmas, out, scratch):
    """Logs of ``int_{z[i-1]}^{z[i]} (t - z0)^k q g dt`` (k = 0, 1, 2) into ``out[i]`` for ``count`` panels from
    ``i = first``, by :data:`_MARCH_GL`-point Gauss-Legendre, each panel's terms scaled by its largest one, in
    loops over all the block's points that LLVM vectorises (exps by :func:`_exp_term`).

    Parameters
    ----------
    z : (n,) float64, metres of depth
        The march's nodes; panel ``i`` is ``[z[i - 1], z[i]]``.
    first, count : int
        The block's first panel and its number of panels (at most :data:`_MARCH_BLOCK`).
    lam : float, per metre of depth
        Surface rate of the prior.
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    geometry : Geometry
        ``z0`` and ``fb`` are read.
    mixture : Mixture
        The error mixture; its ``sigmas`` are read as ``inv_sigmas``.
    inv_sigmas : (J,) float64, 1/pixel
        ``1 / mixture.sigmas``.
    out : (n, 3) float64, log
        Written at rows ``first:first + count``.
    scratch : (J + 5, _MARCH_GL _MARCH_BLOCK) float64
        Work space, overwritten.
    """
    z0, fb = geometry.z0, geometry.fb
    log_wn, means = mixture.log_wn, mixture.means
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
def _log_sup_tail_block(z, first, count, shift, geometry, mixture, inv_sigmas, out, scratch):
    """:func:`_log_sup_tail` at ``z[first:first + count]`` into ``out[first:...]`` ((n,) float64, log), in
    vectorised loops (exps by :func:`_exp_term`); the other parameters as :func:`_log_panel_block`'s (``z_max``
    and ``fb`` of ``geometry`` are read)."""
    fb = geometry.fb
    log_wn, means = mixture.log_wn, mixture.means
    n_comp = means.size
    u_lo = fb / geometry.z_max
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
    :func:`logaddexp` row by row.

    Parameters
    ----------
    terms : (n, 3) float64, log
        The terms to add (a march's panels).
    out : (n, 3) float64, log
        The running sums; row ``first - step`` is read, rows ``first, first + step, ...`` written.
    first, count : int
        First row and number of rows.
    step : int, +1 or -1
        Direction.
    scratch : (3 count,) float64 or longer
        Work space, overwritten.
    """
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
def _march(
    shift,
    lam,
    log_far,
    z_start,
    log_c_start,
    counts,
    widths,
    hq,
    log_eps_bounds,
    lam_slack,
    i_min,
    far_ratio,
    geometry,
    mixture,
):
    """:func:`prism_march` from ``z_start``, where the moments of C are ``log_c_start`` (3,), on ``counts[r]``
    panels of x-width ``widths[r]`` for each leading run in turn (a table's spacing profile), then ``hq``
    (:func:`_march_x`), and with ``far_ratio > 1`` from the first
    node of that last run past the influence node (``i_far``, -1 if none) panels about ``far_ratio`` times
    wider to the end, a multiple of 4 of them, all of one width ``h_far``, and the march stops only on every 4th
    of them (a table's back: 4 equal intervals from ``i_far``). Past the influence depth ``D < (e^eps - 1) C``,
    so ``D``'s relative error there (below about 2e-3 on panels of x-width 2 a narrow component 5 sigmas
    away, far less elsewhere) moves a cell's increment by a thousandth of it. Panels and tail bounds are
    evaluated :data:`_MARCH_BLOCK` at a time (:func:`_log_panel_block`, :func:`_log_sup_tail_block`), the
    running sums and the stop node by node.

    Parameters
    ----------
    shift, lam, log_far, lam_slack, i_min, geometry, mixture
        As :func:`prism_march`'s.
    log_eps_bounds : (K,) float64, log
        Bounds on a later cell's ``log |R - 1|``, the first ``log(expm1(epsilon))`` (:func:`prism_march`'s).
    z_start : float, metres of depth
        First node, at or after ``z0``.
    log_c_start : (3,) float64, log
        Logs of ``C`` and its two moments at ``z_start``.
    counts : (R,) int64
        Panels of the leading runs (:func:`_march_x`).
    widths : (R,) float64, x units
        Their panel widths.
    hq : float, x units
        Fine panel width, of the run that ends the march.
    far_ratio : int
        Far panels about this many times ``hq`` wide; 1: none.

    Returns
    -------
    z, log_c, log_d, log_z
        As :func:`prism_march`'s.
    i_infl : (K,) int64
        Per bound of ``log_eps_bounds``, the first node from which every later cell's ``|R - 1|`` and
        ``|1/R - 1|`` are below it.
    i_far : int
        First node of the far panels, -1 if none.
    h_far : float, x units
        Their width.
    """
    z0, z_max, fb, ku = geometry
    x0 = x_of_z(z_start, lam, ku)
    x_end = x_of_z(z_max, lam, ku)
    last = counts.sum()
    n_max = last + max(1, int(math.ceil((x_end - _march_x(last, x0, counts, widths, hq)) / hq)))
    fine_run = last  # first node of the run of hq panels that ends the march
    for r in range(counts.size - 1, -1, -1):
        if counts[r] > 0 and widths[r] != hq:
            break
        fine_run -= counts[r]
    z = np.empty(n_max + 1)
    log_c = np.full((n_max + 1, 3), -np.inf)
    log_c[0] = log_c_start
    panel = np.full((n_max + 1, 3), -np.inf)
    sup = np.empty(n_max + 1)
    inv_sigmas = 1.0 / mixture.sigmas
    scratch = np.empty((mixture.means.size + 5, _MARCH_GL * _MARCH_BLOCK))
    z[0] = z_start
    i_infl = np.full(log_eps_bounds.size, -1, dtype=np.int64)
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
                z[i] = z_of_x(_march_x(i, x0, counts, widths, hq), lam, ku)
        _log_panel_block(z, first, count, lam, shift, geometry, mixture, inv_sigmas, panel, scratch)
        _log_sup_tail_block(z, first, count, shift, geometry, mixture, inv_sigmas, sup, scratch)
        _log_cumsum_block(panel, log_c, first, count, 1, scratch[0])
        following = first + count
        for i in range(first, first + count):
            bound = -lam * (z[i] - z0) + max(sup[i], log_far)
            excess = bound + lam_slack * lam * (z[i] - z0) + slack - log_c[i, 0]
            for k in range(log_eps_bounds.size):
                if i_infl[k] < 0 and excess < log_eps_bounds[k]:
                    i_infl[k] = i
            if i < n_max and i >= i_min and (i_far < 0 or (i - i_far) % 4 == 0) and bound - log_c[i, 0] < -40.0:
                n = i
                tail = bound
                stopped = True
                break
            if far_ratio > 1 and i_far < 0 and 0 <= i_infl[0] < i and i >= fine_run:
                x_i = _march_x(i, x0, counts, widths, hq)
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
    i_infl[i_infl < 0] = n  # a level not reached holds from the last node on
    log_d = np.empty((n + 1, 3))
    log_s = math.log(z[n] - z0)
    for k in range(3):
        log_d[n, k] = tail + k * log_s
    for last_row in range(n - 1, -1, -_MARCH_BLOCK):
        _log_cumsum_block(panel, log_d, last_row, min(_MARCH_BLOCK, last_row + 1), -1, scratch[0])
    log_z = logaddexp(log_c[n, 0], tail)
    return z[: n + 1], log_c[: n + 1], log_d, log_z, log_far_w, i_infl, i_far, h_far
