"""EM fit of a 1-D Gaussian mixture to weighted samples or to a fine histogram (SENSOR_MODELS.md sec. 2).

A histogram with bins of width ``h`` is fitted as its bin centres weighted by their counts. That makes each
EM iteration cost O(bins) instead of O(errors), so tens of millions of errors fit in well under a second.
The price is Sheppard's grouping bias: every component variance comes out about ``h^2 / 12`` too large,
0.4 % in sigma for sigma = 0.1 px at ``h = 1/32`` px and less for wider components. The same ``h^2 / 12``
is the variance floor, so no component can shrink below the resolution of the data.

References
----------
.. [1] A. P. Dempster, N. M. Laird, D. B. Rubin, "Maximum likelihood from incomplete data via the EM
   algorithm", J. R. Stat. Soc. B 39(1), 1977.
.. [2] D. Arthur, S. Vassilvitskii, "k-means++: the advantages of careful seeding", SODA 2007.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_integer, check_positive
from prismap.errors import PrismapInputError
from prismap.gmm._kernels import em_weighted, kmeans_plus_plus
from prismap.gmm._mixture import GaussianMixture, check_search_range

CRITERIA = ("bic", "aic")
DEFAULT_FAILURE_PRIOR = 1.0
"""Pseudo-failures of the failure weight's prior (``Beta(1 + a, 1)`` with ``a = 1``, MAP: see :func:`fit_mixture`)."""


def n_parameters(n_components: int, with_failure: bool) -> int:
    """Free parameters of a G-component mixture: ``3G - 1``, plus 1 for a failure component's weight."""
    return 3 * n_components - 1 + int(bool(with_failure))


def failure_prior_bound(n_errors: float, failure_prior: float = DEFAULT_FAILURE_PRIOR) -> float:
    """The least failure weight the prior allows after ``n_errors`` errors none of which is gross.

    MAP-EM gives ``w_f = (R_f + a) / (N + a)`` with ``a = failure_prior`` pseudo-failures (a ``Beta(1 + a, 1)``
    prior on ``w_f``): at least ``a / (N + a)``, about ``1 / N`` for ``a = 1``. That is Laplace's rule of
    succession (the predictive failure rate after no failure in ``N`` trials is ``1 / (N + 2)``), within the
    rule of three's 95 % bound ``3 / N``: ``N`` clean errors cannot claim a failure rate far below ``1 / N``.
    """
    a = check_positive(failure_prior, "failure_prior")
    return a / (float(n_errors) + a)


@dataclass(frozen=True)
class MixtureFit:
    """One fitted mixture and how well it explains the data.

    Attributes
    ----------
    mixture : GaussianMixture
    log_likelihood : float, nats
        ``ln L = sum_i w_i ln p(x_i)`` over the (weighted) samples; for a histogram the samples are the
        bin centres weighted by their counts. This is a log *density*, comparable with a fit to the raw
        errors; the log-probability of the bin counts themselves is ``ln L + n_samples * ln(bin_width)``.
    aic : float
        ``2k - 2 ln L`` with ``k = 3G - 1`` free parameters, ``3G`` with a failure component (its weight).
        (The thesis, eq. 3.11, printed ``2G`` as the penalty; this is the standard count: G means, G sigmas,
        G - 1 free weights.)
    bic : float
        ``k ln N - 2 ln L`` with ``N = n_samples``.
    n_samples : float
        Total weight of the data (the number of errors for counts or unit weights).
    n_iter : int
        EM iterations of the best start.
    converged : bool
        Whether the relative log-likelihood tolerance was met before ``max_iter``.
    """

    mixture: GaussianMixture
    log_likelihood: float
    aic: float
    bic: float
    n_samples: float
    n_iter: int
    converged: bool

    @property
    def n_components(self) -> int:
        """Number of components G."""
        return self.mixture.n_components

    @property
    def n_parameters(self) -> int:
        """Free parameters ``k = 3G - 1``, plus 1 for a failure component's weight."""
        return n_parameters(self.n_components, self.mixture.search_range_px is not None)

    @property
    def mean_log_likelihood(self) -> float:
        """``ln L / N``: nats per sample."""
        return self.log_likelihood / self.n_samples


