"""EM fit of 1-D Gaussian mixtures: recovery of a known mixture, exact special cases, kernel vs numpy."""

import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.gmm import (
    GaussianMixture,
    MixtureFit,
    fit_histogram,
    fit_mixture,
    fit_mixtures,
    fit_outlier_weight,
    select_components,
)
from prismap.gmm._kernels import em_weighted, kmeans_plus_plus

TRUTH = GaussianMixture([0.70, 0.25, 0.05], [0.10, -0.30, 2.00], [0.40, 1.50, 12.00])


def _sample_fast(mixture, n, seed):
    """Seeded samples of ``mixture``: multinomial component sizes, then normals (faster than choice)."""
    rng = np.random.default_rng(seed)
    sizes = rng.multinomial(n, mixture.weights)
    return np.concatenate(
        [rng.normal(mu, sigma, size) for mu, sigma, size in zip(mixture.means, mixture.sigmas, sizes)]
    )


def _histogram(samples, bin_width=1 / 32, limit=256.0):
    edges = np.arange(-limit, limit + bin_width / 2, bin_width)
    index = np.floor((samples + limit) / bin_width).astype(np.int64)
    inside = (index >= 0) & (index < edges.size - 1)
    return edges, np.bincount(index[inside], minlength=edges.size - 1).astype(np.float64)


def _em_reference(points, counts, weights, means, variances, var_floor, n_steps):
    """Plain numpy EM: ``n_steps`` M-steps, then the log-likelihood of the result."""
    w, mu, var = (np.array(a, dtype=np.float64) for a in (weights, means, variances))

    def joint(w, mu, var):
        return w / np.sqrt(2 * np.pi * var) * np.exp(-0.5 * (points[:, None] - mu) ** 2 / var)

    for _ in range(n_steps):
        p = joint(w, mu, var)
        resp = p / p.sum(axis=1, keepdims=True) * counts[:, None]
        mass = resp.sum(axis=0)
        w = mass / counts.sum()
        mu = (resp * points[:, None]).sum(axis=0) / mass
        var = np.maximum((resp * (points[:, None] - mu) ** 2).sum(axis=0) / mass, var_floor)
    return w, mu, var, float(counts @ np.log(joint(w, mu, var).sum(axis=1)))


def test_histogram_fit_recovers_a_known_three_component_mixture_from_20_million_errors():
    edges, counts = _histogram(_sample_fast(TRUTH, 20_000_000, seed=7))
    fit = fit_histogram(edges, counts, n_components=3, seed=0)
    assert fit.converged
    assert fit.n_samples == counts.sum()
    # fitted components come sorted by weight, like TRUTH
    np.testing.assert_allclose(fit.mixture.weights, TRUTH.weights, atol=0.01)
    np.testing.assert_allclose(fit.mixture.means, TRUTH.means, atol=0.02)
    np.testing.assert_allclose(fit.mixture.sigmas, TRUTH.sigmas, rtol=0.03)


def test_single_component_is_the_sample_mean_and_std():
    x = np.random.default_rng(1).gamma(2.0, 1.5, 5000)
    fit = fit_mixture(x, n_components=1)
    assert fit.mixture.means[0] == pytest.approx(x.mean(), rel=1e-12)
    assert fit.mixture.sigmas[0] == pytest.approx(x.std(), rel=1e-10)
    assert fit.log_likelihood == pytest.approx(TRUTH.gaussian(x.std(), x.mean()).logpdf(x).sum(), rel=1e-12)


def test_weighted_samples_equal_repeated_samples():
    rng = np.random.default_rng(2)
    values = np.concatenate([rng.normal(0, 0.5, 60), rng.normal(4, 1.0, 40)])
    repeats = rng.integers(1, 5, values.size)
    weighted = fit_mixture(values, weights=repeats.astype(float), n_components=2)
    repeated = fit_mixture(np.repeat(values, repeats), n_components=2)
    for name in ("weights", "means", "sigmas"):
        np.testing.assert_allclose(getattr(weighted.mixture, name), getattr(repeated.mixture, name), rtol=1e-8)
    assert weighted.log_likelihood == pytest.approx(repeated.log_likelihood, rel=1e-10)
    assert weighted.n_samples == repeats.sum()


