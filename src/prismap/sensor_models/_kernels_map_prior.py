"""numba kernels of PRISM with the map as prior: each cell of a ray at its own prior (the map's)."""

import math

import numba as nb
import numpy as np

from prismap.sensor_models._kernel_args import Geometry
from prismap.sensor_models._kernels_direct import log_tail, pass_through_log
from prismap.sensor_models._kernels_march import _log_sum_exp_add
from prismap.sensor_models._kernels_math import _SQRT_HALF, _sigmoid, log1mexp, logaddexp

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

    Parameters
    ----------
    u_lo, u_hi : float, pixels
        The true disparities (without ``doffs``).
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    log_w : (J,) float64, log
        The mixture's log weights.
    means, sigmas : (J,) float64, pixels
        Its component means and standard deviations.
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
    ``1 - e^-hazard`` and ``g`` averaged over its disparities; -inf for an empty stretch.

    Parameters
    ----------
    log_survive : float, log
        Log probability that no surface lies before ``a``.
    hazard : float
        The stretch's integrated surface rate (dimensionless).
    a, c : float, metres of depth
        The stretch.
    fb : float, pixel metres
        Focal length times baseline.
    shift, log_w, means, sigmas
        As :func:`log_mean_g`'s.
    """
    if c <= a or hazard <= 0.0:
        return -np.inf
    return log_survive + log1mexp(-hazard) + log_mean_g(fb / c, fb / a, shift, log_w, means, sigmas)


@nb.njit(cache=True, nogil=True)
def prism_map_prior_cells(
    shift,
    lam,
    log_far,
    order,
    ray_start,
    start,
    end,
    stretch,
    cell_rate,
    hq,
    log_rest,
    pass_through,
    log_w,
    geometry,
    mixture,
):
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

    Parameters
    ----------
    shift : (R,) float64, pixels
        Each ray's measured disparity plus ``doffs``.
    lam : (R,) float64, per metre of depth
        Each ray's prior surface rate, beyond its last cell.
    log_far : (R,) float64, log(1/pixel)
        Each ray's far-measurement log density.
    order : (C,) int64
        Sorts the cells by ray, then by start.
    ray_start : (R + 1,) int64
        Each ray's first position in ``order``.
    start, end : (C,) float64, metres of depth
        The cells, clipped to ``[z0, z_max]``.
    stretch : (R,) float64, metres of depth
        Each ray's voxel overhang share.
    cell_rate : (C,) float64, per metre of depth
        Each cell's surface rate (from its voxel's probability).
    hq : float, x units
        Panel width of the tail beyond the last cell.
    log_rest : float, log
        The tail's march stops where the rest is below this share of the evidence before.
    pass_through : float in [0, 1)
        The chance that a ray passes an occupied cell (0: never).
    log_w : (J,) float64, log
        The mixture's log weights (:func:`log_mean_g`).
    geometry : Geometry
        Depth range and disparity scales (:class:`~prismap.sensor_models._kernel_args.Geometry`).
    mixture : Mixture
        The error mixture (:class:`~prismap.sensor_models._kernel_args.Mixture`).

    Returns
    -------
    post : (C,) float64
        Posterior occupancy of each cell.
    inc : (C,) float64, log-odds
        ``logit(post) - logit(p_i)``.
    """
    z0, z_max, fb, ku = geometry
    means, sigmas = mixture.means, mixture.sigmas
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
            tail = log_tail(
                c[m - 1],
                before[m] - log_s[m],
                lam[r],
                shift[r],
                log_far[r],
                hq,
                Geometry(c[m - 1], z_max, fb, ku),  # the prior's survival restarts past the last cell
                mixture,
                log_rest,
            )
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
                    beyond = logaddexp(
                        after[j + 1],
                        _log_hit(log_s[j] - part, h[j] - part, e, c[j], fb, shift[r], log_w, means, sigmas),
                    )
            log_p = log1mexp(-hazard)
            log_num = logaddexp(log_p + before[k], hit)
            log_den = logaddexp(-hazard + before[k], beyond)
            inc[i] = (log_num - log_den) - (log_p + hazard)
            post[i] = _sigmoid(log_num - log_den)
            if pass_through > 0.0:
                post[i], inc[i] = pass_through_log(inc[i], hazard, pass_through)
    return post, inc
