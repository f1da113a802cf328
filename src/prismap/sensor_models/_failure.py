"""Matcher failures in the inverse sensor models: the failure posterior of a measurement and the evidence bound.

A matcher fails with probability ``w_f`` and then returns a disparity uniform over its search range of ``W``
pixels, whatever the scene holds (:class:`prismap.gmm.GaussianMixture` with a failure component). The
likelihood of a measurement ``d^`` given the map is then ``(1 - w_f) p_G(d^ | map) + w_f / W``, and for any
cell ``c`` of prior ``p_c`` the posterior is a blend of the failure-free posterior ``P_G`` and the prior::

    P(m_c | d^) = rho P_G + (1 - rho) p_c,   rho = (1 - w_f) p_G(d^) / ((1 - w_f) p_G(d^) + w_f / W)

with ``rho`` the probability that the measurement did not fail and ``p_G(d^)`` its marginal density under the
Gaussians (PRISM's normaliser ``Z``). ``p_G(d^)`` never exceeds the Gaussians' peak density ``g_max``, so
``1 - rho >= eps = (w_f / W) / ((1 - w_f) g_max + w_f / W)``, and one measurement moves a cell's log-odds by
no more than :func:`evidence_bound`. docs/SENSOR_MODELS.md, "Matcher failures", derives all of it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import _kernels_failure


def failure_floor(mixture: GaussianMixture) -> float:
    """``eps``: the least posterior failure probability any measurement has under ``mixture`` (0 without failures).

    Parameters
    ----------
    mixture : GaussianMixture
        The error model; its failure weight ``w_f`` and search width ``W`` (pixels).

    Returns
    -------
    float in [0, 1)
        ``(w_f / W) / ((1 - w_f) g_max + w_f / W)`` with ``g_max`` the Gaussians' peak-density bound
        (:meth:`GaussianMixture.peak_density`, 1/pixel).
    """
    floor = mixture.failure_density
    if floor == 0.0:
        return 0.0
    return float(floor / ((1.0 - mixture.failure_weight) * mixture.peak_density() + floor))


def evidence_bound(
    mixture: GaussianMixture, cell_prior: npt.ArrayLike
) -> tuple[npt.NDArray[np.float64] | float, npt.NDArray[np.float64] | float]:
    """The log-odds change one measurement can cause in a cell of prior ``cell_prior``, at most.

    From ``P in [eps p_c, 1 - eps (1 - p_c)]`` (:func:`failure_floor`): the increment
    ``logit(P) - logit(p_c)`` lies in ``[-ln(1 + (1 - eps) / (eps (1 - p_c))), ln(1 + (1 - eps) / (eps p_c))]``.
    A map's per-frame policies ``mean``, ``max``, ``max-abs`` and ``occupied-wins`` pick or average the
    rays' increments of a voxel, so they keep the bound; ``sum`` multiplies it by the rays.

    Parameters
    ----------
    mixture : GaussianMixture
    cell_prior : float or array in (0, 1)
        ``p_c``: the prior of the ray's stretch in the cell (PRISM: ``1 - exp(-lambda_z (c - a))``).

    Returns
    -------
    low, high : float or arrays, log-odds
        ``-inf`` and ``+inf`` for a mixture without a failure component (no bound).
    """
    prior = np.asarray(cell_prior, dtype=np.float64)
    if np.any(~((prior > 0) & (prior < 1))):
        raise PrismapInputError(f"`cell_prior` must lie in (0, 1); got {cell_prior!r}")
    eps = failure_floor(mixture)
    if eps == 0.0:
        return -np.inf * np.ones_like(prior)[()], np.inf * np.ones_like(prior)[()]
    odds = (1.0 - eps) / eps
    return -np.log1p(odds / (1.0 - prior))[()], np.log1p(odds / prior)[()]


def log_failure_posterior(
    mixture: GaussianMixture, log_marginal: npt.ArrayLike
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``log(1 - rho)`` and ``log(rho)`` of each ray from the log of its failure-free marginal ``p_G(d^)``.

    Parameters
    ----------
    mixture : GaussianMixture
        With a failure component.
    log_marginal : (R,) float
        ``log p_G(d^)`` (log 1/pixel), e.g. PRISM's ``log Z``.

    Returns
    -------
    log_fail, log_ok : (R,) float64
        ``log_fail`` is at least ``log(eps)`` (:func:`failure_floor`), so the bound holds even where an
        approximate ``Z`` exceeds ``g_max``.
    """
    log_z = as_float_array(log_marginal, "log_marginal", ndim=1)
    return failure_posterior_terms(*failure_constants(mixture), log_z)


def failure_constants(mixture: GaussianMixture) -> tuple[float, float, float, float]:
    """What :func:`log_failure_posterior` takes from ``mixture``: ``log(w_f / W)``, ``log(1 - w_f)``, ``log(eps)``
    and ``log(1 - eps)`` (:func:`failure_floor`)."""
    eps = failure_floor(mixture)
    return np.log(mixture.failure_density), np.log1p(-mixture.failure_weight), np.log(eps), np.log1p(-eps)


def failure_posterior_terms(log_density, log_keep, log_eps, log_keep_eps, log_z):
    """``log(1 - rho)`` and ``log(rho)`` from :func:`failure_constants` and ``log Z`` (scalars, or arrays of one
    shape: each ray's own mixture's constants, as a conditioned model's fused look-up takes them)."""
    log_good = log_keep + log_z
    log_total = np.logaddexp(log_density, log_good)
    return np.maximum(log_density - log_total, log_eps), np.minimum(log_good - log_total, log_keep_eps)


def blend_increments(
    increment: npt.ArrayLike, prior_log_odds: npt.ArrayLike, log_fail: npt.ArrayLike, log_ok: npt.ArrayLike
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The increments of ``rho P_G + (1 - rho) p_c`` from those of ``P_G``: ``(posterior, increment)`` per cell.

    With ``R = exp(increment)`` (the odds ratio of ``P_G`` to ``p_c``) and ``A = 1 - p_c + p_c R``
    (``P_G = p_c R / A``), the blend's increment is ``log(rho R + (1 - rho) A) - log(rho + (1 - rho) A)``,
    evaluated in logs, so it stays exact however far ``P_G`` is from ``p_c``.

    Parameters
    ----------
    increment : (C,) float, log-odds
        ``logit(P_G) - logit(p_c)`` of each cell.
    prior_log_odds : (C,) float
        ``logit(p_c)``.
    log_fail, log_ok : (C,) float
        ``log(1 - rho)`` and ``log(rho)`` of each cell's ray (:func:`log_failure_posterior`).

    Returns
    -------
    posterior : (C,) float64
    increment : (C,) float64, log-odds
    """
    arrays = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (increment, prior_log_odds, log_fail, log_ok))
    )
    posterior, blended = _kernels_failure.blend_cells(*(np.ascontiguousarray(a).ravel() for a in arrays))
    return posterior.reshape(arrays[0].shape), blended.reshape(arrays[0].shape)