def test_fit_is_deterministic_across_calls():
    x = _sample_fast(TRUTH, 20_000, seed=3)
    first, second = (fit_mixture(x, n_components=3, restarts=5, seed=11) for _ in range(2))
    for name in ("weights", "means", "sigmas"):
        assert np.array_equal(getattr(first.mixture, name), getattr(second.mixture, name))
    assert (first.log_likelihood, first.n_iter) == (second.log_likelihood, second.n_iter)


def test_log_likelihood_and_criteria_follow_their_definitions():
    edges, counts = _histogram(_sample_fast(TRUTH, 200_000, seed=4))
    fit = fit_histogram(edges, counts, n_components=2)
    centres = 0.5 * (edges[1:] + edges[:-1])
    assert fit.log_likelihood == pytest.approx(counts @ fit.mixture.logpdf(centres), rel=1e-10)
    k = 3 * 2 - 1
    assert fit.n_parameters == k
    assert fit.aic == pytest.approx(2 * k - 2 * fit.log_likelihood)
    assert fit.bic == pytest.approx(k * np.log(counts.sum()) - 2 * fit.log_likelihood)
    assert fit.mean_log_likelihood == pytest.approx(fit.log_likelihood / counts.sum())


def test_binning_samples_equals_fitting_their_histogram():
    x = _sample_fast(TRUTH, 50_000, seed=5)
    edges, counts = _histogram(x, bin_width=1 / 16, limit=128.0)
    direct = fit_mixture(x, n_components=2, bin_width=1 / 16)
    binned = fit_histogram(edges, counts, n_components=2)
    np.testing.assert_allclose(direct.mixture.sigmas, binned.mixture.sigmas, rtol=1e-9)
    assert direct.log_likelihood == pytest.approx(binned.log_likelihood, rel=1e-10)


def test_more_components_never_lower_the_log_likelihood_and_selection_prefers_the_truth():
    edges, counts = _histogram(_sample_fast(TRUTH, 2_000_000, seed=6))
    fits = fit_mixtures(edges, counts, max_components=4)
    assert [fit.n_components for fit in fits] == [1, 2, 3, 4]
    lls = [fit.log_likelihood for fit in fits]
    assert all(b >= a - 1e-6 * abs(a) for a, b in zip(lls, lls[1:]))
    assert select_components(fits, criterion="bic", tolerance=0.001) == 3
    assert select_components(fits, criterion="bic", tolerance=0) == int(np.argmin([f.bic for f in fits])) + 1


def test_selection_rule_on_hand_made_scores():
    def fake(g, bic):
        return MixtureFit(
            GaussianMixture(np.full(g, 1 / g), np.zeros(g), np.ones(g)), -bic / 2, bic, bic, 1000.0, 1, True
        )

    fits = [fake(1, 5000.0), fake(2, 3030.0), fake(3, 2990.0), fake(4, 2985.0)]
    assert select_components(fits, tolerance=0) == 4
    assert select_components(fits, tolerance=0.01) == 3  # within 2 * 0.01 * 1000 = 20 of the best
    assert select_components(reversed(fits), tolerance=0.01) == 3
    assert select_components(fits, tolerance=1.0) == 2  # 2000 allowed: 5000 is out, 3030 is in
    with pytest.raises(PrismapInputError, match="criterion"):
        select_components(fits, criterion="likelihood")
    with pytest.raises(PrismapInputError, match="empty"):
        select_components([])


