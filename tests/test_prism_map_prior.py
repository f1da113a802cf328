"""PRISM with the map as prior (``prior="map"``, Kaufman et al. 2016): the kernel against brute force over every
occupancy configuration of a short ray, the p0 special case, the grid handing over the map's log-odds, refusals."""

import itertools

import numpy as np
import pytest
from scipy import integrate

from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.grid import OccupancyMap, make_integrator
from prismap.grid._ray_batch import RayBatch
from prismap.pipeline import map_sequence
from prismap.sensor_models import ConditionedModel, InverseSensorModel, PrismModel
from prismap.sensor_models._prism_discrete import log_mean_likelihood, prism_discrete_posteriors
from support import MIXTURE, config, synthetic_sequence

MIX = GaussianMixture([0.7, 0.25, 0.05], [0.0, 0.3, -1.0], [0.4, 1.2, 8.0])
FB = 60.0


def model(**changes):
    options = dict(
        error_model=MIX,
        focal_baseline=FB,
        voxel_size_m=0.1,
        p0=0.05,
        near_m=2.0,
        far_depth_m=2.7,
        prior="map",
        overhang_fraction=0.0,
    )
    options.update(changes)
    return PrismModel(**options)


def logit(p):
    return np.log(p) - np.log1p(-p)


def brute_force(d, edges, priors, tail, events):
    """Posterior of each event (a set of cells: "some cell of it occupied") by summing over all 2^n maps.

    Cells are binary and independent with ``priors``; the first occupied one produces ``d`` with ``g``
    averaged over its disparities, no occupied cell with ``tail`` (the density of ``d`` given none).
    Returns the posteriors and the events' prior probabilities.
    """
    u = FB / edges
    lik = np.exp(log_mean_likelihood(u[1:], u[:-1], d, MIX))
    num, prior_of, total = np.zeros(len(events)), np.zeros(len(events)), 0.0
    for cfg in itertools.product((False, True), repeat=len(priors)):
        cfg = np.array(cfg)
        weight = np.prod(np.where(cfg, priors, 1 - priors))
        evidence = weight * (lik[np.argmax(cfg)] if cfg.any() else tail)
        total += evidence
        for e, cells in enumerate(events):
            if cfg[list(cells)].any():
                num[e] += evidence
                prior_of[e] += weight
    return num / total, prior_of


