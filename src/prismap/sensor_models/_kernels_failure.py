"""numba kernels of the matcher-failure blend (:mod:`prismap.sensor_models._failure`): a cell's failure-free
increment blended with its prior by its ray's failure posterior, in one pass over the cells.

The maths is :func:`prismap.sensor_models.blend_increments`' (docs/SENSOR_MODELS.md, "Matcher failures"), as
odds of positive terms: no difference cancels, and it stays exact however far the failure-free posterior is
from the prior. Its exp and log are the
vectorisable :func:`~prismap.sensor_models._kernels_math.fast_exp` and
:func:`~prismap.sensor_models._kernels_math.fast_log`, written with selects so that the loops vectorise: the
blend is on every cell of a ray-mode frame, and as numpy expressions it cost more than PRISM's table look-ups.
"""

import math

import numba as nb
import numpy as np

from prismap.sensor_models._kernels_march import x_of_z, z_of_x
from prismap.sensor_models._kernels_math import fast_exp, fast_log, log1mexp

_SERIES_BELOW = 1e-3  # below: 1 - exp(-x) by its series, which 1 - fast_exp(-x) would cancel away
_BLOCK = 2048  # cells a block of blend_ray_cells
_EXP_BOUND = 700.0  # increments beyond +-700 nats blend as +-700 would, to float64 precision: exp stays finite

FLOOR_EFOLDS = 40.0
"""Nats by which :func:`floor_depth`'s bound on a cell's ``R / q`` stays below its ray's ``log_floor``: the blend of
``R`` equals that of ``R = 0`` to float64 precision once ``R <= 2^-54 fail q`` (e^-37.4) and the bound's factor 2
costs 0.7 more; the rest spares the tables' error in ``log Z``."""


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _blend(increment, p, q, ok, fail):
    """``(posterior, increment)`` of ``rho P_G + (1 - rho) p_c`` for a cell of prior ``p = p_c`` (``q = 1 - p_c``,
    each given so that neither is a difference near 1), failure-free increment ``increment`` and failure
    posterior ``fail = 1 - rho`` (``ok = rho``). With ``R = exp(increment)`` and ``A = q + p R`` the blend's odds
    are ``p (rho R + fail A) / (q (rho + fail A))``."""
    ratio = fast_exp(min(max(increment, -_EXP_BOUND), _EXP_BOUND))
    posterior, numerator, denominator = _blend_terms(ratio, p, q, ok, fail)
    return posterior, fast_log(numerator) - fast_log(denominator)


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _blend_terms(ratio, p, q, ok, fail):
    """The blend's posterior and the numerator and denominator of its likelihood ratio, from the failure-free one
    ``ratio`` (``R``); the other parameters as :func:`_blend`'s."""
    a = q + p * ratio
    numerator = ok * ratio + fail * a
    denominator = ok + fail * a
    occupied = p * numerator
    return occupied / (occupied + q * denominator), numerator, denominator


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _clipped_prior(rate, start, end, near, far):
    """``(p, q)``: the prior occupancy ``1 - exp(-rate * length)`` of the cell ``[start, end]`` (metres of depth)
    clipped to ``[near, far]`` (``rate``, 1/metre of depth), and ``1 - p``, each without cancellation."""
    length = min(max(end, near), far) - min(max(start, near), far)
    x = rate * max(length, 0.0)
    q = fast_exp(-x)
    return (x * (1.0 - x * (0.5 - x / 6.0)) if x < _SERIES_BELOW else 1.0 - q), q


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def floor_depth(shift, log_z, log_floor, fb, z0, mixture):
    """Depth (metres) up to which a ray's cells are at the failure floor: their blended increment is that of a
    failure-free likelihood ratio ``R = 0`` (certainly free, blended), to float64 precision.

    A cell ``[a, c]`` of prior ``p_c`` has ``P Z = p_c C(a) + int_a^c q g`` with ``C(z) = int_z0^z q g`` and ``q(z) =
    lam e^{-lam (z - z0)}``, so both terms are at most ``p_c G`` with ``G`` the largest ``g`` on ``[z0, c]``, and
    ``R <= 2 q_c G / Z`` (``P`` tiny), whatever the cell's length. :func:`_blend_terms` of such an ``R`` is that of 0
    when ``R <= 2^-54 fail q`` (``fail q`` is the numerator's other term, ``q`` the denominator's ``a``); with a
    pass-through chance ``m > 0`` the thinned ratio ``m + (1 - m) R`` is ``m`` when ``R <= 2^-54 m``. So the cells
    ending before the depth where ``G / Z`` first reaches ``e^(log_floor - FLOOR_EFOLDS)``, ``log_floor`` the log
    of ``fail`` (or of ``m``), are at the floor. ``G`` is bounded component by component: component ``j`` of the
    mixture (:class:`~prismap.sensor_models._kernel_args.Mixture`) is below its share ``1 / J`` of that bound at
    disparities ``u = fb / z`` more than ``s_j`` of its sigmas above its mean (``u = shift + mu_j``), where it only
    falls towards the camera.

    Parameters
    ----------
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    log_z : float, log
        The ray's ``Z``.
    log_floor : float, log
        ``log(fail)`` of the ray (or ``log(m)``); ``-inf`` (or NaN, like a ``log_z`` that is not finite): no floor.
    fb, z0 : float
        Focal length times baseline (pixel metres) and ``near_m`` (metres).
    mixture : Mixture
        The error mixture.
    """
    if not (log_floor > -np.inf and math.isfinite(log_z)):  # no failures, or no number: no floor
        return z0
    log_wn, means, sigmas = mixture
    log_share = log_z + log_floor - FLOOR_EFOLDS - math.log(means.size)
    depth = np.inf
    for j in range(means.size):
        excess = log_wn[j] - log_share
        if excess <= 0.0:  # below its share at its peak: no bound
            continue
        u = shift + means[j] + sigmas[j] * math.sqrt(2.0 * excess)
        if u > 0.0:
            depth = min(depth, fb / u)
    return max(depth, z0)


