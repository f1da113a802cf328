"""Matcher failures in the sensor models: PRISM's forward density with the uniform floor (discrete, direct,
table), the failure blend of Andert and convolution, and the evidence bound one measurement respects."""

import itertools

import numpy as np
import pytest
from scipy.special import expit, logit

from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import (
    AndertModel,
    ConvolutionModel,
    PrismModel,
    _kernels_failure,
    blend_increments,
    evidence_bound,
    failure_floor,
    log_failure_posterior,
    model_for_mixture,
    prism_discrete_posteriors,
)
from prismap.sensor_models._prism import TABLE_TOLERANCE

FB = 61.5
SEARCH = (0.0, 64.0)
GAUSSIANS = GaussianMixture([0.85, 0.15], [0.05, -0.3], [0.4, 2.5])
FAILING = GAUSSIANS.with_failure(0.01, SEARCH)


def _brute_force(d_hat, edges, mixture, p0):
    """All 2^n maps of independent cells; the first occupied cell produces d^ with the floored likelihood."""
    u = FB / edges
    gauss = (mixture.cdf(u[:-1] - d_hat) - mixture.cdf(u[1:] - d_hat)) / (u[:-1] - u[1:])
    gauss_far = (mixture.cdf(u[-1] - d_hat) - mixture.cdf(-d_hat)) / u[-1]
    lik = (1 - mixture.failure_weight) * gauss + mixture.failure_density
    lik_far = (1 - mixture.failure_weight) * gauss_far + mixture.failure_density
    joint, total = np.zeros(edges.size - 1), 0.0
    for bits in itertools.product((0, 1), repeat=edges.size - 1):
        bits = np.array(bits)
        occupied = np.flatnonzero(bits)
        weight = np.prod(np.where(bits == 1, p0, 1 - p0)) * (lik[occupied[0]] if occupied.size else lik_far)
        total += weight
        joint += weight * bits
    return joint / total


