"""numba kernels of the classic inverse sensor models (ideal, hit/miss, convolution, Andert); called only by
the wrappers in ``_classic``, which validate and convert (contiguous float64 / int64): the kernels assume."""

import math

import numba as nb
import numpy as np

from prismap.sensor_models._kernels_math import _logit, _sigmoid, normal_cdf

# ------------------------------------------------------------------------------------- classic models


@nb.njit(cache=True, nogil=True)
def ideal_cells(depth_hat, ray_norm, ray_of_cell, start, end, half_alpha, p_free, p_occ, p0):
    """Thrun's ideal model at the cell centre; distances along the ray.

    Parameters
    ----------
    depth_hat : (R,) float64, metres of depth
        Each ray's measured depth.
    ray_norm : (R,) float64
        ``|r|``: metres along the ray per metre of depth.
    ray_of_cell : (C,) int64
        Each cell's ray.
    start, end : (C,) float64, metres of depth
        The cell ``[start[i], end[i]]`` on its ray.
    half_alpha : float, metres along the ray
        Half the width of the occupied band around the measurement.
    p_free, p_occ, p0 : float in (0, 1)
        Posterior before the band, in it, and the prior (beyond it).

    Returns
    -------
    post : (C,) float64
        Posterior occupancy of each cell.
    inc : (C,) float64, log-odds
        ``logit(post) - logit(p0)``.
    """
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
    """OctoMap: hit at the cell whose interval holds the measured depth, miss before, nothing after.

    Parameters
    ----------
    depth_hat : (R,) float64, metres of depth
        Each ray's measured depth.
    ray_of_cell : (C,) int64
        Each cell's ray.
    start, end : (C,) float64, metres of depth
        The cell ``[start[i], end[i]]`` on its ray.
    l_hit, l_miss : float, log-odds
        Increments of the hit cell and of the cells before it.
    p0 : float in (0, 1)
        Prior occupancy.

    Returns
    -------
    post : (C,) float64
        Posterior occupancy of each cell.
    inc : (C,) float64, log-odds
        ``logit(post) - logit(p0)``.
    """
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
    """Ideal profile convolved with N(0, sigma_s^2) along the ray, at the cell centre.

    Parameters
    ----------
    depth_hat : (R,) float64, metres of depth
        Each ray's measured depth.
    sigma_depth : (R,) float64, metres of depth
        Each ray's depth standard deviation.
    ray_norm : (R,) float64
        ``|r|``: metres along the ray per metre of depth.
    ray_of_cell : (C,) int64
        Each cell's ray.
    start, end : (C,) float64, metres of depth
        The cell ``[start[i], end[i]]`` on its ray.
    half_alpha : float, metres along the ray
        Half the width of the ideal model's occupied band.
    p_free, p_occ, p0 : float in (0, 1)
        The ideal model's posterior before the band, in it, and the prior (beyond it).

    Returns
    -------
    post : (C,) float64
        Posterior occupancy of each cell.
    inc : (C,) float64, log-odds
        ``logit(post) - logit(p0)``.
    """
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
    """Andert's profile evaluated at ``clip(s^, a, c)``; increments on the even-odds scale.

    Parameters
    ----------
    depth_hat : (R,) float64, metres of depth
        Each ray's measured depth.
    sigma_depth : (R,) float64, metres of depth
        Each ray's depth standard deviation.
    ray_norm : (R,) float64
        ``|r|``: metres along the ray per metre of depth.
    ray_of_cell : (C,) int64
        Each cell's ray.
    start, end : (C,) float64, metres of depth
        The cell ``[start[i], end[i]]`` on its ray.
    eta : float, metres along the ray
        Scale of the peak: ``0.5 + eta / (sqrt(2 pi) sigma)``, capped at ``p_max``.
    p_min, p_max : float in (0, 1)
        Profile before the measurement, and the peak's cap.
    p0 : float in (0, 1)
        Prior occupancy (of ``post``; ``inc`` is ``logit`` of the profile, on the even-odds scale).

    Returns
    -------
    post : (C,) float64
        Posterior occupancy of each cell.
    inc : (C,) float64, log-odds
        ``logit`` of the profile (even odds as the reference).
    """
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