_BOUND_WINDOWS = 10
"""Half-sigma windows of true disparity per component, from one sigma behind its mean to four in front, over which
:func:`log_evidence_lower_bound` bounds ``Z`` (in front, nearer depths, the prior is larger)."""


@nb.njit(cache=True, nogil=True)
def log_evidence_lower_bound(shift, slow, fast, log_far, geometry, mixture):
    """A lower bound on ``log Z`` of every ray of rate ``slow`` to ``fast`` (per metre of depth), without a quadrature.

    Over a window of true disparities ``[u_lo, u_hi]`` within ``[fb / z_max, fb / z0]``, component ``j`` of ``g`` is
    at least its density at the window's end farther from its mean ``u_j = shift + mu_j`` (a Gaussian has no
    minimum inside), and the prior's mass over its depths ``[z_a, z_b] = [fb / u_hi, fb / u_lo]`` is ``e^{-lam
    (z_a - z0)} (1 - e^{-lam (z_b - z_a)})``, which has no minimum inside a range of rates: the lesser of the two
    ends bounds it. The windows are :data:`_BOUND_WINDOWS` half sigmas around each component's mean and half a
    sigma at each end of the range; the far term ``e^{-lam (z_max - z0)} e^log_far``, least at ``fast``, is one more
    bound. Returns the largest. ``shift``, ``mixture`` as :func:`floor_depth`'s; ``geometry``
    (:class:`~prismap.sensor_models._kernel_args.Geometry`) gives ``z0``, ``z_max`` and ``fb``.
    """
    z0, z_max, fb, _ = geometry
    log_wn, means, sigmas = mixture
    u_min, u_max = fb / z_max, fb / z0
    best = log_far - fast * (z_max - z0)
    for j in range(means.size):
        u_j, half = shift + means[j], 0.5 * sigmas[j]
        for m in range(_BOUND_WINDOWS + 2):
            if m < _BOUND_WINDOWS:
                u_lo = u_j + (m - 2) * half
            else:
                u_lo = u_max - half if m == _BOUND_WINDOWS else u_min
            u_lo = max(u_lo, u_min)
            u_hi = min(u_lo + half, u_max)
            if u_hi <= u_lo or u_hi <= 0.0:
                continue
            t = max(abs(u_lo - u_j), abs(u_hi - u_j)) / sigmas[j]
            z_a, z_b = fb / u_hi, fb / u_lo if u_lo > 0.0 else z_max
            mass = min(
                -slow * (z_a - z0) + log1mexp(-slow * (z_b - z_a)), -fast * (z_a - z0) + log1mexp(-fast * (z_b - z_a))
            )
            best = max(best, log_wn[j] - 0.5 * t * t + mass)
    return best


_START_PANELS = 16.0
"""Fine node spacings a table keeps at least between its start (:func:`table_start`) and ``z_max``."""


