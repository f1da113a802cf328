import json

import numpy as np
import pytest
from scipy import integrate, stats

from prismap import PrismapInputError
from prismap.gmm import GaussianMixture

MIX = GaussianMixture([0.7, 0.25, 0.05], [0.1, -0.5, 3.0], [0.4, 1.5, 12.0])


def test_pdf_matches_scipy_sum_of_normals():
    e = np.linspace(-60, 60, 2001)
    expected = sum(w * stats.norm.pdf(e, m, s) for w, m, s in zip(MIX.weights, MIX.means, MIX.sigmas))
    np.testing.assert_allclose(MIX.pdf(e), expected, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(np.exp(MIX.logpdf(e)), expected, rtol=1e-12)


def test_pdf_integrates_to_one_and_cdf_is_its_integral():
    total, _ = integrate.quad(MIX.pdf, -200, 200, points=[0.1, -0.5, 3.0], limit=200)
    assert total == pytest.approx(1.0, abs=1e-9)
    for x in (-5.0, 0.0, 0.3, 7.0):
        value, _ = integrate.quad(MIX.pdf, -200, x, points=[min(x, 0.1)], limit=200)
        assert MIX.cdf(x) == pytest.approx(value, abs=1e-9)
    assert np.exp(MIX.logcdf(-40.0)) == pytest.approx(MIX.cdf(-40.0), rel=1e-9)


def test_sampling_is_seeded_and_matches_moments():
    a = MIX.sample(200_000, 3)
    np.testing.assert_array_equal(a, MIX.sample(200_000, 3))
    assert a.mean() == pytest.approx(MIX.mean(), abs=0.03)
    assert a.std() == pytest.approx(MIX.std(), rel=0.02)


def test_json_round_trip_is_exact():
    again = GaussianMixture.from_dict(json.loads(json.dumps(MIX.to_dict())))
    for name in ("weights", "means", "sigmas"):
        np.testing.assert_array_equal(getattr(again, name), getattr(MIX, name))


def test_widened_adds_variance_in_quadrature():
    wide = MIX.widened(0.3)
    np.testing.assert_allclose(wide.sigmas**2, MIX.sigmas**2 + 0.09)
    np.testing.assert_array_equal(wide.means, MIX.means)


@pytest.mark.parametrize(
    "weights, means, sigmas, fragment",
    [
        ([0.5, 0.6], [0, 0], [1, 1], "sum to 1"),
        ([1.0], [0.0], [0.0], "sigmas must be > 0"),
        ([0.5, 0.5], [0.0], [1.0, 1.0], "equal, non-zero length"),
        ([1.0], [np.nan], [1.0], "finite"),
    ],
)
def test_bad_parameters_are_named(weights, means, sigmas, fragment):
    with pytest.raises(PrismapInputError, match=fragment):
        GaussianMixture(weights, means, sigmas)


def test_from_dict_names_the_source_and_missing_field():
    with pytest.raises(PrismapInputError, match=r"model.json: .*missing field\(s\) \['sigmas'\]"):
        GaussianMixture.from_dict({"weights": [1], "means": [0]}, source="model.json")
