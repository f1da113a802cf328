"""Classic inverse sensor models (ideal, hit/miss, convolution, Andert) and the registry."""

import numpy as np
import pytest
from scipy.special import expit, logit
from scipy.stats import norm as normal

from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import InverseSensorModel, make_sensor_model, model_names

FB = 61.5
COMMON = {"focal_baseline": FB, "voxel_size_m": 0.1, "p0": 0.05}


def _ray(depth, start=0.5, stop=None, step=0.1, ray_norm=1.0):
    """One ray measuring ``depth``, with equal cells ``[start, stop)`` of ``step`` metres."""
    edges = np.arange(start, (stop or 2 * depth) + 1e-9, step)
    n = edges.size - 1
    return [FB / depth], [ray_norm], np.zeros(n, np.int64), edges[:-1], edges[1:]


def test_registry_builds_every_model_by_keyword():
    assert {"ideal", "hitmiss", "convolution", "andert", "prism"} <= set(model_names())
    policies = {}
    for name in ("ideal", "hitmiss", "convolution", "andert"):
        model = make_sensor_model(name, **COMMON)
        assert isinstance(model, InverseSensorModel) and model.name == name
        policies[name] = model.default_policy
    assert policies["hitmiss"] == "occupied-wins" and policies["andert"] == "max"
    prism = make_sensor_model("prism", error_model=GaussianMixture.gaussian(0.5), **COMMON)
    assert prism.p0 == 0.05 and prism.method == "table"
    with pytest.raises(PrismapInputError, match="unknown sensor model 'thrun'"):
        make_sensor_model("thrun", **COMMON)


def test_hitmiss_gives_exactly_octomap_increments():
    model = make_sensor_model("hitmiss", **COMMON)
    d, r, rays, start, end = _ray(3.05)
    post, inc = model.cell_posteriors(d, r, rays, start, end)
    end_cell = (start <= 3.05) & (3.05 < end)
    assert end_cell.sum() == 1
    assert np.all(inc[end_cell] == logit(0.7))
    assert np.all(inc[end <= 3.05] == logit(0.4))
    assert np.all(inc[start > 3.05] == 0.0)
    np.testing.assert_allclose(post, expit(logit(0.05) + inc), rtol=1e-12)
    assert model.influence_depth(d, r)[0] == pytest.approx(3.05)


def test_ideal_model_by_hand():
    model = make_sensor_model("ideal", **COMMON, p_free=0.01, p_occ=0.9)
    d, r, rays, start, end = _ray(3.0, ray_norm=1.25)
    post, inc = model.cell_posteriors(d, r, rays, start, end)
    distance = (0.5 * (start + end) - 3.0) * 1.25  # along the ray, metres
    expected = np.where(np.abs(distance) <= 0.05, 0.9, np.where(distance < 0, 0.01, 0.05))
    np.testing.assert_array_equal(post, expected)
    np.testing.assert_allclose(inc, logit(expected) - logit(0.05), atol=1e-12)
    defaults = make_sensor_model("ideal", **COMMON)
    assert defaults.alpha_m == 0.1
    assert logit(defaults.p_occ) - logit(0.05) == pytest.approx(logit(0.7))
    assert logit(defaults.p_free) - logit(0.05) == pytest.approx(logit(0.4))


def _convolution_reference(model, depth, ray_norm, centre):
    """SENSOR_MODELS.md section 4 with scipy's normal CDF."""
    sigma = ray_norm * depth**2 * model.sigma_px / FB
    gap = (depth - centre) * ray_norm
    below = normal.cdf((gap - model.alpha_m / 2) / sigma)
    inside = normal.cdf((gap + model.alpha_m / 2) / sigma)
    return model.p_free * below + model.p_occ * (inside - below) + model.p0 * (1 - inside)


def test_convolution_matches_closed_form_and_tends_to_ideal():
    d, r, rays, start, end = _ray(4.0, step=0.07, ray_norm=1.1)
    centre = 0.5 * (start + end)
    model = make_sensor_model("convolution", **COMMON, sigma_px=0.8)
    post, inc = model.cell_posteriors(d, r, rays, start, end)
    np.testing.assert_allclose(post, _convolution_reference(model, 4.0, 1.1, centre), rtol=1e-10)
    np.testing.assert_allclose(inc, logit(post) - logit(0.05), rtol=1e-10, atol=1e-14)
    ideal_post, _ = make_sensor_model("ideal", **COMMON).cell_posteriors(d, r, rays, start, end)
    gaps = [
        np.abs(
            make_sensor_model("convolution", **COMMON, sigma_px=s).cell_posteriors(d, r, rays, start, end)[0]
            - ideal_post
        ).max()
        for s in (0.5, 0.05, 0.005, 1e-5)
    ]
    assert all(b < a for a, b in zip(gaps, gaps[1:])) and gaps[-1] < 1e-12, gaps