@nb.njit(cache=True, nogil=True)
def table_start(shift, lam, log_far, geometry, spec, mixture):
    """Depth (metres) where a table of ``(shift, lam)`` starts: every cell of a ray sharing it that ends before is
    at the ray's failure floor (:func:`floor_depth`), so the table needs no node there.

    The floor of the model's least level ``spec.log_floor`` (:class:`~prismap.sensor_models._kernel_args.TableSpec`;
    ``-inf``: none, ``z0``) and of :func:`log_evidence_lower_bound`'s ``Z`` over the rates that share the table,
    ``lam (1 +- spec.lam_slack)``, lies before every ray's own floor. It stays :data:`_START_PANELS` fine spacings
    (``spec.h``) before ``z_max``. ``shift``, ``log_far`` and ``mixture`` as :func:`log_evidence_lower_bound`'s.
    """
    z0, z_max, fb, ku = geometry
    if not spec.log_floor > -np.inf:
        return z0
    log_z = log_evidence_lower_bound(
        shift, lam * (1.0 - spec.lam_slack), lam * (1.0 + spec.lam_slack), log_far, geometry, mixture
    )
    start = floor_depth(shift, log_z, spec.log_floor, fb, z0, mixture)
    return max(min(start, z_of_x(x_of_z(z_max, lam, ku) - _START_PANELS * spec.h, lam, ku)), z0)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def blend_cells(increment, prior_log_odds, log_fail, log_ok):
    """:func:`_blend` of every cell (all (C,) float64): ``(posterior, increment)``."""
    n = increment.size
    posterior, blended = np.empty(n), np.empty(n)
    for i in range(n):
        p = 1.0 / (1.0 + fast_exp(-prior_log_odds[i]))
        q = 1.0 / (1.0 + fast_exp(prior_log_odds[i]))
        posterior[i], blended[i] = _blend(increment[i], p, q, fast_exp(log_ok[i]), fast_exp(log_fail[i]))
    return posterior, blended


@nb.njit(cache=True, nogil=True, error_model="numpy")
def blend_ray_cells(increment, rays, start, end, cell_rate, near, far, log_fail, log_ok):
    """:func:`_blend` of every cell ``[start, end]`` (metres of depth, clipped to ``[near, far]``) of ray
    ``rays`` ((C,) int64), its prior ``1 - exp(-cell_rate * length)`` (``cell_rate`` (C,), 1/metre of depth);
    ``log_fail``, ``log_ok``: (R,) per ray. Returns ``(posterior, increment)``, (C,) float64 each.

    The rays' failure posteriors are gathered a block of :data:`_BLOCK` cells at a time into buffers, so
    that the loop doing the maths reads only contiguous arrays and vectorises (a gather in it stops that)."""
    ok, fail = np.exp(log_ok), np.exp(log_fail)
    n = increment.size
    posterior, blended = np.empty(n), np.empty(n)
    ok_cell, fail_cell = np.empty(_BLOCK), np.empty(_BLOCK)
    for first in range(0, n, _BLOCK):
        size = min(_BLOCK, n - first)
        for j in range(size):
            ray = rays[first + j]
            ok_cell[j] = ok[ray]
            fail_cell[j] = fail[ray]
        for j in range(size):
            i = first + j
            posterior[i], blended[i] = blend_cell(
                increment[i], cell_rate[i], start[i], end[i], near, far, ok_cell[j], fail_cell[j]
            )
    return posterior, blended


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def blend_cell(increment, rate, start, end, near, far, ok, fail):
    """:func:`_blend` of one cell of failure-free ``increment`` (log-odds) and prior :func:`_clipped_prior`:
    ``(posterior, increment)``."""
    p, q = _clipped_prior(rate, start, end, near, far)
    return _blend(increment, p, q, ok, fail)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def blend_ratios_into(posterior, ratio, rate, start, end, near, far, ok, fail, count):
    """:func:`blend_cell` of the first ``count`` cells from their failure-free likelihood ratios ``ratio`` (``e^``
    the increment; overwritten by the blend's) instead of increments: no exp and log per cell before the caller's
    one log (each cell's ``rate``, ``ok`` and ``fail`` gathered beforehand, so that the loop vectorises).
    ``posterior`` is written; all arrays (count,) float64 or longer."""
    for j in range(count):
        p, q = _clipped_prior(rate[j], start[j], end[j], near, far)
        posterior[j], numerator, denominator = _blend_terms(ratio[j], p, q, ok[j], fail[j])
        ratio[j] = numerator / denominator