def far_density(d, z_max):
    return float(np.exp(log_mean_likelihood(0.0, FB / z_max, d, MIX)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_is_the_exact_posterior_of_every_map_of_a_short_ray(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 9))
    edges = np.sort(rng.uniform(2.0, 2.7, n - 1))
    edges = np.r_[2.0, edges, 2.7]  # the last cell ends at far_depth_m: beyond it only the far measurement
    voxel_p = rng.uniform(0.01, 0.9, n)
    priors = 1 - (1 - voxel_p) ** (np.diff(edges) / 0.1)  # a cell of a voxel's probability P: its stretch's share
    d = FB / rng.uniform(2.1, 2.6) + rng.normal(0.0, 0.5)
    post, inc = model().cell_posteriors(
        [d], [1.0], np.zeros(n, int), edges[:-1], edges[1:], map_log_odds=logit(voxel_p)
    )
    want, _ = brute_force(d, edges, priors, far_density(d, 2.7), [(k,) for k in range(n)])
    np.testing.assert_allclose(post, want, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(inc, logit(want) - logit(priors), rtol=1e-9, atol=1e-9)


def test_the_ray_beyond_its_last_cell_has_the_prior_rate_and_the_far_measurement():
    # cells end at 2.4 m, the model reasons to 3.5 m: the rest of the ray is a Poisson stretch at p0's rate
    edges = np.linspace(2.0, 2.4, 5)
    priors = np.array([0.02, 0.3, 0.6, 0.1])
    d, z_max = FB / 2.6, 3.5
    prism = model(far_depth_m=z_max)
    lam = prism.rate_per_m
    g = lambda z: float(np.exp(MIX.logpdf(np.array([FB / z - d])))[0])  # noqa: E731
    inside = integrate.quad(lambda z: lam * np.exp(-lam * (z - 2.4)) * g(z), 2.4, z_max, points=[2.6], limit=200)[0]
    tail = inside + np.exp(-lam * (z_max - 2.4)) * far_density(d, z_max)
    post, _ = prism.cell_posteriors([d], [1.0], np.zeros(4, int), edges[:-1], edges[1:], map_log_odds=logit(priors))
    want, _ = brute_force(d, edges, priors, tail, [(k,) for k in range(4)])
    np.testing.assert_allclose(post, want, rtol=1e-6)


def test_a_stretch_to_the_next_cell_is_the_posterior_that_either_cell_is_occupied():
    edges = np.linspace(2.0, 2.7, 8)
    priors = np.random.default_rng(5).uniform(0.02, 0.5, 7)
    d = FB / 2.35
    overhang = 0.1  # metres along the ray; overhang_fraction 1, |r| 1: each cell's stretch ends at the next one's end
    post, inc = model(overhang_fraction=1.0).cell_posteriors(
        [d], [1.0], np.zeros(7, int), edges[:-1], edges[1:], map_log_odds=logit(priors), voxel_overhang_m=[overhang]
    )
    events = [(k, k + 1) if k < 6 else (k,) for k in range(7)]  # the last stretch is cut at the ray's end
    want, prior = brute_force(d, edges, priors, far_density(d, 2.7), events)
    np.testing.assert_allclose(post, want, rtol=1e-9)
    np.testing.assert_allclose(inc, logit(want) - logit(prior), rtol=1e-8, atol=1e-9)


def test_priors_at_p0_give_the_thesis_discrete_form_and_an_empty_map_is_p0():
    edges = np.linspace(2.0, 2.7, 8)  # cells of one voxel length: a voxel's prior is the cell's
    for d in (FB / 2.33 + 0.2, FB / 2.05, FB / 2.69 - 3.0):
        post, inc = model().cell_posteriors([d], [1.0], np.zeros(7, int), edges[:-1], edges[1:])
        np.testing.assert_allclose(
            post, prism_discrete_posteriors(d, edges, MIX, focal_baseline=FB, p0=0.05), rtol=1e-9, atol=1e-14
        )
        explicit = model().cell_posteriors(
            [d], [1.0], np.zeros(7, int), edges[:-1], edges[1:], map_log_odds=np.full(7, logit(0.05))
        )
        np.testing.assert_allclose(explicit[1], inc, rtol=1e-12, atol=1e-14)


def test_pass_through_thins_each_cells_likelihood_ratio():
    edges = np.linspace(2.0, 2.7, 8)
    priors = np.random.default_rng(9).uniform(0.02, 0.5, 7)
    args = ([FB / 2.35], [1.0], np.zeros(7, int), edges[:-1], edges[1:])
    post0, inc0 = model().cell_posteriors(*args, map_log_odds=logit(priors))
    post, inc = model(pass_through=0.2).cell_posteriors(*args, map_log_odds=logit(priors))
    np.testing.assert_allclose(inc, np.log(0.2 + 0.8 * np.exp(inc0)), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(logit(post), logit(priors) + inc, rtol=1e-9, atol=1e-9)


def test_rays_are_independent_and_a_short_segment_takes_its_voxels_rate():
    # two rays in one call, cells given out of order: each ray as if alone; the second ray's half-voxel cells
    # in voxels of probability P have prior 1 - (1 - P)^(1/2)
    prism = model()
    one = prism.cell_posteriors(
        [FB / 2.3], [1.0], np.zeros(3, int), [2.0, 2.1, 2.2], [2.1, 2.2, 2.7], map_log_odds=[-1.0, 0.5, -2.0]
    )
    half = 1 - (1 - 0.3) ** 0.5
    alone = prism.cell_posteriors(
        [FB / 2.5], [1.0], np.zeros(2, int), [2.0, 2.05], [2.05, 2.7], map_log_odds=[logit(0.3), -2.0]
    )
    both = prism.cell_posteriors(
        [FB / 2.3, FB / 2.5],
        [1.0, 1.0],
        [1, 0, 0, 1, 0],
        [2.0, 2.2, 2.0, 2.05, 2.1],
        [2.05, 2.7, 2.1, 2.7, 2.2],
        map_log_odds=[logit(0.3), -2.0, -1.0, -2.0, 0.5],
    )
    np.testing.assert_allclose(both[1], [alone[1][0], one[1][2], one[1][0], alone[1][1], one[1][1]], rtol=1e-12)
    # the same cells in voxels of half the size, at the same rates: the first cell a whole voxel at prior `half`
    same_rate = np.log(np.expm1(np.logaddexp(0.0, -2.0) / 2))
    scaled = model(voxel_size_m=0.05).cell_posteriors(
        [FB / 2.5], [1.0], np.zeros(2, int), [2.0, 2.05], [2.05, 2.7], map_log_odds=[logit(half), same_rate]
    )
    np.testing.assert_allclose(scaled[1], alone[1], rtol=1e-12)


def test_bad_input_is_refused():
    with pytest.raises(PrismapInputError, match="`prior` must be one of"):
        model(prior="occupancy")
    args = ([FB / 2.3], [1.0], np.zeros(3, int), [2.0, 2.1, 2.2], [2.1, 2.2, 2.7])
    with pytest.raises(PrismapInputError, match="map_log_odds"):
        model().cell_posteriors(*args, map_log_odds=[0.0, 0.0])
    with pytest.raises(PrismapInputError, match="only with prior='map'"):
        model(prior="p0").cell_posteriors(*args, map_log_odds=[0.0, 0.0, 0.0])
    with pytest.raises(PrismapInputError, match="without gaps"):
        model().cell_posteriors([FB / 2.3], [1.0], np.zeros(2, int), [2.0, 2.15], [2.1, 2.7])
    with pytest.raises(PrismapInputError, match="start at or before near_m"):
        model().cell_posteriors([FB / 2.3], [1.0], np.zeros(2, int), [2.1, 2.2], [2.2, 2.7])


class RecordingModel(InverseSensorModel):
    """Takes the map as prior and records what the grid hands it; changes nothing."""

    name = "test-recording"
    takes_map_prior = True

    def __init__(self):
        self.calls = []

    def cell_posteriors(self, disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m, *, map_log_odds):
        self.calls.append((np.array(depth_start_m), np.array(map_log_odds)))
        return np.full(len(depth_start_m), 0.5), np.zeros(len(depth_start_m))

    def influence_depth(self, disparity_px, ray_norm):
        return np.full(len(disparity_px), 1.25)

    def with_extra_noise(self, sigma_px):
        return self


def test_the_ray_integrator_hands_over_each_cells_map_log_odds_before_the_frame():
    grid = OccupancyMap(0.1, p0=0.05)
    keys = np.array([[k, 0, 0] for k in range(0, 12, 2)])  # every other voxel along +x known, values k / 4
    grid.set_voxels(keys, keys[:, 0] / 4.0, np.ones(len(keys), np.uint16))
    recorder = RecordingModel()
    for _ in range(2):  # the second frame sees the same values: the recorder changes nothing
        grid.integrate_rays([0.0, 0.05, 0.05], [[1.0, 0.0, 0.0]], [1.0], recorder)
    for start, log_odds in recorder.calls:
        k = np.floor(start / 0.1 + 1e-9).astype(int)  # the ray runs along x through voxel centres
        assert k.tolist() == list(range(13))
        want = np.where((k % 2 == 0) & (k < 12), k / 4.0, grid.prior_log)
        np.testing.assert_allclose(log_odds, want, atol=2.0**-20)


def test_whole_rays_are_needed():
    batch = RayBatch(np.zeros(3), np.array([[0.0, 0.0, 1.0]]), np.array([1.0]), np.array([1.0]))
    with pytest.raises(PrismapInputError, match="needs whole rays: use mode='ray'"):
        make_integrator("projective", voxel_size_m=0.1, map_log_odds=lambda rows: rows).integrate(
            None, batch, RecordingModel()
        )
    with pytest.raises(PrismapInputError, match="needs `map_log_odds`"):
        make_integrator("ray", voxel_size_m=0.1).integrate(None, batch, RecordingModel())
    conditioned = ConditionedModel(model(), (model(),))
    assert conditioned.takes_map_prior and not ConditionedModel(model(prior="p0"), (model(prior="p0"),)).takes_map_prior


def test_the_pipeline_maps_with_the_map_prior_here_and_refuses_dask_and_projective(tmp_path):
    sequence = synthetic_sequence(tmp_path / "seq", n_frames=2)
    cfg = config(model="prism", model_params={"prior": "map", "near_m": 0.5}, error_model=MIXTURE)
    grid = map_sequence(sequence, cfg, progress=False)
    assert grid.n_frames == 2 and grid.n_known > 0
    plain = map_sequence(
        sequence, config(model="prism", model_params={"near_m": 0.5}, error_model=MIXTURE, floor_rays=0), progress=False
    )
    assert plain.n_known == grid.n_known  # same rays (no floor sampling, as with the map prior), same voxels
    with pytest.raises(PrismapInputError, match="cannot be merged"):
        map_sequence(sequence, cfg, progress=False, client=object())
    with pytest.raises(PrismapInputError, match="needs whole rays"):
        map_sequence(sequence, config(model="prism", model_params={"prior": "map"}, mode="projective"), progress=False)