def fit_mixture(
    values: npt.ArrayLike,
    *,
    weights: npt.ArrayLike | None = None,
    n_components: int,
    bin_width: float | None = None,
    restarts: int = 4,
    seed: int = 0,
    tol: float = 1e-9,
    max_iter: int = 3000,
    min_sigma: float | None = None,
    search_range_px: tuple[float, float] | None = None,
    failure_prior: float = DEFAULT_FAILURE_PRIOR,
) -> MixtureFit:
    """Fit a G-component Gaussian mixture to 1-D samples by EM.

    Parameters
    ----------
    values : (N,) float, pixels
        Samples (disparity errors); NaN or infinity is an error.
    weights : (N,) float, >= 0, optional
        Sample weights; a weight of 3 counts like three copies of the sample.
    n_components : int, >= 1
        G; at most the number of distinct values with positive weight.
    bin_width : float, pixels, optional
        If given, the samples are first accumulated into a histogram of this bin width (bin edges at
        multiples of it) and the histogram is fitted (:func:`fit_histogram`): O(bins) per iteration
        instead of O(N), at the cost of Sheppard's ``bin_width^2 / 12`` variance bias.
    restarts : int, >= 1
        Starts tried; the best final log-likelihood wins. Start 0 puts the means at the quantiles
        ``(j + 1/2)/G``; start 1 nests all components at the median with widths spread from the
        robust (MAD) sigma to the standard deviation, the shape of stereo errors; the others are
        k-means++ seedings from ``seed``.
    seed : int
        Seed of the k-means++ starts: the result is a deterministic function of the inputs.
    tol : float, > 0
        Relative log-likelihood tolerance: stop when ``ln L`` rises by less than ``tol * |ln L|``.
    max_iter : int, >= 1
        EM iterations per start.
    min_sigma : float, pixels, optional
        Lower bound of every sigma. Default ``1e-3 *`` the standard deviation of the samples; with a
        histogram it is never below ``bin_width / sqrt(12)``, the spread of a value within its bin.
    search_range_px : (lo, hi), pixels, optional
        The matcher's disparity search range. If given, the mixture gains the matcher-failure component of
        density ``1 / W`` (``W = hi - lo``) per error, its weight ``w_f`` fitted with the Gaussians by MAP-EM
        (:func:`failure_prior_bound` states the prior).
    failure_prior : float, > 0
        Pseudo-failures of that prior: ``w_f = (R_f + failure_prior) / (N + failure_prior)`` with ``R_f`` the
        failure responsibilities of ``N`` errors, so ``n`` errors without a gross one still give
        ``w_f >= failure_prior / (n + failure_prior)``.

    Returns
    -------
    MixtureFit
    """
    points = as_float_array(values, "values", ndim=1, allow_nan=False)
    if weights is None:
        counts = np.ones_like(points)
    else:
        counts = as_float_array(weights, "weights", shape=(points.size,), allow_nan=False)
        if np.any(counts < 0):
            raise PrismapInputError("`weights` must be >= 0; got a negative weight")
    if bin_width is not None:
        width = check_positive(bin_width, "bin_width")
        index = np.floor(points / width).astype(np.int64)
        low = index.min() if index.size else 0
        binned = np.bincount(index - low, weights=counts)
        centres = (np.arange(binned.size) + low + 0.5) * width
        return _fit(
            centres,
            binned,
            n_components=n_components,
            bin_width=width,
            restarts=restarts,
            seed=seed,
            tol=tol,
            max_iter=max_iter,
            min_sigma=min_sigma,
            search_range_px=search_range_px,
            failure_prior=failure_prior,
        )
    return _fit(
        points,
        counts,
        n_components=n_components,
        bin_width=None,
        restarts=restarts,
        seed=seed,
        tol=tol,
        max_iter=max_iter,
        min_sigma=min_sigma,
        search_range_px=search_range_px,
        failure_prior=failure_prior,
    )