def test_andert_peak_and_profile():
    sigma_px, eta, depth, ray_norm = 0.5, 0.1, 6.0, 1.2
    model = make_sensor_model("andert", **COMMON, sigma_px=sigma_px, eta=eta)
    d, r, rays, start, end = _ray(depth, step=0.1, ray_norm=ray_norm)
    post, inc = model.cell_posteriors(d, r, rays, start, end)
    sigma_s = ray_norm * depth**2 * sigma_px / FB
    peak = 0.5 + eta / (np.sqrt(2 * np.pi) * sigma_s)
    assert peak < model.p_max
    hit = (start <= depth) & (depth <= end)
    np.testing.assert_allclose(expit(inc[hit]), peak, rtol=1e-12)
    # reference: Andert's formula at clip(s^, a, c)
    z = np.clip(depth, start, end)
    gap = (z - depth) * ray_norm
    base = np.where(gap <= 0, model.p_min, 0.5)
    expected = base + (peak - base) * np.exp(-0.5 * (gap / sigma_s) ** 2)
    np.testing.assert_allclose(inc, logit(expected), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(post, expit(logit(0.05) + inc), rtol=1e-12)
    capped = make_sensor_model("andert", **COMMON, sigma_px=sigma_px, eta=eta)
    post_near, inc_near = capped.cell_posteriors(*_ray(0.8, step=0.01))
    assert expit(inc_near).max() == pytest.approx(capped.p_max)


@pytest.mark.parametrize("name", ["ideal", "hitmiss", "convolution", "andert"])
def test_influence_depth_bounds_later_cells(name):
    model = make_sensor_model(name, **COMMON)
    disparity = FB / np.array([1.5, 7.0, 25.0])
    ray_norm = np.array([1.0, 1.15, 1.3])
    influence = model.influence_depth(disparity, ray_norm)
    rays = np.repeat(np.arange(3), 50)
    start = np.repeat(influence, 50) + np.tile(np.linspace(1e-9, 3, 50), 3)
    _, inc = model.cell_posteriors(disparity, ray_norm, rays, start, start + 0.1)
    assert np.all(np.abs(inc) < 1.01e-3)


@pytest.mark.parametrize("name", ["convolution", "andert"])
def test_extra_noise_widens_sigma_in_quadrature(name):
    model = make_sensor_model(name, **COMMON, sigma_px=0.3)
    wider = model.with_extra_noise(0.4)
    assert wider.sigma_px == pytest.approx(0.5) and model.sigma_px == 0.3
    assert make_sensor_model("ideal", **COMMON).with_extra_noise(0.4).name == "ideal"


@pytest.mark.parametrize(
    ("name", "params", "message"),
    [
        ("hitmiss", {"p_hit": 0.4}, "p_miss < 0.5 < p_hit"),
        ("ideal", {"p_free": 0.2}, "p_free < p0 < p_occ"),
        ("convolution", {"sigma_px": 0.0}, "sigma_px"),
        ("andert", {"p_min": 0.6}, "p_min < 0.5 < p_max"),
        ("andert", {"eta": -1.0}, "eta"),
        ("ideal", {"p0": 0.0}, "p0"),
        ("ideal", {"alpha_m": "wide"}, "alpha_m"),
    ],
)
def test_bad_parameters_are_named(name, params, message):
    with pytest.raises(PrismapInputError, match=message):
        make_sensor_model(name, **{**COMMON, **params})


def test_bad_rays_are_named():
    model = make_sensor_model("ideal", **COMMON)
    with pytest.raises(PrismapInputError, match="depth_end_m"):
        model.cell_posteriors([5.0], [1.0], [0, 0], [1.0, 2.0], [1.1])
    with pytest.raises(PrismapInputError, match="finite"):
        model.cell_posteriors([np.inf], [1.0], [0], [1.0], [1.1])
