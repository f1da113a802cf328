"""PRISM's discrete reference on one ray of cells (the thesis form, SENSOR_MODELS.md section 5) and the mean
likelihood of a disparity interval it and the continuous model share.

References
----------
E. Kaufman, T. Lee, Z. Ai, "Bayesian occupancy grid mapping via an exact inverse sensor model", ACC 2016.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.special import log_ndtr, logsumexp

from prismap._validate import as_float_array, check_positive, check_probability
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture


def _log_diff_ndtr(hi, lo):
    """``log(Phi(hi) - Phi(lo))`` for ``hi >= lo``, accurate in both tails."""
    hi, lo = np.broadcast_arrays(np.asarray(hi, dtype=np.float64), np.asarray(lo, dtype=np.float64))
    upper = lo > 0  # both in the upper tail: use the mirrored pair
    a = np.where(upper, -lo, hi)
    b = np.where(upper, -hi, lo)
    log_a = log_ndtr(a)
    with np.errstate(divide="ignore"):
        return log_a + np.log(-np.expm1(np.minimum(log_ndtr(b) - log_a, 0.0)))


def with_floor(log_likelihood, mixture):
    """``log((1 - w_f) L + w_f / W)`` of the Gaussians' ``log L``: the likelihood with the failure floor
    (docs/SENSOR_MODELS.md section 8); ``log L`` itself without a failure component."""
    if mixture.failure_weight == 0.0:
        return log_likelihood
    return np.logaddexp(np.log1p(-mixture.failure_weight) + log_likelihood, np.log(mixture.failure_density))


def log_mean_likelihood(
    u_lo: npt.ArrayLike,
    u_hi: npt.ArrayLike,
    disparity_px: npt.ArrayLike,
    mixture: GaussianMixture,
    doffs_px: float = 0.0,
) -> npt.NDArray[np.float64]:
    """Log of ``g`` averaged over true disparities uniform in ``[u_lo, u_hi]`` (pixels); arrays broadcast.

    ``g(u) = sum_j w_j N(u - doffs - d^; mu_j, sigma_j^2)``, so the average is a sum of normal-CDF
    differences divided by ``u_hi - u_lo``.
    """
    u_lo, u_hi, d = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (u_lo, u_hi, disparity_px)))
    shift = (d + doffs_px)[..., None] + mixture.means
    terms = np.log(mixture.weights) + _log_diff_ndtr(
        (u_hi[..., None] - shift) / mixture.sigmas, (u_lo[..., None] - shift) / mixture.sigmas
    )
    return logsumexp(terms, axis=-1) - np.log(u_hi - u_lo)


def prism_discrete_posteriors(
    disparity_px: float,
    cell_edges_depth_m: npt.ArrayLike,
    mixture: GaussianMixture,
    *,
    focal_baseline: float,
    doffs_px: float = 0.0,
    p0: float = 0.05,
) -> npt.NDArray[np.float64]:
    """The thesis's discrete PRISM on one ray of equal cells: O(n) with prefix sums, in log space.

    Cell ``k`` (1-based) is the first occupied one with ``pi_k = p0 (1 - p0)^(k-1)`` and then produces
    ``d^`` with ``L_k``, ``g`` averaged uniformly in disparity over the cell; no occupied cell gives
    ``pi_far = (1 - p0)^n`` and ``L_far``, ``g`` averaged over true disparities in ``(0, f b / z_n]``.
    ``P(m_i | d^) = (p0 sum_{k<i} pi_k L_k + pi_i L_i) / (sum_k pi_k L_k + pi_far L_far)``. A mixture with a
    failure component adds its floor to every likelihood: ``L -> (1 - w_f) L + w_f / W``.

    Parameters
    ----------
    disparity_px : float, pixels
        Measured disparity ``d^``.
    cell_edges_depth_m : (n + 1,) float64, metres, increasing, > 0
        Cell boundaries along the ray (depth); the spec's cells are equal, any increasing edges work.
    mixture : GaussianMixture
        Disparity error model ``e = d_true - d^``.
    focal_baseline : float, pixel-metres
    doffs_px : float, pixels
    p0 : float in (0, 1)
        Prior occupancy of one cell.

    Returns
    -------
    posterior : (n,) float64 in [0, 1]
    """
    edges = as_float_array(cell_edges_depth_m, "cell_edges_depth_m", ndim=1, allow_nan=False)
    if edges.size < 2 or edges[0] <= 0 or np.any(np.diff(edges) <= 0):
        raise PrismapInputError("`cell_edges_depth_m` must hold >= 2 increasing depths > 0")
    fb = check_positive(focal_baseline, "focal_baseline")
    p0 = check_probability(p0, "p0")
    d = float(disparity_px)
    u = fb / edges
    n = edges.size - 1
    log_l = with_floor(log_mean_likelihood(u[1:], u[:-1], d, mixture, doffs_px), mixture)
    log_pi = np.log(p0) + np.arange(n) * np.log1p(-p0)
    log_far = n * np.log1p(-p0) + with_floor(log_mean_likelihood(0.0, u[-1], d, mixture, doffs_px), mixture)
    terms = log_pi + log_l
    before = np.concatenate(([-np.inf], np.logaddexp.accumulate(terms)[:-1]))
    log_num = np.logaddexp(np.log(p0) + before, terms)
    log_norm = np.logaddexp(np.logaddexp.reduce(terms), log_far)
    return np.exp(log_num - log_norm)