def fit_histogram(
    bin_edges: npt.ArrayLike,
    counts: npt.ArrayLike,
    *,
    n_components: int,
    restarts: int = 4,
    seed: int = 0,
    tol: float = 1e-9,
    max_iter: int = 3000,
    min_sigma: float | None = None,
    search_range_px: tuple[float, float] | None = None,
    failure_prior: float = DEFAULT_FAILURE_PRIOR,
) -> MixtureFit:
    """Fit a G-component Gaussian mixture to a histogram by EM on its counted bin centres.

    Parameters
    ----------
    bin_edges : (B + 1,) float, pixels, increasing with equal spacing
    counts : (B,) float, >= 0
        Errors per bin.
    n_components, restarts, seed, tol, max_iter, min_sigma, search_range_px, failure_prior
        As in :func:`fit_mixture`; ``min_sigma`` is at least ``bin_width / sqrt(12)``.

    Returns
    -------
    MixtureFit
        ``log_likelihood`` is ``sum counts * ln p(centres)`` (see :class:`MixtureFit`).
    """
    edges = as_float_array(bin_edges, "bin_edges", ndim=1, allow_nan=False)
    if edges.size < 2:
        raise PrismapInputError(f"`bin_edges` needs at least 2 edges; got {edges.size}")
    widths = np.diff(edges)
    if np.any(widths <= 0) or not np.allclose(widths, widths[0], rtol=1e-6, atol=0):
        raise PrismapInputError("`bin_edges` must be increasing with equal spacing")
    values = as_float_array(counts, "counts", shape=(edges.size - 1,), allow_nan=False)
    if np.any(values < 0):
        raise PrismapInputError("`counts` must be >= 0; got a negative count")
    centres = 0.5 * (edges[:-1] + edges[1:])
    return _fit(
        centres,
        values,
        n_components=n_components,
        bin_width=float(widths[0]),
        restarts=restarts,
        seed=seed,
        tol=tol,
        max_iter=max_iter,
        min_sigma=min_sigma,
        search_range_px=search_range_px,
        failure_prior=failure_prior,
    )


def fit_outlier_weight(
    mixture: GaussianMixture,
    outlier: GaussianMixture,
    bin_edges: npt.ArrayLike,
    counts: npt.ArrayLike,
    *,
    prior_count: float = 1.0,
) -> float:
    """Weight ``w`` of a fixed outlier component mixed into a fitted mixture: ``(1 - w) mixture + w outlier``.

    The two shapes stay as they are; ``w`` maximises the histogram's log-likelihood plus
    ``prior_count * ln w``, as if ``prior_count`` more errors had come from ``outlier`` (a Beta prior on
    ``w``). Without that pseudo-count ``w`` would be 0 for data that hold no gross error, and one gross
    error of unseen data would then cost hundreds of nats under a narrow mixture. ``w`` is about
    ``(outlier errors + prior_count) / (N + prior_count)``.

    Parameters
    ----------
    mixture : GaussianMixture
        The fitted mixture (pixels).
    outlier : GaussianMixture
        The component(s) to mix in, e.g. the widest component of a model fitted to more data (pixels).
    bin_edges : (B + 1,) float, pixels
    counts : (B,) float, >= 0, not all 0
        The histogram ``mixture`` was fitted to.
    prior_count : float, > 0
        Pseudo-errors from the outlier component.

    Returns
    -------
    float in (0, 1)
    """
    edges = as_float_array(bin_edges, "bin_edges", ndim=1, allow_nan=False)
    values = as_float_array(counts, "counts", shape=(edges.size - 1,), allow_nan=False)
    prior = check_positive(prior_count, "prior_count")
    if np.any(values < 0) or values.sum() <= 0:
        raise PrismapInputError("`counts` must be >= 0 and not all 0")
    occupied = np.flatnonzero(values)
    centres = 0.5 * (edges[occupied] + edges[occupied + 1])
    weights = values[occupied]
    inlier, outside = mixture.logpdf(centres), outlier.logpdf(centres)

    from scipy.optimize import minimize_scalar  # here, not above: slow to import, and few commands need it

    def cost(log_w):  # concave in w: one bounded 1-D search over ln w finds its maximum
        return -(weights @ np.logaddexp(np.log1p(-np.exp(log_w)) + inlier, log_w + outside) + prior * log_w)

    # ln w from 1e-12 (far below 1 / N for any histogram) to ln 0.5
    return float(
        np.exp(minimize_scalar(cost, bounds=(np.log(1e-12), np.log(0.5)), method="bounded", options={"xatol": 1e-6}).x)
    )