@pytest.mark.parametrize("depth", [2.0, 3.1, 30.0])  # 30 m: d^ = 2 px, far from every cell: mostly failure
def test_discrete_reference_with_failures_equals_brute_force(depth):
    edges = 1.0 + 0.4 * np.arange(11)
    got = prism_discrete_posteriors(FB / depth, edges, FAILING, focal_baseline=FB, p0=0.1)
    np.testing.assert_allclose(got, _brute_force(FB / depth, edges, FAILING, 0.1), rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", ["direct", "table"])
def test_continuous_prism_with_failures_converges_to_the_discrete_reference(method):
    d_hat, rate, errors = FB / 3.0, 0.5, []
    for length in (0.1, 0.025, 0.0125):
        edges = np.arange(1.0, 8.0 + 1e-9, length)
        p0 = -np.expm1(-rate * length)
        model = PrismModel(
            error_model=FAILING,
            focal_baseline=FB,
            voxel_size_m=length,
            p0=p0,
            near_m=edges[0],
            far_depth_m=edges[-1],
            method=method,
        )
        n = edges.size - 1
        posterior, _ = model.cell_posteriors([d_hat], [1.0], np.zeros(n, np.int64), edges[:-1], edges[1:])
        errors.append(
            np.abs(posterior - prism_discrete_posteriors(d_hat, edges, FAILING, focal_baseline=FB, p0=p0)).max()
        )
    assert errors[-1] < (2e-4 if method == "direct" else TABLE_TOLERANCE["posterior"]), errors
    assert errors[1] < 0.1 * errors[0]


def test_prism_posterior_is_the_blend_of_the_gaussian_posterior_and_the_prior():
    # P = rho P_G + (1 - rho) p_c, rho = (1 - w_f) Z_G / ((1 - w_f) Z_G + w_f / W): from the two discrete references
    edges = np.linspace(1.0, 9.0, 41)
    p0, d_hat = 0.05, FB / 4.0
    plain = prism_discrete_posteriors(d_hat, edges, GAUSSIANS, focal_baseline=FB, p0=p0)
    failing = prism_discrete_posteriors(d_hat, edges, FAILING, focal_baseline=FB, p0=p0)
    rho = (failing - p0) / (plain - p0)
    assert np.ptp(rho[np.abs(plain - p0) > 1e-3]) < 1e-9  # one rho for the whole ray
    assert 0.5 < rho[0] < 1.0


def test_blend_increments_matches_the_probability_form():
    rng = np.random.default_rng(0)
    inc, prior = rng.normal(0, 8, 200), rng.normal(-3, 2, 200)
    rho = rng.uniform(0.5, 1.0, 200)
    posterior, blended = blend_increments(inc, prior, np.log1p(-rho), np.log(rho))
    expected = rho * expit(prior + inc) + (1 - rho) * expit(prior)
    np.testing.assert_allclose(posterior, expected, rtol=1e-10)
    np.testing.assert_allclose(blended, logit(expected) - prior, rtol=1e-9, atol=1e-9)
    # exact where the failure-free increment is far beyond float64's probabilities
    _, far = blend_increments(
        np.array([-800.0, 800.0]), np.array([-3.0, -3.0]), np.log([1e-4, 1e-4]), np.log1p([-1e-4, -1e-4])
    )
    np.testing.assert_allclose(
        far,
        [-np.log1p((1 - 1e-4) / (1e-4 * (1 - expit(-3.0)))), np.log1p((1 - 1e-4) / (1e-4 * expit(-3.0)))],
        rtol=1e-9,
    )


def test_the_ray_cell_blend_takes_each_cells_prior_from_its_clipped_length():
    rng = np.random.default_rng(1)
    n_rays, n_cells = 7, 5000
    rays = np.sort(rng.integers(0, n_rays, n_cells))
    start = rng.uniform(-1.0, 30.0, n_cells)
    end = start + rng.choice([0.0, 1e-7, 1e-4, 0.2, 50.0], n_cells)  # empty, series-sized, ordinary and clipped
    rate = rng.uniform(0.01, 2.0, n_rays)[rays]
    inc = rng.normal(0, 1, n_cells) * 10.0 ** rng.uniform(-3, 3, n_cells)
    log_fail = np.log(rng.uniform(1e-9, 0.5, n_rays))
    log_ok = np.log1p(-np.exp(log_fail))
    near, far = 0.5, 40.0
    posterior, blended = _kernels_failure.blend_ray_cells(inc, rays, start, end, rate, near, far, log_fail, log_ok)
    length = np.clip(end, near, far) - np.clip(start, near, far)
    with np.errstate(divide="ignore"):
        prior = np.log(np.expm1(rate * length))  # -inf for empty cells: the blend keeps P = 0
    expected_posterior, expected = blend_increments(inc, prior, log_fail[rays], log_ok[rays])
    np.testing.assert_allclose(blended, expected, rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(posterior, expected_posterior, rtol=1e-8, atol=1e-300)
    assert np.all(posterior[length <= 0] == 0.0)
    rho = np.exp(log_ok[rays])
    with np.errstate(over="ignore"):
        by_probability = rho * expit(prior + inc) + (1 - rho) * expit(prior)
    ordinary = (length > 0) & (np.abs(inc) < 30)
    np.testing.assert_allclose(posterior[ordinary], by_probability[ordinary], rtol=1e-9)


def test_table_cells_blend_as_the_ray_cell_blend_does():
    """PRISM's tables blend each cell inside the look-up, from the likelihood ratio; the reference is the separate
    pass over the unblended increments (``blend_ray_cells``) with the rays' failure posteriors from their tables'
    ``Z``. Cells tile 0-60 m from the camera (before ``near_m`` and past the influence depth: skipped), stretched
    by each ray's voxel overhang, on rays from near to far (cells far in front of their measurement: the look-up's
    log-space cases)."""
    model = PrismModel(
        error_model=FAILING, focal_baseline=FB, voxel_size_m=0.2, p0=0.05, near_m=0.5, overhang_fraction=0.25
    )
    disparity = FB / np.array([1.2, 3.0, 11.0, 40.0, 150.0]) + np.array([0.0, 1 / 16, 0.3, -0.1, 0.02])
    norm = np.array([1.0, 1.02, 1.1, 1.3, 1.04])
    overhang = np.array([0.0, 0.1, 0.3, 0.05, 1.0])
    edges = np.arange(0.0, 60.0 + 1e-9, 0.2)
    rays = np.repeat(np.arange(disparity.size), edges.size - 1)
    start, end = np.tile(edges[:-1], disparity.size), np.tile(edges[1:], disparity.size)
    posterior, increment = model.cell_posteriors(disparity, norm, rays, start, end, voxel_overhang_m=overhang)
    stretch = model.overhang_fraction * overhang / norm
    lam = model.rate_per_m * norm
    tables = model._tables_for(disparity, norm)
    _, unblended = model._table_cells(lam, rays, start, end, stretch, tables, (np.empty(0), np.empty(0)))
    log_fail, log_ok = model._log_failure(model._ray_log_z(tables))
    expected_posterior, expected = _kernels_failure.blend_ray_cells(
        unblended, rays, start, end + stretch[rays], lam[rays], model.near_m, model.far_depth_m, log_fail, log_ok
    )
    assert np.any(unblended < -600) and np.any(unblended == 0) and np.any(np.abs(unblended) > 1)
    np.testing.assert_allclose(increment, expected, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(posterior, expected_posterior, rtol=1e-12, atol=1e-300)


def test_failure_posterior_never_drops_below_the_floor():
    eps = failure_floor(FAILING)
    expected = (0.01 / 64) / (0.99 * FAILING.peak_density() + 0.01 / 64)
    assert eps == pytest.approx(expected, rel=1e-12)
    log_fail, log_ok = log_failure_posterior(FAILING, np.array([-50.0, 0.0, 10.0]))  # the last beyond g_max
    assert log_fail[0] == pytest.approx(0.0, abs=1e-12)  # a measurement no Gaussian explains is a failure
    assert log_fail[2] == pytest.approx(np.log(eps))
    np.testing.assert_allclose(np.exp(log_fail) + np.exp(log_ok), 1.0)
    assert failure_floor(GAUSSIANS) == 0.0
    assert evidence_bound(GAUSSIANS, 0.1) == (-np.inf, np.inf)
    with pytest.raises(PrismapInputError, match="cell_prior"):
        evidence_bound(FAILING, 1.0)


@pytest.mark.parametrize("method", ["direct", "table"])
def test_no_measurement_moves_a_prism_cell_beyond_the_bound(method):
    rng = np.random.default_rng(4)
    model = PrismModel(
        error_model=FAILING, focal_baseline=FB, voxel_size_m=0.1, p0=0.05, near_m=0.5, far_depth_m=60.0, method=method
    )
    plain = PrismModel(
        error_model=GAUSSIANS, focal_baseline=FB, voxel_size_m=0.1, p0=0.05, near_m=0.5, far_depth_m=60.0, method=method
    )
    disparity = np.round(rng.uniform(1.0, 63.0, 40) * 16) / 16  # gross failures anywhere in the search range
    norm = rng.uniform(1.0, 1.3, disparity.size)
    edges = np.arange(0.5, 20.0, 0.1)
    rays = np.repeat(np.arange(disparity.size), edges.size - 1)
    start, end = np.tile(edges[:-1], disparity.size), np.tile(edges[1:], disparity.size)
    _, inc = model.cell_posteriors(disparity, norm, rays, start, end)
    _, inc_plain = plain.cell_posteriors(disparity, norm, rays, start, end)
    p_c = -np.expm1(-model.rate_per_m * norm[rays] * (end - start))
    low, high = evidence_bound(FAILING, p_c)
    assert np.all(inc >= low - 1e-9) and np.all(inc <= high + 1e-9)
    assert inc_plain.min() < 2 * low.min()  # without the floor these rays claim far more
    assert inc.min() < 0.5 * low.min()  # and the bound is not vacuous: failures reach a good part of it


def test_andert_and_convolution_blend_with_their_no_information_value():
    eps = failure_floor(FAILING)
    rays, start, end = np.zeros(60, np.int64), np.linspace(0.5, 6.0, 60), np.linspace(0.6, 6.1, 60)
    for cls, neutral in ((ConvolutionModel, 0.05), (AndertModel, 0.5)):
        base = cls(focal_baseline=FB, p0=0.05, sigma_px=0.4)
        model = cls(focal_baseline=FB, p0=0.05, sigma_px=0.4, failure_floor=eps)
        p_base, inc_base = base.cell_posteriors([FB / 3.0], [1.0], rays, start, end)
        p_fail, inc_fail = model.cell_posteriors([FB / 3.0], [1.0], rays, start, end)
        model_p = expit(logit(neutral) + inc_base)  # the model's own P against its neutral value
        np.testing.assert_allclose(expit(logit(neutral) + inc_fail), (1 - eps) * model_p + eps * neutral, rtol=1e-10)
        np.testing.assert_allclose(p_fail, expit(logit(0.05) + inc_fail), rtol=1e-12)
        assert np.all(np.abs(inc_fail) <= np.abs(inc_base) + 1e-12)
        with pytest.raises(PrismapInputError, match="failure_floor"):
            cls(focal_baseline=FB, p0=0.05, failure_floor=1.0)
    built = model_for_mixture("andert", FAILING, focal_baseline=FB, doffs_px=0.0, voxel_size_m=0.1, p0=0.05)
    assert built.failure_floor == pytest.approx(eps) and built.sigma_px == pytest.approx(0.4)
    plain = model_for_mixture("convolution", GAUSSIANS, focal_baseline=FB, doffs_px=0.0, voxel_size_m=0.1, p0=0.05)
    assert plain.failure_floor == 0.0


@pytest.mark.parametrize("gross", [True, False])
def test_one_frame_moves_no_voxel_beyond_the_bound_through_the_map_update(gross):
    """A frame of gross failures (disparities uniform over the search range) and a frame of the true scene with
    seeded mixture errors, integrated projectively with PRISM: every voxel's log-odds change stays within
    ``evidence_bound`` of the mixture, at the voxel stretch priors projective integration can give."""
    from prismap.camera import integrate_disparity
    from prismap.grid import OccupancyMap
    from support import planes_frame

    camera, pose, depth = planes_frame(width=64, height=48)
    rng = np.random.default_rng(11 if gross else 12)
    truth = camera.focal_baseline / depth
    search = (0.0, 48.0)
    mixture = GaussianMixture([0.9, 0.1], [0.0, -0.2], [0.3, 1.5], 0.01, search)
    if gross:
        disparity = rng.uniform(*search, truth.shape)
    else:
        disparity = truth - mixture.sample(truth.size, rng, truth_px=truth.ravel()).reshape(truth.shape)
    disparity = np.clip(np.round(disparity * 16) / 16, 0.25, None)
    p0, voxel = 0.05, 0.2
    changes = []
    for error_model in (mixture, mixture.gaussian_part()):
        model = PrismModel(
            error_model=error_model,
            focal_baseline=camera.focal_baseline,
            voxel_size_m=voxel,
            p0=p0,
            near_m=1.0,
            far_depth_m=40.0,
            overhang_fraction=0.0,
        )
        grid = OccupancyMap(voxel, p0=p0)
        integrate_disparity(grid, disparity, camera, pose, model, mode="projective", max_range_m=30.0)
        changes.append(grid.known_voxels()[1] - logit(p0))
    change, plain = changes
    norm_max = float(np.linalg.norm(camera.pixel_rays(), axis=-1).max())
    low = evidence_bound(mixture, 1 - (1 - p0) ** (np.sqrt(3.0) * norm_max))[0]  # the longest stretch
    high = evidence_bound(mixture, p0)[1]  # a voxel's depth along a ray is at least the voxel's
    quantum = 2.0**-19
    assert change.size > 300
    assert change.min() >= low - quantum and change.max() <= high + quantum
    assert change.min() < 0.5 * low  # not vacuous: a frame reaches a good part of it
    assert plain.min() < 2 * low  # the Gaussians alone let the same frame claim far more


_EXACT = 54 * np.log(2.0)  # R <= 2^-54 fail q leaves the blend that of R = 0
_BLEND_EXACT = _EXACT + np.log(2.0)  # and floor_depth's bound has a factor 2
STREET_FB = 194.4  # the half-size street rig's 360 px times 0.54 m


def _street_rays(first_edge):
    """Three street rays (measured at 8, 20 and 45 m, three ray norms) and cells of 0.2 m tiling each from
    ``first_edge`` to 60 m: ``(disparity, norm, rays, start, end)``."""
    disparity = np.round(STREET_FB / np.array([8.0, 20.0, 45.0]) * 16) / 16
    edges = np.arange(first_edge, 60.0 + 1e-9, 0.2)
    rays = np.repeat(np.arange(disparity.size), edges.size - 1)
    start, end = np.tile(edges[:-1], disparity.size), np.tile(edges[1:], disparity.size)
    return disparity, np.array([1.0, 1.1, 1.3]), rays, start, end


@pytest.mark.parametrize(
    "mixture",
    [
        GAUSSIANS,
        GaussianMixture([0.9, 0.1], [0.1, -0.5], [0.3, 10.0]),  # a wide outlier component, as real matchers have
        GaussianMixture([0.5, 0.3, 0.2], [0.0, 42.0, 82.0], [0.4, 0.7, 0.4]),  # components far in front
    ],
)
def test_floor_depth_bounds_the_likelihood_before_it(mixture):
    """``floor_depth`` by brute force: on a dense grid of depths from ``near_m`` up to it, the largest likelihood
    ``g`` so far over ``Z`` stays below ``e^log_floor`` by what the blend's exactness needs (2^-54, and the bound's
    factor 2), and at the depth itself one component reaches its share of ``FLOOR_EFOLDS`` exactly (the bound
    is as near as a component-wise one gets)."""
    mix = PrismModel(error_model=mixture, focal_baseline=FB, voxel_size_m=0.2, p0=0.05, near_m=0.5)._mixture()
    log_wn, means, sigmas = mix
    z0 = 0.5
    floors = 0
    for shift, log_z, log_floor in itertools.product([0.7, 3.1, 20.0], [-9.0, -2.0, 0.5], [np.log(0.4), -20.0]):
        depth = _kernels_failure.floor_depth(shift, log_z, log_floor, FB, z0, mix)
        assert depth >= z0
        if depth == z0:  # no cell at the floor (cells end after near_m)
            continue
        floors += 1
        z = np.linspace(z0, depth, 20_001)[1:] if np.isfinite(depth) else np.geomspace(z0, 1e6, 20_001)
        t = (FB / z[:, None] - shift - means) / sigmas
        log_g = np.logaddexp.reduce(log_wn - 0.5 * t * t, axis=1)
        assert np.max(log_g) - log_z <= log_floor - _BLEND_EXACT, (shift, log_z, log_floor)
        if z0 < depth < np.inf:
            share = log_z + log_floor - _kernels_failure.FLOOR_EFOLDS - np.log(means.size)
            assert np.max(log_wn - 0.5 * t[-1] ** 2) == pytest.approx(share, abs=1e-9)
    assert floors >= 12
    assert _kernels_failure.floor_depth(3.1, -2.0, -np.inf, FB, z0, mix) == z0  # no failures, no floor
    assert _kernels_failure.floor_depth(3.1, np.nan, -1.0, FB, z0, mix) == z0  # a Z that is not a number: none
    assert _kernels_failure.floor_depth(3.1, -2.0, np.nan, FB, z0, mix) == z0


def test_cells_before_the_floor_depth_skip_the_look_up_and_blend_as_a_zero_ratio():
    """Cells of long street rays before their failure floor depth are not looked up (``side`` flag ``_FLOOR``); each one's
    failure-free ratio from the tables is below what the blend's exactness needs, and its blended increment is
    ``log(fail q / (ok + fail q))``, that of a ratio of 0. The bound finds nearly all the cells the tables' own ratios
    put there (with this mixture's 2.5 px component, a sixth of the rays' cells)."""
    from prismap.sensor_models import _kernels_lookup
    from prismap.sensor_models._kernel_args import Cells
    from prismap.sensor_models._prism import _QUAD_STEP

    model = PrismModel(error_model=FAILING, focal_baseline=STREET_FB, voxel_size_m=0.2, p0=0.05, near_m=0.5)
    disparity, norm, rays, start, end = _street_rays(0.0)
    lam, stretch = model.rate_per_m * norm, np.zeros(disparity.size)
    tables = model._tables_for(disparity, norm)
    log_fail, log_ok = model._log_failure(model._ray_log_z(tables))
    n = start.size
    l_a, l_c, lam_len, side = np.empty(n), np.empty(n), np.empty(n), np.empty(n, dtype=np.int8)
    _kernels_lookup.prism_table_lookup(
        lam, stretch, tables, Cells(rays, start, end), 0, n, _QUAD_STEP, model._geometry(), model._mixture(),
        log_fail, l_a, l_c, side, lam_len,
    )  # fmt: skip
    floor = side == _kernels_lookup._FLOOR
    _, unblended = model._table_cells(lam, rays, start, end, stretch, tables, (np.empty(0), np.empty(0)))
    _, increment = model.cell_posteriors(disparity, norm, rays, start, end)
    q, fail, ok = np.exp(-lam_len), np.exp(log_fail[rays]), np.exp(log_ok[rays])
    exact = (side != _kernels_lookup._SKIP) & (unblended <= np.log(q * fail) - _EXACT)
    assert np.all(exact[floor])  # every floor cell's ratio is small enough
    assert floor.sum() >= 0.9 * exact.sum()  # and the bound finds nearly all such cells
    np.testing.assert_allclose(increment[floor], np.log(fail * q / (ok + fail * q))[floor], rtol=1e-14)
    for ray_floor, ray_live in zip(
        floor.reshape(disparity.size, -1), (side != _kernels_lookup._SKIP).reshape(disparity.size, -1)
    ):
        run = ray_floor[ray_live]  # the ray's first cells after near_m, then none
        assert run[0] and np.all(np.diff(run.astype(int)) <= 0)


def test_with_pass_through_the_floor_blends_the_pass_through_chance():
    """With a pass-through chance ``m`` the thinned ratio ``m + (1 - m) R`` of a cell at the floor is ``m``: the floor
    depth comes from ``log m`` instead of the failure posterior, the tables' thinned ratio there is ``m`` to float64
    precision, those cells' blended increments are the blend of ``m``, and every cell agrees with the direct method
    within the tables' tolerance."""
    m = 0.02
    model = PrismModel(
        error_model=FAILING, focal_baseline=STREET_FB, voxel_size_m=0.2, p0=0.05, near_m=0.5, pass_through=m
    )
    disparity, norm, rays, start, end = _street_rays(0.5)
    lam = model.rate_per_m * norm
    tables = model._tables_for(disparity, norm)
    log_fail, log_ok = model._log_failure(model._ray_log_z(tables))
    depth = [
        _kernels_failure.floor_depth(d, lz, np.log(m), STREET_FB, model.near_m, model._mixture())
        for d, lz in zip(disparity, model._ray_log_z(tables))
    ]
    floor = end <= np.array(depth)[rays]
    assert np.all(floor.reshape(disparity.size, -1)[:, 0]) and floor.sum() > 0.05 * floor.size
    _, increment = model.cell_posteriors(disparity, norm, rays, start, end)
    _, unblended = model._table_cells(lam, rays, start, end, np.zeros(3), tables, (np.empty(0), np.empty(0)))
    assert np.all(np.exp(unblended[floor]) <= m * (1 + 2.0**-52))  # thinned to m, to float64's precision
    q = np.exp(-lam[rays] * (end - start))
    fail, ok = np.exp(log_fail[rays]), np.exp(log_ok[rays])
    a = q + (1 - q) * m
    np.testing.assert_allclose(increment[floor], np.log((ok * m + fail * a) / (ok + fail * a))[floor], rtol=1e-14)
    _, direct = model.cell_posteriors(disparity, norm, rays, start, end, method="direct")
    assert np.all(np.abs(increment - direct) <= TABLE_TOLERANCE["abs"] + TABLE_TOLERANCE["rel"] * np.abs(direct))


OUTLIERS = GaussianMixture([0.9, 0.1], [0.1, -0.5], [0.3, 10.0]).with_failure(0.01, SEARCH)
"""A wide outlier component, as real matchers have, and failures."""


@pytest.mark.parametrize("mixture", [FAILING, OUTLIERS])
def test_evidence_lower_bound_holds_over_the_rates_of_a_table_and_is_near(mixture):
    """``log_evidence_lower_bound`` of a rate range against the quadrature's ``log Z`` (``prism_log_evidence``) at
    both ends and inside: never above it, and within 2.5 nats (a bound that loose moves the table's start by a
    fraction of a sigma)."""
    from prismap.sensor_models import _kernels_direct
    from prismap.sensor_models._prism import _QUAD_STEP

    model = PrismModel(error_model=mixture, focal_baseline=STREET_FB, voxel_size_m=0.2, p0=0.05, near_m=0.5)
    geometry, mix = model._geometry(), model._mixture()
    gaps = []
    for depth, norm in itertools.product([0.8, 3.0, 12.0, 45.0, 75.0, 400.0], [1.0, 1.3]):
        disparity = STREET_FB / depth
        lam = model.rate_per_m * norm
        log_far = float(model._log_far(np.array([disparity]))[0])
        bound = _kernels_failure.log_evidence_lower_bound(disparity, lam * 0.95, lam * 1.05, log_far, geometry, mix)
        rates = lam * np.array([0.95, 0.98, 1.0, 1.02, 1.05])
        log_z = _kernels_direct.prism_log_evidence(
            np.full(rates.size, disparity), rates, np.full(rates.size, log_far), _QUAD_STEP, geometry, mix
        )
        assert np.all(bound <= log_z), (depth, norm)
        gaps.append(log_z.min() - bound)
    assert max(gaps) < 2.5, gaps


def test_tables_start_at_the_least_failure_floor_and_keep_every_cell_after_it():
    """With matcher failures a table starts before its failure floor (``table_start``) instead of at near_m, far
    enough that the intervals a look-up integrates on the spot end before the floor: every cell ending before
    the start blends, by the direct method, to the increment of a likelihood ratio of 0 with the ray's own
    failure posterior; cells across it and after it agree with the direct method within the tables'
    tolerance; the tables hold fewer rows than those of the same Gaussians without failures, which start at
    near_m (here with a short coarse front before the floor: 69 %)."""
    from prismap.sensor_models._kernels_pack import META_COLUMNS
    from prismap.sensor_models._kernels_table import N_SEGMENTS

    column = META_COLUMNS.index
    model = PrismModel(error_model=FAILING, focal_baseline=STREET_FB, voxel_size_m=0.2, p0=0.05, near_m=0.5)
    disparity, norm, rays, start, end = _street_rays(0.5)
    tables = model._tables_for(disparity, norm)
    z_start = tables.meta[tables.table, column("z_start")]
    assert np.all(z_start > 2 * model.near_m), z_start
    _, direct = model.cell_posteriors(disparity, norm, rays, start, end, method="direct")
    log_fail, log_ok = log_failure_posterior(FAILING, _direct_log_z(model, disparity, norm))
    before = end <= z_start[rays]
    assert before.sum() > 0.05 * before.size
    q, fail, ok = np.exp(-model.rate_per_m * norm[rays] * (end - start)), np.exp(log_fail[rays]), np.exp(log_ok[rays])
    np.testing.assert_allclose(direct[before], np.log(fail * q / (ok + fail * q))[before], rtol=1e-13)
    rng = np.random.default_rng(11)  # cells across each ray's start: from before it to after it
    across_start = np.concatenate([z_start * f for f in rng.uniform(0.3, 1.0, (8, 1))])
    across_end = np.concatenate([z_start * f for f in rng.uniform(1.0, 2.5, (8, 1))])
    across_rays = np.tile(np.arange(disparity.size), 8)
    for cells in [(rays, start, end), (across_rays, across_start, across_end)]:
        _, table = model.cell_posteriors(disparity, norm, *cells)
        _, exact = model.cell_posteriors(disparity, norm, *cells, method="direct")
        assert np.all(np.abs(table - exact) <= TABLE_TOLERANCE["abs"] + TABLE_TOLERANCE["rel"] * np.abs(exact))
    for row in tables.meta:  # the intervals a look-up integrates on the spot end before the floor
        floor = _kernels_failure.table_start(
            row[column("shift")], row[column("lam")], row[column("log_far")], model._geometry(), model._table_spec,
            model._mixture(),
        )  # fmt: skip
        segment = next(k for k in range(N_SEGMENTS) if row[column(f"row_{k + 1}")] > 0)
        n_first = 1 if row[column("row_1")] > 0 else 2
        x_first = row[column(f"x_{segment}")] + n_first * row[column(f"h_{segment}")]
        assert x_first <= row[column("lam")] * floor - model._ku() / floor + 1e-9
        assert row[column("z_start")] < floor
    plain = PrismModel(error_model=GAUSSIANS, focal_baseline=STREET_FB, voxel_size_m=0.2, p0=0.05, near_m=0.5)
    plain_tables = plain._tables_for(disparity, norm)
    assert np.all(plain_tables.meta[:, column("z_start")] == plain.near_m)
    assert tables.meta[:, column("stored")].sum() < 0.8 * plain_tables.meta[:, column("stored")].sum()


def _direct_log_z(model, disparity, norm):
    """Each ray's ``log Z`` by the direct method's quadrature."""
    from prismap.sensor_models import _kernels_direct
    from prismap.sensor_models._prism import _QUAD_STEP

    return _kernels_direct.prism_log_evidence(
        disparity + model.doffs_px, model.rate_per_m * norm, model._log_far(disparity), _QUAD_STEP,
        model._geometry(), model._mixture(),
    )  # fmt: skip


OFTEN_FAILING = GaussianMixture([0.9, 0.1], [0.1, -0.5], [0.3, 3.0]).with_failure(0.1, SEARCH)


@pytest.mark.parametrize(("pass_through", "solid_depth_m"), [(0.0, 0.0), (0.05, 0.0), (0.0, 1.1)])
def test_a_silent_ray_moves_no_cell_by_epsilon_and_has_no_influence(pass_through, solid_depth_m):
    """A ray measured far along a street (a few pixels, under a mixture that fails often) is likely a failure there:
    its failure posterior leaves every cell near its prior (with a pass-through chance, and with a solid depth that
    lengthens every cell). ``influence_depth`` gives such a silent ray
    0 (``_kernels_failure.silent_rays``), and the grid casts none of its cells. By brute force with
    ``method="direct"``, over cells of every length up to a voxel's diagonal at every position from ``near_m`` to
    ``far_depth_m`` (each stretched by its ray's overhang share), no silent ray moves a cell by ``influence_epsilon``;
    the rule finds most rays that move none by half of it, and leaves the others their influence depth."""
    fb = 2 * STREET_FB  # the full-size street rig
    model = PrismModel(
        error_model=OFTEN_FAILING, focal_baseline=fb, voxel_size_m=0.2, p0=0.05, near_m=0.5, far_depth_m=150.0,
        pass_through=pass_through, solid_depth_m=solid_depth_m,
    )  # fmt: skip
    eps = model.influence_epsilon
    disparity = fb / np.geomspace(20.0, 140.0, 12)
    norm = np.linspace(1.0, 1.3, disparity.size)
    overhang = np.linspace(1.6, 0.0, disparity.size)  # metres along the ray: up to 8 voxels
    depth = model.influence_depth(disparity, norm, voxel_overhang_m=overhang)
    silent = depth == 0
    largest = np.zeros(disparity.size)
    for r in range(disparity.size):
        longest = np.sqrt(3.0) * 0.2 / norm[r]
        for length in (longest, 0.02):
            for offset in (0.0, 0.5):
                edges = np.arange(model.near_m + offset * length, model.far_depth_m, length)
                cells = np.zeros(edges.size - 1, dtype=np.int64)
                _, increment = model.cell_posteriors(
                    disparity[r : r + 1], norm[r : r + 1], cells, edges[:-1], edges[1:], method="direct",
                    voxel_overhang_m=overhang[r : r + 1],
                )  # fmt: skip
                largest[r] = max(largest[r], np.abs(increment).max())
    assert 0 < silent.sum() < disparity.size
    assert np.all(largest[silent] < eps)
    assert silent.sum() >= 0.75 * np.sum(largest < eps / 2)
    assert np.all(depth[~silent] > model.near_m)
    without_overhang = model.influence_depth(disparity, norm)
    assert np.all(without_overhang[silent] == 0)  # a shorter longest cell: silent all the same
    assert np.all(without_overhang[~silent] == depth[~silent])


@pytest.mark.parametrize("mode", ["ray", "projective"])
def test_the_map_casts_no_cell_of_a_silent_ray(mode):
    """A frame's silent rays (``influence_depth`` 0) reach no voxel in either mode: the rays of a far wall leave the
    map as it was, and the same wall nearer, its rays not silent, does not."""
    from prismap.camera import StereoCamera, integrate_disparity
    from prismap.grid import OccupancyMap

    camera = StereoCamera(720.0, 31.5, 23.5, 0.54, width=64, height=48)
    model = PrismModel(
        error_model=OFTEN_FAILING, focal_baseline=camera.focal_baseline, voxel_size_m=0.2, p0=0.05, near_m=0.5,
        far_depth_m=150.0,
    )  # fmt: skip
    known = {}
    for wall_m in (130.0, 25.0):
        disparity = np.full((camera.height, camera.width), camera.focal_baseline / wall_m)
        silent = model.influence_depth(disparity.reshape(-1)[:1], np.ones(1)) == 0
        grid = OccupancyMap(0.2, p0=0.05)
        integrate_disparity(grid, disparity, camera, np.eye(4), model, mode=mode, max_range_m=140.0)
        known[wall_m] = (bool(silent[0]), len(grid.known_voxels()[0]))
    assert known == {130.0: (True, 0), 25.0: (False, known[25.0][1])} and known[25.0][1] > 1000


def test_a_blended_increment_is_within_rho_of_the_failure_free_ratio():
    """The influence levels' premise (docs/SENSOR_MODELS.md, "The influence depth of a blended ray"): blended by
    its success posterior ``rho``, a cell whose failure-free ratio is ``R`` moves by at most
    ``log(1 + rho max(R - 1, 1/R - 1))``, and the bound is reached to first order near ``R = 1``."""
    rng = np.random.default_rng(21)
    n = 20_000
    increment = rng.uniform(-3.0, 3.0, n)
    prior = logit(rng.uniform(1e-4, 0.6, n))
    rho = np.exp(rng.uniform(np.log(1e-4), 0.0, n))
    _, blended = blend_increments(increment, prior, np.log1p(-rho), np.log(rho))
    ratio = np.exp(increment)
    bound = np.log1p(rho * np.maximum(ratio - 1.0, 1.0 / ratio - 1.0))
    assert np.all(np.abs(blended) <= bound * (1 + 1e-9) + 1e-15)
    small = np.abs(increment) < 1e-3
    assert np.abs(blended[small]) == pytest.approx(rho[small] * np.abs(increment[small]), rel=2e-3)


@pytest.mark.parametrize(
    ("fb", "measured_m"),
    [(2 * STREET_FB, np.geomspace(4.0, 45.0, 16)), (STREET_FB, STREET_FB / np.linspace(1.5, 4.0, 8))],
    ids=["full-size rig", "half-size rig, distant measurements"],
)
def test_a_blended_rays_influence_depth_bounds_every_later_cell(fb, measured_m):
    """A ray that fails often stops where its success posterior ``rho`` lets it
    (``_prism_reach.influence_depths``): before the failure-free influence depth once ``rho <= 1/4``, and in front of
    a distant measurement, where the bound for cells of at most a voxel's diagonal (plus the ray's overhang share)
    takes the prior behind each cell rather than at it. By brute force with ``method="direct"``, no cell beyond it (a
    voxel's diagonal long or a sliver, stretched by the overhang share) moves by ``influence_epsilon``."""
    from prismap.sensor_models._kernels_pack import _Z_INFL

    model = PrismModel(
        error_model=OFTEN_FAILING, focal_baseline=fb, voxel_size_m=0.2, p0=0.05, near_m=0.5, far_depth_m=150.0
    )
    disparity = fb / measured_m
    norm = np.linspace(1.0, 1.3, disparity.size)
    overhang = np.linspace(0.0, 0.8, disparity.size)
    depth = model.influence_depth(disparity, norm, voxel_overhang_m=overhang)
    tables, _, (_, log_ok), _ = model._ray_terms(disparity, norm)
    failure_free = tables[2][tables[0], _Z_INFL]
    rho = np.exp(log_ok)
    likely_failed = rho <= 0.25
    assert likely_failed.sum() >= 3 and np.all(depth > 0)  # no ray silent here
    assert np.all(depth <= failure_free) and np.all(depth[likely_failed] < failure_free[likely_failed])
    if measured_m.max() > 100.0:
        assert np.sum(depth < 0.6 * measured_m) >= 3  # cut well in front of the measurement
    rng = np.random.default_rng(22)
    for r in range(disparity.size):
        start = depth[r] + rng.uniform(0.0, 30.0, 200)
        length = np.where(rng.random(200) < 0.5, np.sqrt(3.0) * 0.2 / norm[r], rng.uniform(1e-4, 0.02, 200))
        _, increment = model.cell_posteriors(
            disparity[r : r + 1], norm[r : r + 1], np.zeros(200, dtype=np.int64), start, start + length,
            method="direct", voxel_overhang_m=overhang[r : r + 1],
        )  # fmt: skip
        assert np.abs(increment).max() < model.influence_epsilon, r
