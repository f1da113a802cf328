"""The matcher-failure component of the error mixture: its density, sampling, JSON form and its MAP-EM fit."""

import json

import numpy as np
import pytest
from scipy import stats

from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, failure_prior_bound, fit_mixture, n_parameters
from prismap.gmm._kernels import em_weighted

SEARCH = (0.0, 96.0)
TRUTH = GaussianMixture([0.8, 0.2], [0.05, -0.3], [0.3, 1.2], 0.04, SEARCH)


def _errors(mixture, n, seed):
    """Seeded errors of ``mixture`` at true disparities uniform in [5, 80) px (inside the search range)."""
    rng = np.random.default_rng(seed)
    return mixture.sample(n, rng, truth_px=rng.uniform(5.0, 80.0, n))


def test_density_is_the_scaled_gaussians_plus_the_floor():
    e = np.linspace(-40.0, 40.0, 801)
    gaussians = sum(w * stats.norm.pdf(e, m, s) for w, m, s in zip(TRUTH.weights, TRUTH.means, TRUTH.sigmas))
    expected = 0.96 * gaussians + 0.04 / 96.0
    np.testing.assert_allclose(TRUTH.pdf(e), expected, rtol=1e-12)
    np.testing.assert_allclose(TRUTH.logpdf(e), np.log(expected), rtol=1e-12)
    assert TRUTH.failure_density == pytest.approx(0.04 / 96.0)
    assert TRUTH.logpdf(np.array([1e4])) == pytest.approx(np.log(0.04 / 96.0))  # never below the floor


def test_density_integrates_to_one_over_the_errors_of_one_true_disparity():
    # for a true disparity t the returned d^ = t - e lies in [0, 96): errors in (t - 96, t]
    t = 30.0
    e = np.linspace(t - 96.0, t, 400_001)
    assert np.trapezoid(TRUTH.pdf(e), e) == pytest.approx(1.0, abs=2e-4)  # the Gaussians' mass beyond is ~0


def test_samples_put_failures_uniformly_over_the_search_range():
    rng = np.random.default_rng(5)
    truth = rng.uniform(5.0, 80.0, 400_000)
    errors = TRUTH.sample(truth.size, np.random.default_rng(6), truth_px=truth)
    measured = truth - errors
    gross = np.abs(errors) > 10.0
    # failures are 4 %; those within 10 px of the truth (20 / 96 of the range, about) are not gross
    assert gross.mean() == pytest.approx(0.04 * (1 - 20.0 / 96.0), abs=0.002)
    assert measured[gross].min() >= 0.0 and measured[gross].max() < 96.0
    counts, _ = np.histogram(measured[gross & (truth > 40) & (measured < 20)], bins=4, range=(0, 20))
    assert counts.min() > 0.85 * counts.mean()  # flat over the range
    with pytest.raises(PrismapInputError, match="truth_px"):
        TRUTH.sample(10, 0)


def test_plain_mixture_is_unchanged_and_json_round_trips():
    plain = GaussianMixture([0.8, 0.2], [0.05, -0.3], [0.3, 1.2])
    assert plain.failure_weight == 0.0 and plain.search_range_px is None
    assert "failure_weight" not in plain.to_dict()  # a plain mixture writes what it always wrote
    again = GaussianMixture.from_dict(json.loads(json.dumps(TRUTH.to_dict())))
    assert (again.failure_weight, again.search_range_px) == (0.04, SEARCH)
    np.testing.assert_array_equal(again.logpdf(np.linspace(-50, 50, 11)), TRUTH.logpdf(np.linspace(-50, 50, 11)))
    assert TRUTH.widened(0.5).failure_weight == TRUTH.failure_weight
    assert TRUTH.gaussian_part().failure_weight == 0.0


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"failure_weight": 1.0, "search_range_px": SEARCH}, "failure_weight"),
        ({"failure_weight": -0.1, "search_range_px": SEARCH}, "failure_weight"),
        ({"failure_weight": 0.1}, "needs `search_range_px`"),
        ({"failure_weight": 0.1, "search_range_px": (5.0, 5.0)}, "lo < hi"),
        ({"failure_weight": 0.1, "search_range_px": "wide"}, "two numbers"),
    ],
)
def test_bad_failure_parameters_are_named(kwargs, fragment):
    with pytest.raises(PrismapInputError, match=fragment):
        GaussianMixture([1.0], [0.0], [1.0], **kwargs)


def test_em_recovers_a_known_gaussian_plus_uniform_mixture():
    errors = _errors(TRUTH, 400_000, seed=1)
    fit = fit_mixture(errors, n_components=2, bin_width=1 / 32, search_range_px=SEARCH)
    m = fit.mixture
    assert fit.converged
    assert m.failure_weight == pytest.approx(0.04, rel=0.05)
    np.testing.assert_allclose(m.weights, TRUTH.weights, atol=0.01)
    np.testing.assert_allclose(m.means, TRUTH.means, atol=0.02)
    np.testing.assert_allclose(m.sigmas, TRUTH.sigmas, rtol=0.02)
    assert fit.n_parameters == 6 == n_parameters(2, True)
    assert fit.aic == pytest.approx(2 * 6 - 2 * fit.log_likelihood)
    # the uniform explains the gross errors far better than a wide Gaussian does
    plain = fit_mixture(errors, n_components=2, bin_width=1 / 32)
    assert fit.log_likelihood > plain.log_likelihood + 0.1 * errors.size


def test_failure_weight_of_clean_errors_stays_at_the_prior_bound():
    for n in (300, 2000, 20_000):
        clean = np.random.default_rng(n).normal(0.0, 0.3, n)
        fit = fit_mixture(clean, n_components=1, bin_width=1 / 32, search_range_px=SEARCH)
        bound = failure_prior_bound(n)
        assert bound == pytest.approx(1.0 / (n + 1))
        assert bound <= fit.mixture.failure_weight <= 3.0 / n  # at least the prior's, within the rule of three
        # a stronger prior raises the floor in proportion
        strong = fit_mixture(clean, n_components=1, bin_width=1 / 32, search_range_px=SEARCH, failure_prior=3.0)
        assert strong.mixture.failure_weight >= failure_prior_bound(n, 3.0) > 2.9 / (n + 3)


def test_map_em_kernel_matches_a_numpy_reference_step():
    rng = np.random.default_rng(3)
    points = rng.normal(0.0, 1.0, 50) * 3
    counts = rng.integers(1, 5, 50).astype(np.float64)
    w0, mu0, var0 = np.array([0.6, 0.4]), np.array([-1.0, 1.0]), np.array([1.0, 4.0])
    floor, wf0, prior = 1.0 / 64.0, 0.1, 2.0
    w, mu, var, wf, _, n_iter, _ = em_weighted(points, counts, w0, mu0, var0, 1e-6, 1e-300, 1, floor, wf0, prior)
    assert n_iter == 1
    full = np.append(w0 * (1 - wf0), wf0)
    dens = np.stack(
        [
            full[0] * stats.norm.pdf(points, mu0[0], 1.0),
            full[1] * stats.norm.pdf(points, mu0[1], 2.0),
            np.full(points.size, wf0 * floor),
        ]
    )
    resp = dens / dens.sum(axis=0) * counts
    total = counts.sum() + prior
    assert wf == pytest.approx((resp[2].sum() + prior) / total, rel=1e-12)
    gauss = resp[:2].sum(axis=1) / total
    np.testing.assert_allclose(w, gauss / gauss.sum(), rtol=1e-12)
    np.testing.assert_allclose(mu, (resp[:2] * points).sum(axis=1) / resp[:2].sum(axis=1), rtol=1e-12)