def fit_mixtures(
    bin_edges: npt.ArrayLike, counts: npt.ArrayLike, *, max_components: int, **options: Any
) -> list[MixtureFit]:
    """Fit G = 1 .. ``max_components`` to one histogram; ``options`` go to :func:`fit_histogram`.

    Returns
    -------
    list of MixtureFit, index ``G - 1``.
    """
    max_components = _check_count(max_components, "max_components")
    return [fit_histogram(bin_edges, counts, n_components=g, **options) for g in range(1, max_components + 1)]


def select_components(fits: Sequence[MixtureFit], *, criterion: str = "bic", tolerance: float = 0.01) -> int:
    """Pick G: the smallest G whose criterion is within ``tolerance`` nats per sample of the best.

    With millions of errors the AIC/BIC penalties (tens) vanish against log-likelihood gains (thousands),
    so a plain minimum always picks the largest G tried, modelling every ripple of one dataset (the thesis
    saw near-equal AIC for 3 and 9 components and chose by eye). The tolerance turns that eye into a rule:
    an extra component must raise the mean log-likelihood per error by more than ``tolerance`` nats
    (criterion difference ``<= 2 * tolerance * N``). ``tolerance=0`` is the plain minimum.

    Parameters
    ----------
    fits : sequence of MixtureFit
        Fits of one data set (equal ``n_samples``), any order.
    criterion : {"bic", "aic"}
    tolerance : float, nats per sample, >= 0

    Returns
    -------
    int: the selected G.
    """
    if criterion not in CRITERIA:
        raise PrismapInputError(f"`criterion` must be one of {list(CRITERIA)}; got {criterion!r}")
    fits = list(fits)
    if not fits:
        raise PrismapInputError("`fits` is empty: nothing to select from")
    tolerance = float(tolerance)
    if not np.isfinite(tolerance) or tolerance < 0:
        raise PrismapInputError(f"`tolerance` must be a finite number >= 0; got {tolerance!r}")
    scores = np.array([getattr(fit, criterion) for fit in fits])
    allowed = 2.0 * tolerance * fits[0].n_samples
    candidates = [fit.n_components for fit, score in zip(fits, scores) if score <= scores.min() + allowed]
    return min(candidates)


def _check_count(value, name):
    return check_integer(value, name, expected="an integer >= 1", condition=lambda n: n >= 1)