SILENT_STEP = 0.125
"""Sigmas between the points at which :func:`silent_rays` bounds a component's density times the prior's survival."""


@nb.njit(cache=True, nogil=True, error_model="numpy")
def silent_rays(shift, lam, lam_len, log_z, log_fail, log_ok, model_of_ray, fb, z0, models, epsilon):
    """Whether every cell a ray may meet changes by less than ``epsilon`` (log-odds): (R,) bool.

    A cell ``[a, c]`` of prior ``p_c`` has ``P = rho P_G + (1 - rho) p_c`` (docs/SENSOR_MODELS.md, "Silent rays").
    From ``P_G >= 0``, ``P >= (1 - rho) p_c``; from ``C(a) <= Z`` and ``int_a^c q g <= p_c e^{lam L} M`` (``M =
    sup_t e^{-lam (t - z0)} g(t)``, ``L`` the longest cell), ``P <= p_c (1 + K)`` with ``K = rho e^{lam L} M / Z``.
    With ``p`` the longest cell's prior the increment lies in ``[log(1 - rho) - log1p(rho p / (1 - p)), log1p(K) -
    log1p(-K p / (1 - p))]``; a ray is silent when both ends are within ``epsilon`` of 0. ``M`` is bounded component
    by component (:func:`_log_component_sup`).

    Parameters
    ----------
    shift : (R,) float64, pixels
        Each ray's table's disparity plus ``doffs``.
    lam : (R,) float64, 1/metre of depth
        Each ray's prior rate.
    lam_len : (R,) float64
        Each ray's rate times its longest cell (its prior's ``-log(1 - p)``).
    log_z, log_fail, log_ok : (R,) float64
        Each ray's ``log Z`` and ``log(1 - rho)``, ``log(rho)``.
    model_of_ray : (R,) int64
        Each ray's row of ``models`` (:class:`~prismap.sensor_models._kernel_args.MixtureSet`).
    fb, z0 : float
        Focal length times baseline (pixel metres) and ``near_m`` (metres).
    epsilon : float, log-odds
    """
    silent = np.zeros(shift.size, dtype=np.bool_)
    for r in range(shift.size):
        odds = math.expm1(lam_len[r])  # p / (1 - p) of the longest cell
        if not -log_fail[r] + math.log1p(math.exp(log_ok[r]) * odds) < epsilon:
            continue
        k = model_of_ray[r]
        log_scale = log_ok[r] + lam_len[r] - log_z[r]  # log K = log_scale + log M
        cap = math.log(math.expm1(epsilon)) - log_scale  # log M past which log1p(K) alone reaches epsilon
        log_m = -np.inf
        for j in range(models.size[k]):
            centre = shift[r] + models.means[k, j]
            term = models.log_wn[k, j]
            term += _log_component_sup(centre, models.sigmas[k, j], lam[r], fb, z0, cap - term)
            log_m = max(log_m, term) + math.log1p(math.exp(-abs(log_m - term)))  # log(e^log_m + e^term)
            if not log_m < cap:
                break
        ratio = math.exp(log_scale + log_m)  # K
        silent[r] = ratio * odds < 0.5 and math.log1p(ratio) - math.log1p(-ratio * odds) < epsilon
    return silent


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _log_component_sup(centre, sigma, lam, fb, z0, cap):
    """A bound on ``log sup_{t >= z0} e^{-x^2 / 2} e^{-lam (t - z0)}``, ``x = (fb / t - centre) / sigma``: beyond the
    peak (``x <= 0``) the survival at the peak's depth; in front, on each step of :data:`SILENT_STEP` sigmas ``x in
    [k, k + step]``, ``e^{-k^2 / 2}`` times the survival at the step's nearer end, until ``e^{-k^2 / 2}`` alone is
    below the bound so far, or the bound has reached ``cap`` (the caller's answer then is known)."""
    best = _log_survival(centre, fb, z0, lam)
    k = 0.0
    while -0.5 * k * k > best and best < cap:
        best = max(best, -0.5 * k * k + _log_survival(centre + (k + SILENT_STEP) * sigma, fb, z0, lam))
        k += SILENT_STEP
    return best


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _log_survival(u, fb, z0, lam):
    """Log of the prior's survival ``e^{-lam (t - z0)}`` at the depth ``t = max(fb / u, z0)`` of disparity ``u``;
    ``-inf`` when ``u <= 0`` (no depth has it)."""
    if not u > 0.0:
        return -np.inf
    return -lam * (max(fb / u, z0) - z0)