def test_em_kernel_matches_a_numpy_reference():
    rng = np.random.default_rng(8)
    points = rng.normal(0, 2, 300)
    counts = rng.integers(1, 10, 300).astype(np.float64)
    start = (np.array([0.5, 0.3, 0.2]), np.array([-1.0, 0.0, 2.0]), np.array([1.0, 2.0, 0.5]))
    for steps in (1, 5):
        w, mu, var, w_f, ll, n_iter, converged = em_weighted(points, counts, *start, 1e-6, 1e-300, steps)
        assert w_f == 0.0
        ref = _em_reference(points, counts, *start, 1e-6, steps)
        assert n_iter == steps and not converged
        np.testing.assert_allclose(w, ref[0], rtol=1e-10)
        np.testing.assert_allclose(mu, ref[1], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(var, ref[2], rtol=1e-10)
        assert ll == pytest.approx(ref[3], rel=1e-12)


def test_variance_floor_holds_when_a_component_sits_on_one_value():
    values = np.array([0.0, 0.0, 0.0, 5.0, 5.2, 4.8])
    fit = fit_mixture(values, n_components=2, min_sigma=0.01)
    assert fit.mixture.sigmas.min() == pytest.approx(0.01)


def test_kmeans_plus_plus_picks_data_points_and_spreads_out():
    points = np.array([0.0, 0.1, 0.2, 10.0, 10.1])
    counts = np.ones(5)
    centres = kmeans_plus_plus(points, counts, 2, np.array([0.0, 0.5]))
    assert centres[0] == 0.0  # u = 0 picks the first point
    assert centres[1] >= 10.0  # D^2 weighting makes the far cluster almost certain


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: fit_mixture(np.array([]), n_components=1), "empty"),
        (lambda: fit_mixture(np.array([1.0, np.nan]), n_components=1), "values.*finite"),
        (lambda: fit_mixture(np.array([1.0, 2.0]), n_components=0), "n_components.*>= 1"),
        (lambda: fit_mixture(np.array([1.0, 1.0, 2.0]), n_components=3), "3 exceeds the 2 distinct"),
        (lambda: fit_mixture(np.array([1.0, 2.0]), weights=[1.0, -1.0], n_components=1), "weights.*>= 0"),
        (lambda: fit_mixture(np.array([1.0, 2.0]), weights=[0.0, 0.0], n_components=1), "empty"),
        (lambda: fit_mixture(np.ones((2, 2)), n_components=1), "values.*1-D"),
        (lambda: fit_histogram([0.0, 1.0, 3.0], [1.0, 1.0], n_components=1), "equal spacing"),
        (lambda: fit_histogram([0.0, 1.0, 2.0], [1.0], n_components=1), r"counts.*shape \(2\)"),
        (lambda: fit_histogram([0.0, 1.0, 2.0], [0.0, 0.0], n_components=1), "empty"),
    ],
)
def test_bad_input_raises_a_clear_error(call, message):
    with pytest.raises(PrismapInputError, match=message):
        call()


def test_histogram_fits_never_go_below_the_bin_resolution():
    edges = np.arange(-2.0, 2.0 + 1e-9, 0.5)
    counts = np.array([0, 0, 0, 50, 0, 0, 40, 0], dtype=float)  # two spikes, one bin each
    fit = fit_histogram(edges, counts, n_components=2, min_sigma=1e-6)
    np.testing.assert_allclose(fit.mixture.sigmas, 0.5 / np.sqrt(12.0))


def test_outlier_weight_recovers_a_known_contamination_and_floors_at_one_pseudo_error():
    core, outlier = GaussianMixture.gaussian(0.2), GaussianMixture.gaussian(10.0, 5.0)
    n = 200_000
    edges, counts = _histogram(_sample_fast(core.with_component(0.02, 5.0, 10.0), n, seed=4))
    assert fit_outlier_weight(core, outlier, edges, counts) == pytest.approx(0.02, rel=0.05)
    edges, counts = _histogram(_sample_fast(core, n, seed=5))
    # no outlier in the data: w ~ prior_count / N (the core's far tail adds a few per cent)
    assert 1.0 / n < fit_outlier_weight(core, outlier, edges, counts) < 1.2 / n
    assert 10.0 / n < fit_outlier_weight(core, outlier, edges, counts, prior_count=10.0) < 12.0 / n
    with pytest.raises(PrismapInputError, match="`prior_count` must be"):
        fit_outlier_weight(core, outlier, edges, counts, prior_count=0.0)
    with pytest.raises(PrismapInputError, match="not all 0"):
        fit_outlier_weight(core, outlier, edges, np.zeros_like(counts))


def test_with_component_is_the_weighted_sum_of_the_two_densities():
    mixture = GaussianMixture([0.7, 0.3], [0.0, 1.0], [0.5, 2.0])
    mixed = mixture.with_component(0.1, 4.0, 8.0)
    x = np.linspace(-30.0, 30.0, 61)
    np.testing.assert_allclose(mixed.pdf(x), 0.9 * mixture.pdf(x) + 0.1 * GaussianMixture.gaussian(8.0, 4.0).pdf(x))
    with pytest.raises(PrismapInputError, match=r"`weight` of the added component must lie in \[0, 1\); got 1.0"):
        mixture.with_component(1.0, 0.0, 1.0)
