"""numba kernels of PRISM evaluated directly (quadrature ray by ray): the cell combination, pass-through,
the tail beyond a point, every cell's update and each measurement's evidence."""

import math

import numba as nb
import numpy as np

from prismap.sensor_models._kernels_march import _log_panel, _log_sup_tail, log_integral, prism_march, x_of_z, z_of_x
from prismap.sensor_models._kernels_math import _sigmoid, log1mexp, logaddexp


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
def log_tail(z, log_c_z, lam, shift, log_far, hq, geometry, mixture, log_rest=-40.0):
    """``log D(z)``: evidence beyond ``z`` (far measurement included), marched until the rest is below
    ``e^log_rest`` of ``C(z)`` plus the march so far.

    Parameters
    ----------
    z : float, metres of depth
        Start of the tail.
    log_c_z : float, log
        ``log C(z)``, on the scale of the panels (not normalised).
    lam : float, per metre of depth
        Surface rate of the prior.
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    log_far : float, log(1/pixel)
        Log density of the far measurement.
    hq : float, x units
        Panel width (:func:`~prismap.sensor_models._kernels_march.x_of_z`).
    geometry : Geometry
        Depth range and disparity scales (:class:`~prismap.sensor_models._kernel_args.Geometry`); its ``z0`` is
        where the prior's survival starts.
    mixture : Mixture
        The error mixture (:class:`~prismap.sensor_models._kernel_args.Mixture`).
    log_rest : float, log, default -40
        Stop where the rest is below this share of the evidence so far.
    """
    z0, z_max, _, ku = geometry
    tail = -np.inf
    acc = log_c_z
    x_start = x_of_z(z, lam, ku)
    x_end = x_of_z(z_max, lam, ku)
    za = z
    k = 1
    while za < z_max:
        zb = z_of_x(x_start + k * hq, lam, ku) if x_start + k * hq < x_end else z_max
        zb = min(zb, z_max)
        p = _log_panel(za, zb, lam, shift, geometry, mixture)
        tail = logaddexp(tail, p)
        acc = logaddexp(acc, p)
        za = zb
        k += 1
        bound = -lam * (za - z0) + max(_log_sup_tail(za, shift, geometry, mixture), log_far)
        if za < z_max and bound - acc < log_rest:
            return logaddexp(tail, bound)
    return logaddexp(tail, -lam * (z_max - z0) + log_far)


@nb.njit(cache=True, nogil=True)
def prism_direct_cells(shift, lam, log_far, order, ray_start, start, end, hq, pass_through, geometry, mixture):
    """Continuous PRISM by quadrature, ray by ray: exact C and D at every distinct cell boundary.

    Parameters
    ----------
    shift : (R,) float64, pixels
        Each ray's measured disparity plus ``doffs``.
    lam : (R,) float64, per metre of depth
        Each ray's surface rate.
    log_far : (R,) float64, log(1/pixel)
        Each ray's far-measurement log density.
    order : (C,) int64
        Sorts the cells by ray: the cells of ray ``r`` are ``order[ray_start[r]:ray_start[r + 1]]``.
    ray_start : (R + 1,) int64
        Each ray's first position in ``order``.
    start, end : (C,) float64, metres of depth
        Cell ``[start[i], end[i]]``, clipped to ``[z0, z_max]``.
    hq : float, x units
        Panel width (:func:`~prismap.sensor_models._kernels_march.x_of_z`).
    pass_through : float in [0, 1)
        The chance that a ray passes an occupied cell (:func:`pass_through_log`; 0: never).
    geometry : Geometry
        Depth range and disparity scales.
    mixture : Mixture
        The error mixture.

    Returns
    -------
    post : (C,) float64
        Posterior occupancy of each cell.
    inc : (C,) float64, log-odds
        ``logit(post) - logit(prior)``.
    """
    z0, z_max = geometry.z0, geometry.z_max
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
        log_c[0] = log_integral(z0, bounds[0], lam[r], shift[r], hq, geometry, mixture)
        panels[0] = -np.inf
        for k in range(1, nb_):
            panels[k] = log_integral(bounds[k - 1], bounds[k], lam[r], shift[r], hq, geometry, mixture)
            log_c[k] = logaddexp(log_c[k - 1], panels[k])
        tail = log_tail(bounds[nb_ - 1], log_c[nb_ - 1], lam[r], shift[r], log_far[r], hq, geometry, mixture)
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


@nb.njit(cache=True, nogil=True)
def prism_log_evidence(shift, lam, log_far, hq, geometry, mixture):
    """``log Z`` (the marginal density of each measured disparity, 1/pixel) for every ray: (R,) float64.

    Parameters
    ----------
    shift, lam, log_far, hq, geometry, mixture
        As :func:`prism_direct_cells`'s.
    """
    out = np.empty(shift.size)
    for r in range(shift.size):
        out[r] = prism_march(shift[r], lam[r], log_far[r], hq, 0.0, 0.0, 0, geometry, mixture)[3]
    return out