def _fit(
    points,
    counts,
    *,
    n_components,
    bin_width,
    restarts,
    seed,
    tol,
    max_iter,
    min_sigma,
    search_range_px=None,
    failure_prior=DEFAULT_FAILURE_PRIOR,
):
    n_components = _check_count(n_components, "n_components")
    floor_density, prior = 0.0, 0.0
    if search_range_px is not None:
        search_range_px = check_search_range(search_range_px, "`search_range_px`")
        floor_density = 1.0 / (search_range_px[1] - search_range_px[0])
        prior = check_positive(failure_prior, "failure_prior")
    restarts = _check_count(restarts, "restarts")
    max_iter = _check_count(max_iter, "max_iter")
    tol = check_positive(tol, "tol")
    keep = counts > 0
    points = np.ascontiguousarray(points[keep])
    counts = np.ascontiguousarray(counts[keep])
    if points.size == 0:
        raise PrismapInputError("no data to fit: the error set is empty (or every weight/count is 0)")
    distinct = np.unique(points).size
    if n_components > distinct:
        raise PrismapInputError(f"`n_components` = {n_components} exceeds the {distinct} distinct value(s) in the data")
    total = counts.sum()
    mean = counts @ points / total
    std = np.sqrt(counts @ (points - mean) ** 2 / total)
    if min_sigma is not None:
        min_sigma = check_positive(min_sigma, "min_sigma")
    elif bin_width is None:
        min_sigma = max(1e-3 * std, 1e-12)
    if bin_width is not None:
        min_sigma = max(min_sigma or 0.0, bin_width / np.sqrt(12.0))
    var_floor = min_sigma**2
    floor_start = _failure_start(points, counts, total, prior) if floor_density else 0.0
    best, best_score = None, -np.inf
    for start in _starts(points, counts, n_components, restarts, seed, mean, std):
        w0, mu0, var0 = (np.ascontiguousarray(a, dtype=np.float64) for a in start)
        result = em_weighted(
            points,
            counts,
            w0,
            mu0,
            np.maximum(var0, var_floor),
            var_floor,
            tol,
            max_iter,
            floor_density,
            floor_start,
            prior,
        )
        score = result[4] + (prior * np.log(result[3]) if floor_density else 0.0)  # the log-posterior EM climbs
        if best is None or score > best_score:
            best, best_score = result, score
    weights, means, variances, failure_weight, log_lik, n_iter, converged = best
    order = np.argsort(-weights, kind="stable")
    mixture = GaussianMixture(weights[order], means[order], np.sqrt(variances[order]), failure_weight, search_range_px)
    k = n_parameters(n_components, floor_density > 0)
    return MixtureFit(
        mixture=mixture,
        log_likelihood=float(log_lik),
        aic=float(2 * k - 2 * log_lik),
        bic=float(k * np.log(total) - 2 * log_lik),
        n_samples=float(total),
        n_iter=int(n_iter),
        converged=bool(converged),
    )


def _failure_start(points, counts, total, prior):
    """Starting failure weight: the share of errors beyond 8 robust sigmas (+ 1 px) of the median, or the prior's."""
    median = _weighted_quantiles(points, counts, [0.5])[0]
    deviations = np.abs(points - median)
    mad_sigma = 1.4826 * _weighted_quantiles(deviations, counts, [0.5])[0]
    far = counts[deviations > 8.0 * mad_sigma + 1.0].sum()
    return float(np.clip((far + prior) / (total + prior), 1e-6, 0.5))


def _weighted_quantiles(points, counts, probabilities):
    order = np.argsort(points, kind="stable")
    cumulative = np.cumsum(counts[order])
    positions = np.searchsorted(cumulative, np.asarray(probabilities) * cumulative[-1], side="left")
    return points[order][np.minimum(positions, points.size - 1)]


def _starts(points, counts, n_components, restarts, seed, mean, std):
    """Yield ``(weights, means, variances)`` starting mixtures; one for G = 1 (EM's answer is unique)."""
    g = n_components
    yield np.full(g, 1.0 / g), _weighted_quantiles(points, counts, (np.arange(g) + 0.5) / g), np.full(g, (std / g) ** 2)
    if g == 1 or restarts == 1:
        return
    median = _weighted_quantiles(points, counts, [0.5])[0]
    deviations = np.abs(points - median)
    mad_sigma = 1.4826 * _weighted_quantiles(deviations, counts, [0.5])[0]
    low = max(min(mad_sigma, std), 1e-3 * std, 1e-12)
    yield np.full(g, 1.0 / g), np.full(g, median), np.geomspace(low, max(std, low), g) ** 2
    rng = np.random.default_rng(seed)
    for _ in range(restarts - 2):
        centres = np.sort(kmeans_plus_plus(points, counts, g, rng.random(g)))
        label = np.searchsorted(0.5 * (centres[1:] + centres[:-1]), points)
        mass = np.bincount(label, weights=counts, minlength=g)
        spread = np.bincount(label, weights=counts * (points - centres[label]) ** 2, minlength=g)
        variances = np.where(mass > 0, spread / np.maximum(mass, 1e-300), std**2)
        weights = mass + 0.01 * mass.sum() / g  # an empty cluster still starts alive
        yield weights / weights.sum(), centres, np.where(variances > 0, variances, (std / g) ** 2)
