"""PRISM: discrete reference against brute force, continuous against discrete, table against direct, shape."""

import itertools
import mmap
import pickle
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from prismap._memory import _meminfo_bytes
from prismap.camera import integrate_disparity
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import (
    PrismModel,
    _kernels_direct,
    _kernels_lookup,
    _kernels_march,
    _kernels_math,
    _kernels_pack,
    _kernels_table,
    _prism,
    _prism_cache,
    _prism_spacing,
    estimate_prior_from_likelihood,
    make_sensor_model,
    prior_from_ground_truth,
    prism_discrete_posteriors,
)
from prismap.sensor_models._kernel_args import Geometry, Mixture
from prismap.sensor_models._prism import TABLE_TOLERANCE

FB = 61.5  # New Tsukuba: 615 px * 0.10 m
MIXTURE = GaussianMixture([0.85, 0.15], [0.05, -0.3], [0.4, 2.5])


def _on_grid(depth):
    """Disparity of ``depth`` rounded to OpenCV's 1/16 px."""
    return np.round(FB / np.asarray(depth, dtype=np.float64) * 16) / 16


def _tiling(edges_of_rays):
    """Cells tiling each ray between its ascending ``edges_of_rays[r]`` (metres): ``(rays, starts, ends)``."""
    rays = np.concatenate([np.full(edges.size - 1, r) for r, edges in enumerate(edges_of_rays)])
    return rays, np.concatenate([e[:-1] for e in edges_of_rays]), np.concatenate([e[1:] for e in edges_of_rays])


def _one_ray_cells(edges):
    n = edges.size - 1
    return np.zeros(n, np.int64), edges[:-1], edges[1:]


def _brute_force(d_hat, edges, mixture, p0, doffs=0.0):
    """Enumerate all 2^n maps: independent cells of prior p0, the first occupied cell produces d^."""
    u = FB / edges
    n = edges.size - 1
    # g averaged uniformly over true disparities of each cell: e = u - doffs - d^
    lik = (mixture.cdf(u[:-1] - doffs - d_hat) - mixture.cdf(u[1:] - doffs - d_hat)) / (u[:-1] - u[1:])
    lik_far = (mixture.cdf(u[-1] - doffs - d_hat) - mixture.cdf(0.0 - doffs - d_hat)) / u[-1]
    joint_occupied = np.zeros(n)
    total = 0.0
    for bits in itertools.product((0, 1), repeat=n):
        bits = np.array(bits)
        prior = np.prod(np.where(bits == 1, p0, 1 - p0))
        occupied = np.flatnonzero(bits)
        weight = prior * (lik[occupied[0]] if occupied.size else lik_far)
        total += weight
        joint_occupied += weight * bits
    return joint_occupied / total


@pytest.mark.parametrize(("n", "depth", "p0"), [(1, 2.0, 0.3), (6, 2.7, 0.2), (12, 3.1, 0.1), (12, 9.0, 0.05)])
def test_discrete_reference_equals_brute_force(n, depth, p0):
    edges = 1.0 + 0.4 * np.arange(n + 1)
    d_hat = FB / depth
    expected = _brute_force(d_hat, edges, MIXTURE, p0)
    got = prism_discrete_posteriors(d_hat, edges, MIXTURE, focal_baseline=FB, p0=p0)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def test_discrete_reference_with_disparity_offset():
    edges = np.linspace(2.0, 5.0, 9)
    d_hat = FB / 3.3 - 31.0
    expected = _brute_force(d_hat, edges, MIXTURE, 0.15, doffs=31.0)
    got = prism_discrete_posteriors(d_hat, edges, MIXTURE, focal_baseline=FB, doffs_px=31.0, p0=0.15)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def test_continuous_converges_to_discrete_as_cells_shrink():
    errors = []
    d_hat = FB / 3.0
    rate = 0.5  # surfaces per metre
    for length in (0.2, 0.1, 0.05, 0.025, 0.0125):
        edges = np.arange(1.0, 8.0 + 1e-9, length)
        p0 = -np.expm1(-rate * length)
        model = PrismModel(
            error_model=MIXTURE,
            focal_baseline=FB,
            voxel_size_m=length,
            p0=p0,
            near_m=edges[0],
            far_depth_m=edges[-1],
            method="direct",
        )
        continuous, _ = model.cell_posteriors([d_hat], [1.0], *_one_ray_cells(edges))
        discrete = prism_discrete_posteriors(d_hat, edges, MIXTURE, focal_baseline=FB, p0=p0)
        errors.append(np.abs(continuous - discrete).max())
    assert all(b < 0.6 * a for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 2e-3


def _random_cells(rng, depths, n_cells=120):
    starts, ends, rays = [], [], []
    for r, z in enumerate(depths):
        edges = np.sort(rng.uniform(0.1, 2.5 * z + 1.0, n_cells + 1))
        starts.append(edges[:-1])
        ends.append(edges[1:])
        rays.append(np.full(n_cells, r))
    return np.concatenate(rays), np.concatenate(starts), np.concatenate(ends)


@pytest.mark.parametrize(
    ("mixture", "voxel", "p0"),
    [
        (MIXTURE, 0.1, 0.05),
        (GaussianMixture.gaussian(0.3), 0.05, 0.2),
        (GaussianMixture([0.6, 0.3, 0.1], [0.1, -0.5, 2.0], [0.25, 1.0, 6.0]), 0.2, 0.01),
    ],
)
def test_table_agrees_with_direct_within_stated_bound(mixture, voxel, p0):
    rng = np.random.default_rng(3)
    depths = np.exp(rng.uniform(np.log(0.4), np.log(40.0), 25))
    model = make_sensor_model("prism", focal_baseline=FB, error_model=mixture, voxel_size_m=voxel, p0=p0)
    _assert_table_within_tolerance(
        model, _on_grid(depths), rng.uniform(1.0, 1.3, depths.size), _random_cells(rng, depths)
    )


def _assert_table_within_tolerance(model, disparity, norm, cells, *, moderate_min=500, large_min=50):
    p_table, inc_table = model.cell_posteriors(disparity, norm, *cells)
    p_direct, inc_direct = model.cell_posteriors(disparity, norm, *cells, method="direct")
    moderate = np.abs(inc_direct) <= TABLE_TOLERANCE["large"]
    assert moderate.sum() >= moderate_min and (~moderate).sum() >= large_min
    assert np.all(np.abs(inc_table - inc_direct) <= _table_bound(inc_direct))
    assert np.abs(p_table - p_direct).max() <= TABLE_TOLERANCE["posterior"]


KITTI_FB = 720.0 * 0.54
STREET = GaussianMixture([0.80, 0.15, 0.05], [0.0, -0.1, -2.0], [0.3, 1.0, 10.0])


@pytest.mark.parametrize("voxel", [0.2, 0.1])
def test_table_with_a_broad_front_agrees_with_direct_within_stated_bound(voxel):
    """A street rig and a mixture with 5 % outliers of 10 px: most of each table is its broad front."""
    rng = np.random.default_rng(4)
    depths = np.exp(rng.uniform(np.log(2.0), np.log(80.0), 25))
    model = make_sensor_model(
        "prism", focal_baseline=KITTI_FB, error_model=STREET, voxel_size_m=voxel, p0=0.05, near_m=1.5
    )
    disparity = np.round(KITTI_FB / depths * 16) / 16
    _assert_table_within_tolerance(model, disparity, rng.uniform(1.0, 1.3, depths.size), _random_cells(rng, depths))
    meta = model._cache.meta
    rows = [meta[:, _kernels_pack.META_COLUMNS.index(f"row_{k}")] for k in range(_kernels_table.N_SEGMENTS)]
    assert np.all(rows[2] - rows[1] > 10)  # a broad front, and the cells above crossed it
    assert np.sum(rows[4] - rows[3] > 10) >= 3  # the near measurements' tables have a broad back


SGBM_LIKE = GaussianMixture([0.84, 0.10, 0.06], [0.01, -0.04, -10.4], [0.24, 0.92, 13.6])
FAR_APART = GaussianMixture([0.912, 0.003, 0.075, 0.01], [0.0, 41.7, 0.2, 81.7], [0.139, 0.41, 0.615, 0.703])
"""A characterised class's mixture (SGBM on the half-resolution street): narrow components 42 and 82 px in front
of the main one and no wide component to span them."""


@pytest.mark.parametrize(
    ("fb", "mixture", "voxel", "p0", "near"),
    [
        (KITTI_FB, STREET, 0.2, 0.05, 1.5),
        (KITTI_FB, STREET, 0.1, 0.05, 1.5),
        (FB, SGBM_LIKE, 0.1, 0.05, 0.5),
        (FB, MIXTURE, 0.05, 0.1, 0.5),
    ],
)
def test_table_within_stated_bound_at_the_rate_grids_half_steps(fb, mixture, voxel, p0, near):
    """Rays on the edges between two keys of the rate grid (``delta = +-_LAMBDA_STEP / 2``, the largest Taylor step
    in log lambda) and cells of 0.5-15 cm tiling 2-80 m, the short ones far in front of the measurement
    included (where ``C`` grows slowly, so a cell's share of it follows the derivative of the Taylor terms)."""
    rng = np.random.default_rng(13)
    disparity = np.round(fb / np.geomspace(2.0, 60.0, 7) * 16) / 16
    edge = np.arange(1, 5) * _prism._LAMBDA_STEP
    log_norm = np.concatenate([edge - 1e-6, edge + 1e-6])  # either side: the tables of both neighbouring keys
    disparity, norm = np.repeat(disparity, log_norm.size), np.tile(np.exp(log_norm), disparity.size)
    edges = [2.0 + np.concatenate([[0.0], np.cumsum(rng.uniform(0.005, 0.15, 1100))]) for _ in disparity]
    model = make_sensor_model("prism", focal_baseline=fb, error_model=mixture, voxel_size_m=voxel, p0=p0, near_m=near)
    _, delta, _, _ = model._tables_for(disparity, norm)
    assert np.abs(delta).min() > 0.499 * _prism._LAMBDA_STEP
    cells = _tiling([e[e <= 80.0] for e in edges])
    _assert_table_within_tolerance(model, disparity, norm, cells, moderate_min=40_000, large_min=0)


def _profile_by_brute_force(mixture, e):
    """The spacing ratio at errors ``e`` (pixels) by the rule ``spacing_profile`` states, point by point."""
    log_dens = np.log(mixture.weights / mixture.sigmas) - 0.5 * ((e[:, None] - mixture.means) / mixture.sigmas) ** 2
    within = np.abs(e[:, None] - mixture.means) <= _prism_spacing._WINDOW_SIGMAS * mixture.sigmas
    matters = within & (log_dens >= log_dens.max(axis=1, keepdims=True) + _prism_spacing._BROAD_SHARE)
    own = np.floor(_prism_spacing._WIDE_SIGMAS * mixture.sigmas / (mixture.sigmas.min() * _prism_spacing._TABLE_STEP))
    own = np.clip(own, 1, _prism_spacing._COARSE_RATIO)
    ratio = np.where(matters, own, np.inf).min(axis=1)
    windowed = np.flatnonzero(within.any(axis=1))
    ratio[np.isinf(ratio)] = 0
    ratio[: windowed[0]] = ratio[windowed[0]]  # in front of every window (e descending): the first one's spacing
    ratio[windowed[-1] + 1 :] = 1  # behind every window: fine
    return ratio


@pytest.mark.parametrize("name", ["STREET", "TWO_WIDE", "FAR_APART", "SGBM_LIKE", "one Gaussian"])
def test_spacing_profile_follows_the_components_that_matter(name):
    """Each piece's ratio against the rule evaluated on a dense grid of errors: the narrowest component within
    _WINDOW_SIGMAS of its sigmas and within e^_BROAD_SHARE of the largest density sets the spacing, gaps (0)
    between windows, the first window's spacing in front and fine behind."""
    mixture = {"one Gaussian": GaussianMixture.gaussian(0.3)}.get(name) or globals()[name]
    edges, ratios = _prism_spacing.spacing_profile(mixture)
    assert edges[0] == np.inf and edges[-1] == -np.inf and np.all(np.diff(edges) < 0)
    assert ratios.size == edges.size - 1 <= _prism_spacing._MAX_PIECES + 1 and np.all(ratios[1:] != ratios[:-1])
    spread = np.abs(mixture.means).max() + _prism_spacing._WINDOW_SIGMAS * mixture.sigmas.max()
    e = np.linspace(spread + 5.0, -spread - 5.0, 200_001)
    piece = np.searchsorted(-edges, -e, side="right") - 1
    near_edge = np.abs(e[:, None] - edges[1:-1]).min(axis=1, initial=np.inf) < 1e-6 * spread
    np.testing.assert_array_equal(ratios[piece][~near_edge], _profile_by_brute_force(mixture, e)[~near_edge])


def test_spacing_profile_has_gaps_between_far_apart_components_and_keeps_an_outlier_component():
    edges, ratios = _prism_spacing.spacing_profile(FAR_APART)
    assert np.count_nonzero(ratios == 0) == 2  # between the components at 81.7, 41.7 and 0 px
    edges, ratios = _prism_spacing.spacing_profile(STREET)  # the 10 px outliers span the others: no gap
    assert 0 not in ratios and ratios[0] == int(_prism_spacing._WIDE_SIGMAS * 10.0 / (0.3 * _prism_spacing._TABLE_STEP))


TWO_WIDE = GaussianMixture([0.70, 0.15, 0.02, 0.08, 0.05], [0.0, -0.4, -20.0, 38.0, 33.7], [0.3, 3.5, 0.15, 33.0, 33.5])
"""A characterised class's mixture (SGBM on the street, half resolution): its own 33 px outlier component beside
the whole image's 33.5 px one, and a narrow component 20 px behind the measurement."""


@pytest.mark.parametrize("voxel", [0.2, 0.1])
def test_table_with_two_wide_components_agrees_with_direct_within_stated_bound(voxel):
    """The half-resolution street rig with :data:`TWO_WIDE`: broad segments on the 33 px components."""
    rng = np.random.default_rng(5)
    fb = KITTI_FB / 2
    depths = np.exp(rng.uniform(np.log(3.0), np.log(80.0), 25))
    model = make_sensor_model("prism", focal_baseline=fb, error_model=TWO_WIDE, voxel_size_m=voxel, p0=0.05)
    disparity = np.round(fb / depths * 16) / 16
    _assert_table_within_tolerance(
        model, disparity, rng.uniform(1.0, 1.1, depths.size), _random_cells(rng, depths), large_min=0
    )
    meta = model._cache.meta
    rows = [meta[:, _kernels_pack.META_COLUMNS.index(f"row_{k}")] for k in range(_kernels_table.N_SEGMENTS)]
    assert np.all(rows[1] - rows[0] > 10)  # a broad front on every table


NEEDLE = GaussianMixture(
    [0.684, 0.288, 0.027, 0.0007, 0.0003], [-0.02, 0.08, -0.17, -0.7, 33.74], [0.14, 0.28, 0.01, 0.01, 33.54]
)
"""A characterised class's mixture (SGBM on the half-resolution street) with components of 0.01 px beside 33.5 px
outliers: its coarse front is spaced on the outliers' sigma."""


def test_coarse_front_spacing_follows_the_widest_sigma_only_for_a_wide_span():
    for mixture in (
        STREET,
        SGBM_LIKE,
        MIXTURE,
        GaussianMixture([0.64, 0.27, 0.05, 0.04], [0.05, -0.04, 0.2, 33.7], [0.168, 0.35, 3.27, 33.54]),
    ):
        assert _prism_spacing.coarse_ratio(mixture) == _prism_spacing._COARSE_RATIO
    spacing_px = (
        _prism_spacing.coarse_ratio(NEEDLE) * _prism_spacing._TABLE_STEP * 0.01
    )  # disparity between coarse nodes
    assert 33.54 * _prism_spacing._COARSE_WIDE_SIGMAS - 0.01 < spacing_px <= 33.54 * _prism_spacing._COARSE_WIDE_SIGMAS


def _street_class_tables(mixture, seed, far_m):
    """The tables of a characterised class's ``mixture`` on the half-resolution street rig (12 rays at 3 m to
    ``far_m``, 1/16 px disparities), their cells checked against ``method="direct"``: the tables' metadata."""
    rng = np.random.default_rng(seed)
    fb = KITTI_FB / 2
    depths = np.exp(rng.uniform(np.log(3.0), np.log(far_m), 12))
    model = make_sensor_model("prism", focal_baseline=fb, error_model=mixture, voxel_size_m=0.2, p0=0.05)
    disparity = np.round(fb / depths * 16) / 16
    _assert_table_within_tolerance(
        model, disparity, rng.uniform(1.0, 1.1, depths.size), _random_cells(rng, depths), large_min=0
    )
    return model._cache.meta


def test_table_with_a_needle_component_agrees_with_direct_within_stated_bound():
    meta = _street_class_tables(NEEDLE, 6, 80.0)
    column = _kernels_pack.META_COLUMNS.index
    assert np.all(meta[:, column("row_1")] > 10)  # a coarse front, and the cells in it agree


def test_table_with_far_apart_components_agrees_with_direct_and_spans_the_gaps_in_two_panels():
    """Between the windows of components tens of pixels apart ``q g`` is negligible: two panels span each gap, so
    a table holds a fraction of the nodes that fine spacing from its first window to its back would need."""
    meta = _street_class_tables(FAR_APART, 9, 80.0)
    column = _kernels_pack.META_COLUMNS.index
    march = meta[:, column("length")] - meta[:, column("row_1")]
    x_span = meta[:, column(f"x_{_kernels_table.N_SEGMENTS - 1}")] - meta[:, column("x_1")]
    fine_nodes = x_span / _prism_spacing._TABLE_STEP
    assert np.all(march < 0.5 * fine_nodes)


@pytest.mark.parametrize("mixture", [GaussianMixture.gaussian(1.0), STREET, FAR_APART, SGBM_LIKE, NEEDLE])
def test_packed_tables_keep_each_side_wherever_a_look_up_may_read_it(mixture):
    """A packed table keeps C only to ``c_end`` and D only from ``d_first`` (``_kernels_pack._side_rows``): at
    every interval from ``c_end`` on, the look-up's interpolated ``log(C/Z)`` is at least ``log(1/2)`` (it reads
    D there), and before ``d_first`` below ``log(1/4)`` (it never reads D), at every fraction and rate offset of
    the rays that share the table; the packed tables hold little more than one side's rows."""
    rng = np.random.default_rng(11)
    fb = KITTI_FB / 2
    model = make_sensor_model("prism", focal_baseline=fb, error_model=mixture, voxel_size_m=0.2, p0=0.05)
    disparity = np.round(fb / np.exp(rng.uniform(np.log(3.0), np.log(80.0), 6)) * 16) / 16
    delta_max = np.log1p(model._table_spec.lam_slack)
    fraction = np.linspace(0.0, 1.0, 65)
    offsets = np.linspace(-delta_max, delta_max, 5)
    stored = length = 0
    for d in disparity:
        lam = model.rate_per_m * np.exp(_kernels_pack.rate_key_centre(0, _prism._LAMBDA_STEP))
        log_far = model._log_far(np.array([d]))[0]
        args = (d + model.doffs_px, lam, log_far, model._geometry(), model._table_spec, model._mixture())
        nodes, table_meta = _kernels_table.prism_table(*args)
        c_end, d_first = _kernels_pack._side_rows(nodes, table_meta, delta_max)
        spacing = np.repeat(
            table_meta[2 * _kernels_table.N_SEGMENTS : 3 * _kernels_table.N_SEGMENTS],
            np.diff(
                np.append(table_meta[_kernels_table.N_SEGMENTS : 2 * _kernels_table.N_SEGMENTS], nodes.shape[0])
            ).astype(np.int64),
        )  # each row's interval width in x
        for k in range(1, nodes.shape[0] - 1):
            if d_first <= k < c_end:
                continue
            values = [
                _kernels_lookup._interpolate(nodes, k, f, spacing[k], 0, delta) for f in fraction for delta in offsets
            ]
            if k >= c_end:
                assert min(values) >= np.log(0.5), (d, k, c_end)
            else:
                assert max(values) < np.log(0.25), (d, k, d_first)
        packed, meta = _kernels_pack.prism_tables(np.array(args[0:1]), np.array([lam]), np.array([log_far]), *args[3:])
        assert meta[0, _prism_cache._STORED] == packed.shape[0] == c_end + 1 + nodes.shape[0] - d_first
        np.testing.assert_array_equal(packed[: c_end + 1], nodes[: c_end + 1, :5].astype(np.float32))
        np.testing.assert_array_equal(packed[c_end + 1 :], nodes[d_first:, 5:].astype(np.float32))
        stored, length = stored + packed.shape[0], length + nodes.shape[0]
    assert stored < 1.15 * length


@pytest.mark.parametrize("mixture", [GaussianMixture.gaussian(1.0), STREET, FAR_APART, SGBM_LIKE])
def test_coarse_front_reaches_as_far_as_its_conditions_hold(mixture):
    """A table's coarse front ends where ``C/Z`` reaches ``e^coarse_below`` (less the refit margin) or ``q g``
    stops rising steeply (``_STEEP_END``), to a thousandth of its spacing: nothing before the march is left to
    fine nodes (unless the front stopped at its cap or for want of room before ``z_max``)."""
    rng = np.random.default_rng(10)
    fb = KITTI_FB / 2
    model = make_sensor_model("prism", focal_baseline=fb, error_model=mixture, voxel_size_m=0.2, p0=0.05)
    disparity = np.round(fb / np.exp(rng.uniform(np.log(3.0), np.log(80.0), 12)) * 16) / 16
    model._tables_for(disparity, np.ones(disparity.size))
    geometry, kernel_mixture = model._geometry(), model._mixture()
    column = _kernels_pack.META_COLUMNS.index
    fronts = 0
    for m in model._cache.meta:
        lam, shift, log_z, h_coarse, x_split = (m[column(c)] for c in ("lam", "shift", "log_z", "h_0", "x_1"))
        x_end = _kernels_march.x_of_z(geometry.z_max, lam, geometry.ku)
        if not 0 < m[column("row_1")] < _kernels_table.MAX_COARSE or x_split + 2 * h_coarse >= x_end:
            continue  # no front, or one that stopped at its cap or for want of room before z_max
        fronts += 1

        def log_c_over_z(x, lam=lam, shift=shift, log_z=log_z):
            z = _kernels_march.z_of_x(x, lam, geometry.ku)
            return _kernels_table._log_c_asymptotic(z, lam, shift, geometry, kernel_mixture)[0] - log_z

        assert log_c_over_z(x_split) < _prism_spacing._COARSE_BELOW
        beyond = x_split + 1e-3 * h_coarse
        steep = _kernels_table._steep(beyond, lam, shift, geometry, kernel_mixture, _kernels_table._STEEP_END)
        assert not steep or log_c_over_z(beyond) > _prism_spacing._COARSE_BELOW - _kernels_table._FIT_MARGIN - 0.05
    assert fronts >= 4


def test_table_of_one_gaussian_on_the_street_rig_agrees_with_direct_within_stated_bound():
    """Far measurements (3-80 m) whose coarse fronts reach far: a front whose last interval reached where ``q g``
    is barely steep (``_STEEP``) interpolated its cells 3 % off (1.7x the bound)."""
    meta = _street_class_tables(GaussianMixture.gaussian(0.25), 0, 80.0)
    assert np.all(meta[:, _kernels_pack.META_COLUMNS.index("row_1")] > 10)  # every table has a coarse front


PINHEAD = GaussianMixture(
    [0.7983, 0.1903, 0.0061, 0.0053],
    [-0.021, 0.113, -0.359, -0.422],
    [0.1316, 0.2500, 0.0090, 0.0090],
    failure_weight=6.1e-5,
    search_range_px=(0.0, 64.0),
)
"""A characterised class's mixture (SGBM on the half-resolution street, 24 classes): 0.009 px components and no
wide one, so ``coarse_ratio`` keeps 64 and the front from near_m = 0.1 m would hold thousands of nodes."""


def test_coarse_front_is_capped_and_agrees_with_direct_within_stated_bound():
    """Without matcher failures (with them, the tables start at the failure floor, well after near_m)."""
    pinhead = GaussianMixture(PINHEAD.weights, PINHEAD.means, PINHEAD.sigmas)
    meta = _street_class_tables(pinhead, 8, 60.0)
    column = _kernels_pack.META_COLUMNS.index
    uncapped = _prism_spacing.coarse_ratio(pinhead) * _prism_spacing._TABLE_STEP
    assert np.all(meta[:, column("h_0")] > 4 * uncapped)  # the cap widened every front
    assert np.all(meta[:, column("row_1")] <= _kernels_table.MAX_COARSE)


FRAME_MIXTURE = GaussianMixture([0.9, 0.1], [0.0, 0.0], [0.3, 3.0])


def _first_intervals_end(model, table_meta, n):
    """Depth (metres) ``n`` widths of its first interval after a table's first node (``table_meta``: its meta row)."""
    column = _kernels_pack.META_COLUMNS.index
    segment = next(k for k in range(_kernels_table.N_SEGMENTS) if table_meta[column(f"row_{k + 1}")] > 0)  # row 0's
    x = table_meta[column(f"x_{segment}")] + n * table_meta[column(f"h_{segment}")]
    return _kernels_march.z_of_x(x, table_meta[column("lam")], model._ku())


@pytest.mark.parametrize(
    ("fb", "mixture", "voxel", "p0", "near", "depth", "steep"),
    [
        (KITTI_FB, STREET, 0.2, 0.05, 1.5, 5.0, True),
        (FB, SGBM_LIKE, 0.2, 0.05, 0.9, 5.0 * FB / KITTI_FB, False),
        (13.125, FRAME_MIXTURE, 0.1, 0.1, 0.5, 3.0, False),
    ],  # the last: tests/test_grid_frames.py's small frame
)
def test_cells_in_a_tables_first_interval_agree_with_direct(fb, mixture, voxel, p0, near, depth, steep):
    """Cells ending between near_m and a table's first node: C from the steep front's asymptotic, or (no
    steep front) from one panel over the interval, at the ray's own rate and with the ray's Z, for rays on
    the rate grid's keys' centres and edges (far in front of the measurement the rate term of
    log(C/Z) is about 1 - lambda_z z^ per unit of log lambda_z: several nats at a half step)."""
    model = make_sensor_model("prism", focal_baseline=fb, error_model=mixture, voxel_size_m=voxel, p0=p0, near_m=near)
    step = _prism._LAMBDA_STEP
    norm = np.exp(np.array([0.5 * step, step - 1e-6, step + 1e-6, 2 * step - 1e-6]))  # a key's centre, its edges
    disparity = np.repeat(np.round(fb / (depth * np.array([1.0, 2.4, 6.0, 12.0])) * 16) / 16, norm.size)
    norm = np.tile(norm, disparity.size // norm.size)
    table, delta, meta, _ = model._tables_for(disparity, norm)
    assert np.abs(delta[0::4]).max() < 1e-12 and np.abs(delta.reshape(-1, 4)[:, 1:]).min() > 0.499 * step
    column = _kernels_pack.META_COLUMNS.index
    assert np.all((meta[table, column("row_1")] > 0) == steep)  # a coarse front or none
    ends = [np.geomspace(near + 1e-4, _first_intervals_end(model, m, 1), 12) for m in meta[table]]
    rays = np.repeat(np.arange(disparity.size), 12)
    _assert_table_within_tolerance(
        model,
        disparity,
        norm,
        (rays, np.full(rays.size, near - 0.5), np.concatenate(ends)),
        moderate_min=0,
        large_min=0,
    )


@pytest.mark.parametrize(
    ("mixture", "depths"),
    [(TWO_WIDE, (2.7, 3.2, 3.9)), (SGBM_LIKE, (1.9, 2.3, 2.8))],
)
def test_cells_in_a_tables_second_interval_agree_with_direct(mixture, depths):
    """Without a steep front ``q g`` is not negligible at ``near_m``: ``C`` grows like ``z - z0`` there and ``log C``
    like ``log(z - z0)``, too curved for a cubic over the table's second interval (up to 0.016 nats off; the
    look-up integrates it on the spot, like the first). Short cells tile each ray from near_m to four first-interval widths,
    on the half-resolution street rig with measurements a metre or two behind near_m."""
    fb, near = KITTI_FB / 2, 1.5
    model = make_sensor_model("prism", focal_baseline=fb, error_model=mixture, voxel_size_m=0.2, p0=0.05, near_m=near)
    disparity = np.round(fb / np.repeat(depths, 3) * 16) / 16
    norm = np.tile([1.02, 1.105, 1.26], len(depths))
    table, _, meta, _ = model._tables_for(disparity, norm)
    column = _kernels_pack.META_COLUMNS.index
    assert np.all(meta[table, column("row_1")] == 0)  # no steep front
    edges = [np.linspace(near, _first_intervals_end(model, m, 4), 41) for m in meta[table]]
    _assert_table_within_tolerance(model, disparity, norm, _tiling(edges), moderate_min=200, large_min=0)


BUMP_BEFORE = GaussianMixture(
    [0.7564, 0.1930, 0.0460, 0.0046], [0.047, 0.032, 6.56, 25.26], [0.204, 0.764, 5.90, 0.415]
)
"""A characterised SGBM class of the quarter-size street: a 5.9 px component centred 6.6 px in front."""


def test_table_of_a_measurement_just_behind_a_bump_of_g_agrees_with_direct():
    """Measured 0.2 m behind near_m (quarter-size street rig, ``BUMP_BEFORE``), ``q g`` rises from near_m over the
    wide component's bump, falls, then rises steeply to the measurement: steep at the coarse front's first node but
    not between, so the front is dropped (its asymptotic ``C`` is not a number there, and above ``e^coarse_below``
    at the next node) and the march starts at near_m from ``C = 0``, not from the dropped front's ``C``."""
    fb, near = KITTI_FB / 4, 1.5
    model = make_sensor_model(
        "prism", focal_baseline=fb, error_model=BUMP_BEFORE, voxel_size_m=0.4, p0=0.0836, near_m=near
    )
    disparity = np.repeat(np.arange(56.375, 56.76, 1 / 16), 3)  # 1.71-1.72 m
    norm = np.tile([1.0, 1.12, 1.25], disparity.size // 3)
    tables = model._tables_for(disparity, norm)
    log_z = model._ray_log_z(tables)
    direct = _kernels_direct.prism_log_evidence(
        disparity,
        model.rate_per_m * norm,
        model._log_far(disparity),
        _prism._QUAD_STEP,
        model._geometry(),
        model._mixture(),
    )
    np.testing.assert_allclose(log_z, direct, rtol=0, atol=1e-3)  # Z: C from 0 at near_m
    edges = [np.linspace(near, 6.0, 121)] * disparity.size
    _assert_table_within_tolerance(model, disparity, norm, _tiling(edges), moderate_min=500, large_min=0)


def _table_bound(inc_direct):
    """:data:`TABLE_TOLERANCE`'s bound on ``|inc_table - inc_direct|`` (log-odds) at each direct increment."""
    size = np.abs(inc_direct)
    return np.where(
        size <= TABLE_TOLERANCE["large"],
        TABLE_TOLERANCE["abs"] + TABLE_TOLERANCE["rel"] * size,
        TABLE_TOLERANCE["large_rel"] * size,
    )


@pytest.mark.parametrize("mode", ["ray", "projective"])
def test_table_maps_agree_with_direct_maps_within_the_stated_bound(mode):
    """A whole frame (tests/test_grid_frames.py's small frame, disparities on the 1/16 px grid, ray norms
    1-1.2 across all rate offsets) mapped with tabulated and with direct PRISM, with and without the voxel
    overhang: every voxel's increment (log-odds minus prior) within the cell bound taken at the largest
    direct increment of that voxel's cells, for the mean of the frame's increments (a mean of errors within
    their cells' bounds is within the bound of the largest) and for the largest one (``max-abs``). Cells ending
    right after near_m (in the tables' first interval) are part of ray mode's map."""
    from test_grid_frames import small_frame

    from prismap.grid import OccupancyMap
    from prismap.grid._logodds import LOG_ODDS_STEP

    camera, pose, disparity = small_frame()
    disparity = np.rint(disparity * 16) / 16
    prior = np.log(0.1 / 0.9)
    for overhang in (0.0, _prism.OVERHANG_FRACTION):
        maps = {}
        for method, policy in itertools.product(("table", "direct"), ("mean", "max-abs")):
            model = make_sensor_model(
                "prism",
                focal_baseline=camera.focal_baseline,
                voxel_size_m=0.1,
                p0=0.1,
                error_model=FRAME_MIXTURE,
                near_m=0.5,
                method=method,
                overhang_fraction=overhang,
            )
            grid = OccupancyMap(0.1, p0=0.1)
            integrate_disparity(
                grid, disparity, camera, pose, model, mode=mode, max_range_m=6.0, subsample=6, policy=policy
            )
            keys, log, _ = grid.known_voxels()
            order = np.lexsort(keys.T)
            maps[method, policy] = keys[order], log[order] - prior
        keys, largest = maps["direct", "max-abs"]
        assert keys.shape[0] > 20_000
        bound = _table_bound(largest) + LOG_ODDS_STEP  # and the map's fixed-point rounding
        for policy in ("mean", "max-abs"):
            np.testing.assert_array_equal(maps["table", policy][0], keys)
            assert np.all(np.abs(maps["table", policy][1] - maps["direct", policy][1]) <= bound), (overhang, policy)


def test_table_combination_keeps_a_tiny_d_at_either_end():
    """prism_table_combine against the log-space combination (``_kernels_direct.combine``) for cells whose end has
    ``D/Z`` down to e^-36 (the looked-up side used as it is, not as ``1 - (1 - D/Z)``, where it would vanish
    beside ``q_c C(a)/Z``), starts with tiny ``C/Z`` or with ``D`` the smaller, and priors of 0.05-0.9."""
    l_c = -np.array([0.1, 2.0, 20.0, 30.0, 36.0])  # log D/Z at the end
    l_a = -np.array([3.0, 25.0, 33.0, 40.0])  # log C/Z at the start, and log D/Z for a start behind C/Z = 1/2
    lam_len = np.array([0.05, 0.5, 2.3])
    grid = np.array(list(itertools.product(l_a, l_c, lam_len, (0, 1))))
    la, lc, length, a_is_d = grid.T
    ok = ~a_is_d.astype(bool) | (la > lc)  # D only shrinks with depth
    la, lc, length, a_is_d = la[ok], lc[ok], length[ok], a_is_d[ok].astype(np.int8)
    n = la.size
    side = a_is_d + 2
    post, ratio, fix_value = np.empty(n), np.empty(n), np.empty(n)
    fixed = _kernels_lookup.prism_table_combine(
        0, n, la, lc, np.exp(la), np.exp(lc), side, length, post, ratio, np.empty(n, dtype=np.int64), fix_value, 0.0
    )
    assert fixed == 0  # the linear-space pass, not the log-space fallback
    other_a, other_c = np.log(-np.expm1(la)), np.log(-np.expm1(lc))
    expected = np.array(
        [
            _kernels_direct.combine(*((oa, a) if d else (a, oa)), oc, c, ln)[1]
            for a, oa, c, oc, ln, d in zip(la, other_a, lc, other_c, length, a_is_d)
        ]
    )
    np.testing.assert_allclose(np.log(ratio), expected, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("pass_through", [0.0, 0.02])
def test_cells_far_in_front_match_the_log_space_combination(pass_through):
    """prism_table_combine's cells far in front of the measurement (``log(C/Z)`` below -600 at both ends; gathered and
    combined by fast exp and log) against the log-space formula by numpy (``P Z = C(c) - e^-lam_len C(a)``, ``D/Z =
    1``), with gaps ``log(C(c)/C(a))`` from 0 (a start interpolated above its end) to 200 nats and cell priors from
    1e-7 to 1, mixed with cells of the linear pass; then thinned by ``pass_through``."""
    l_c = -np.array([600.5, 750.0, 4000.0, 1e5])
    gap = np.array([-1.0, 0.0, 1e-6, 0.1, 3.0, 200.0])  # log C(c) - log C(a); below 0 is interpolation noise
    lam_len = np.array([1e-7, 1e-3, 0.05, 2.3, 45.0, 800.0])
    lc, g, length = (v.ravel() for v in np.meshgrid(l_c, gap, lam_len, indexing="ij"))
    la = lc - g
    near = np.array([-3.0, -0.2])  # two cells of the linear pass between them, C/Z and D/Z at the end
    la, lc, length = np.r_[la, -5.0, -4.0], np.r_[lc, near], np.r_[length, 0.3, 0.3]
    side = np.r_[np.zeros(la.size - 1, dtype=np.int8), 2].astype(np.int8)
    n = la.size
    post, ratio, fix_value = np.empty(n), np.empty(n), np.empty(n)
    fix_index = np.empty(n, dtype=np.int64)
    fixed = _kernels_lookup.prism_table_combine(
        0, n, la, lc, np.exp(la), np.exp(lc), side, length, post, ratio, fix_index, fix_value, pass_through
    )
    far = np.arange(n - 2)
    assert fixed == far.size and sorted(fix_index[:fixed]) == list(far)
    increment = np.log(ratio)
    increment[fix_index[:fixed]] = fix_value[:fixed]
    log_num = lc[far] + np.log(-np.expm1(-(length[far] - np.minimum(la[far] - lc[far], 0.0))))
    expected = log_num - length[far] - np.log(-np.expm1(-length[far]))
    expected_post = np.exp(log_num)
    if pass_through:
        expected_post, expected = np.array(
            [_kernels_direct.pass_through_log(v, ln, pass_through) for v, ln in zip(expected, length[far])]
        ).T
    np.testing.assert_allclose(increment[far], expected, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(post[far], expected_post, rtol=1e-9, atol=0)
    assert np.all(np.isfinite(increment)) and np.all(ratio[-2:] != 1.0)  # the linear pass's cells stay its own


@pytest.mark.parametrize("method", ["table", "direct"])
def test_finite_and_in_unit_interval_from_10cm_to_200m_with_high_rate(method):
    rate = 50.0  # per metre: p0 = 1 - e^-5 for 0.1 m cells
    model = make_sensor_model(
        "prism",
        focal_baseline=FB,
        error_model=GaussianMixture.gaussian(0.3),
        voxel_size_m=0.1,
        p0=-np.expm1(-rate * 0.1),
        method=method,
    )
    depths = np.array([0.1, 0.3, 2.0, 30.0, 150.0, 200.0])
    disparity = _on_grid(depths)
    edges = np.geomspace(0.1, 200.0, 150)
    rays = np.repeat(np.arange(depths.size), edges.size - 1)
    post, inc = model.cell_posteriors(
        disparity, np.full(depths.size, 1.05), rays, np.tile(edges[:-1], depths.size), np.tile(edges[1:], depths.size)
    )
    assert np.all(np.isfinite(post)) and np.all(np.isfinite(inc))
    assert np.all((post >= 0) & (post <= 1))


def _profile(model, depth, edges):
    post, inc = model.cell_posteriors(_on_grid([depth]), [1.0], *_one_ray_cells(edges), method="direct")
    return post, inc, 0.5 * (edges[:-1] + edges[1:])


def test_shape_free_in_front_peak_skewed_behind_prior_far_behind():
    sigma = GaussianMixture.gaussian(0.5)
    model = PrismModel(error_model=sigma, focal_baseline=FB, voxel_size_m=0.01, p0=1e-4)
    edges = np.arange(2.0, 40.0, 0.01)
    depth = 10.0
    post, inc, centre = _profile(model, depth, edges)
    z_hat = FB / _on_grid([depth])[0]
    sigma_z = z_hat**2 * 0.5 / FB
    assert post[centre < z_hat - 5 * sigma_z].max() < 1e-6  # free in front
    assert abs(centre[np.argmax(post)] - z_hat) < 0.5 * sigma_z  # peak at the measurement
    behind = np.interp(z_hat + 1.5 * sigma_z, centre, post)
    ahead = np.interp(z_hat - 1.5 * sigma_z, centre, post)
    assert behind > 1.5 * ahead  # skewed to larger depth (Matthies & Shafer)
    peak = np.abs(centre - z_hat) < 10 * sigma_z  # with this tiny prior, P is the first-surface mass
    assert (post[peak] * centre[peak]).sum() / post[peak].sum() > z_hat
    prior = -np.expm1(-model.rate_per_m * 0.01)
    far = centre > model.influence_depth(_on_grid([depth]), [1.0])[0]
    assert far.any() and np.all(np.abs(inc[far]) < model.influence_epsilon)
    np.testing.assert_allclose(post[far], prior, rtol=2 * model.influence_epsilon)


def test_peak_flattens_with_distance_and_with_extra_noise():
    model = PrismModel(error_model=MIXTURE, focal_baseline=FB, voxel_size_m=0.1, p0=0.05)
    edges = np.arange(0.5, 60.0, 0.1)
    peaks = [_profile(model, depth, edges)[0].max() for depth in (2.0, 5.0, 10.0, 20.0)]
    assert all(b < a for a, b in zip(peaks, peaks[1:])), peaks
    wider = model.with_extra_noise(1.0)
    assert wider.error_model.sigmas[0] == pytest.approx(np.hypot(0.4, 1.0))
    assert model.with_extra_noise(1.0) is wider  # memoised: its tables are reused
    assert _profile(wider, 5.0, edges)[0].max() < peaks[1]


def test_influence_depth_bounds_every_later_cell():
    model = PrismModel(error_model=MIXTURE, focal_baseline=FB, voxel_size_m=0.1, p0=0.05)
    depths = np.array([1.0, 4.0, 15.0])
    disparity = _on_grid(depths)
    norm = np.array([1.0, 1.1, 1.25])
    influence = model.influence_depth(disparity, norm)
    assert np.all(influence > FB / disparity) and np.all(influence <= model.far_depth_m)
    rng = np.random.default_rng(5)
    rays = np.repeat(np.arange(3), 40)
    start = np.repeat(influence, 40) + rng.uniform(0, 5, 120)
    end = start + rng.uniform(0.01, 0.5, 120)
    _, inc = model.cell_posteriors(disparity, norm, rays, start, end, method="direct")
    assert np.all(np.abs(inc) < model.influence_epsilon)


def _simulate_disparities(rng, p0, n, voxel=0.1, near=0.5, far=60.0):
    """Disparities drawn from PRISM's own forward model with prior p0."""
    rate = -np.log1p(-p0) / voxel
    norm = rng.uniform(1.0, 1.2, n)
    depth = near + rng.exponential(1.0 / (rate * norm))
    true_disp = np.where(depth < far, FB / np.minimum(depth, far), rng.uniform(0, FB / far, n))
    return true_disp - MIXTURE.sample(n, rng), norm


def test_prior_estimated_from_likelihood_recovers_the_simulated_prior():
    rng = np.random.default_rng(11)
    disparity, norm = _simulate_disparities(rng, 0.03, 600)
    estimate = estimate_prior_from_likelihood(
        disparity,
        norm,
        error_model=MIXTURE,
        focal_baseline=FB,
        voxel_size_m=0.1,
        near_m=0.5,
        far_depth_m=60.0,
        max_rays=600,
    )
    assert estimate == pytest.approx(0.03, rel=0.2)


def test_prior_from_ground_truth_is_the_smoothed_occupancy_ratio():
    occupied = np.zeros(98, bool)
    occupied[:4] = True
    assert prior_from_ground_truth(occupied) == pytest.approx(5 / 100)
    with pytest.raises(PrismapInputError, match="bool"):
        prior_from_ground_truth(np.array([0.1, 0.2]))


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({}, "error_model"),
        ({"error_model": MIXTURE, "p0": 1.0}, "p0"),
        ({"error_model": MIXTURE, "near_m": 5.0, "far_depth_m": 2.0}, "near_m < far_depth_m"),
        ({"error_model": MIXTURE, "method": "fast"}, "method"),
        ({"error_model": MIXTURE, "voxel_size_m": -0.1}, "voxel_size_m"),
        ({"error_model": MIXTURE, "focal_baseline": 0.0}, "focal_baseline"),
    ],
)
def test_bad_parameters_are_named(params, message):
    params = {"focal_baseline": FB, **params}
    with pytest.raises(PrismapInputError, match=message):
        make_sensor_model("prism", **params)


def test_bad_rays_are_named():
    model = PrismModel(error_model=MIXTURE, focal_baseline=FB)
    with pytest.raises(PrismapInputError, match="finite"):
        model.cell_posteriors([np.nan], [1.0], [0], [1.0], [1.1])
    with pytest.raises(PrismapInputError, match="ray_norm"):
        model.cell_posteriors([5.0], [0.5], [0], [1.0], [1.1])
    with pytest.raises(PrismapInputError, match="ray_of_cell"):
        model.cell_posteriors([5.0], [1.0], [3], [1.0], [1.1])
    with pytest.raises(PrismapInputError, match="increasing"):
        prism_discrete_posteriors(5.0, [2.0, 1.0], MIXTURE, focal_baseline=FB)


def test_table_cache_evicts_least_recently_used_beyond_its_budget():
    model = PrismModel(error_model=MIXTURE, focal_baseline=FB, table_memory_mb=0.012)  # room for ~2 tables
    edges = np.linspace(0.5, 12.0, 60)
    cells = _one_ray_cells(edges)
    first = model.cell_posteriors(_on_grid([2.0]), [1.0], *cells)
    assert len(model._cache) == 1
    for depth in (3.0, 4.0, 5.0):
        model.cell_posteriors(_on_grid([depth]), [1.0], *cells)
        assert model._cache.nbytes <= model._cache.limit_bytes
    assert len(model._cache) < 4  # the 2 m table went first
    np.testing.assert_array_equal(model.cell_posteriors(_on_grid([2.0]), [1.0], *cells)[1], first[1])
    # the tables one call needs stay, even beyond the budget
    model.cell_posteriors(
        _on_grid([6.0, 7.0, 8.0, 9.0]),
        np.ones(4),
        np.repeat(np.arange(4), 59),
        np.tile(edges[:-1], 4),
        np.tile(edges[1:], 4),
    )
    assert len(model._cache) == 4
    with pytest.raises(PrismapInputError, match="table_memory_mb"):
        PrismModel(error_model=MIXTURE, focal_baseline=FB, table_memory_mb=0.0)


def test_an_eviction_compacts_the_room_in_place_unless_a_reader_holds_a_view_of_it(monkeypatch):
    """With no reader's view alive the kept tables move to the front of their room (the same memory); a view held
    across an eviction keeps its rows (a new room takes the kept tables). The values are the same either way."""
    edges = np.linspace(0.5, 12.0, 60)
    cells = _one_ray_cells(edges)
    depths = (2.0, 3.0, 4.0, 5.0, 2.5, 3.5)
    fresh = [
        PrismModel(error_model=MIXTURE, focal_baseline=FB).cell_posteriors(_on_grid([d]), [1.0], *cells) for d in depths
    ]
    counts = {"evict": 0, "compact": 0}

    def counted(name, function):
        def call(*args):
            counts[name] += 1
            return function(*args)

        return call

    monkeypatch.setattr(_prism_cache.TableCache, "_evict", counted("evict", _prism_cache.TableCache._evict))
    monkeypatch.setattr(_prism_cache._kernels_pack, "compact_rows", counted("compact", _kernels_pack.compact_rows))
    for hold in (False, True):
        counts.update(evict=0, compact=0)
        model = PrismModel(error_model=MIXTURE, focal_baseline=FB, table_memory_mb=0.012)  # room for ~2 tables
        held = model._tables_for(_on_grid([2.0, 3.0]), np.ones(2)) if hold else None  # a reader in another thread
        before = None if held is None else held.nodes.copy()
        for depth, want in zip(depths, fresh):
            np.testing.assert_array_equal(model.cell_posteriors(_on_grid([depth]), [1.0], *cells)[1], want[1])
            assert model._cache.nbytes <= model._cache.limit_bytes
        # held: the first eviction copies into a new room, which no reader views, so the later ones compact it
        assert counts["evict"] >= 2 and counts["compact"] == counts["evict"] - hold
        if hold:
            np.testing.assert_array_equal(held.nodes, before)


def test_threads_sharing_a_small_cache_that_evicts_get_the_serial_values():
    """Two threads call one model whose budget holds a few tables, so builds and evictions in one thread land
    while the other's look-up kernel reads its tables: every call gives what a model of its own gives."""
    rng = np.random.default_rng(11)
    edges = np.linspace(0.5, 30.0, 3000)
    calls = [(_on_grid(rng.uniform(1.0, 25.0, 4)), 1.0 + rng.uniform(0.0, 0.3, 4)) for _ in range(40)]
    cells = (np.repeat(np.arange(4), edges.size - 1), np.tile(edges[:-1], 4), np.tile(edges[1:], 4))
    fresh = [PrismModel(error_model=MIXTURE, focal_baseline=FB).cell_posteriors(d, n, *cells)[1] for d, n in calls]
    shared = PrismModel(error_model=MIXTURE, focal_baseline=FB, table_memory_mb=0.05)
    with ThreadPoolExecutor(2) as threads:
        got = list(threads.map(lambda call: shared.cell_posteriors(*call, *cells)[1], calls))
    assert shared._cache.builds > len(shared._cache)  # it evicted
    for want, have in zip(fresh, got):
        np.testing.assert_array_equal(have, want)


def test_a_pickled_model_arrives_with_its_budget_and_an_empty_cache_and_builds_the_same_tables():
    """What a Dask worker receives (``map_sequence`` scatters the run's model): its tables are rebuilt there, once."""
    model = PrismModel(error_model=MIXTURE, focal_baseline=FB, table_memory_mb=0.5)
    model._cache.floor_bytes = 1234  # as conditioned_sensor_model splits the floor among its class models
    edges = np.linspace(0.5, 12.0, 60)
    args = (_on_grid([2.0, 5.0]), [1.0, 1.1], np.repeat([0, 1], 59), np.tile(edges[:-1], 2), np.tile(edges[1:], 2))
    want = model.cell_posteriors(*args)
    assert len(model._cache) == 2
    twin = pickle.loads(pickle.dumps(model))
    assert repr(twin) == repr(model) and len(twin._cache) == 0 and twin._cache is not model._cache
    assert (twin._cache.budget_bytes, twin._cache.floor_bytes) == (model._cache.budget_bytes, 1234)
    for _ in range(2):
        for mine, theirs in zip(want, twin.cell_posteriors(*args)):
            np.testing.assert_array_equal(mine, theirs)
    assert (twin._cache.builds, twin._cache.hits) == (2, 2)


def test_calls_from_two_threads_under_a_thrashing_cache_equal_serial_calls():
    # The grid may call cell_posteriors from two threads at once. With room for about two tables every call
    # builds and evicts (new arrays, renumbered rows) while the other thread's call may be looking up; each
    # call must still read its own tables.
    from concurrent.futures import ThreadPoolExecutor

    edges = np.linspace(0.5, 12.0, 60)
    calls = [
        (_on_grid([d, d + 0.7]), [1.0, 1.2], np.repeat([0, 1], 59), np.tile(edges[:-1], 2), np.tile(edges[1:], 2))
        for d in np.linspace(1.0, 9.0, 12)
    ]
    want = [PrismModel(error_model=MIXTURE, focal_baseline=FB).cell_posteriors(*args)[1] for args in calls]
    model = PrismModel(error_model=MIXTURE, focal_baseline=FB, table_memory_mb=0.012)
    with ThreadPoolExecutor(2) as pool:
        got = list(pool.map(lambda args: model.cell_posteriors(*args)[1], calls * 3))
    for k, increment in enumerate(got):
        np.testing.assert_array_equal(increment, want[k % len(calls)])
    assert model._cache.builds > len(calls)  # it did thrash


def _fake_tables(keys):
    """Tables of 100 packed rows whose only content is their key (the cache never looks inside but for the
    offsets and packed row counts)."""
    nodes = np.repeat(np.asarray(keys, dtype=np.float32), 100)[:, None] * np.ones(
        _kernels_pack.TABLE_COLUMNS, np.float32
    )
    meta = np.repeat(np.asarray(keys, dtype=np.float64)[:, None], len(_kernels_pack.META_COLUMNS), axis=1)
    meta[:, _prism._OFFSET] = 100.0 * np.arange(len(keys))
    meta[:, _prism_cache._STORED] = 100.0
    return nodes, meta


@pytest.mark.parametrize(("budget_tables", "rebuilt"), [(None, False), (6, True)])
def test_auto_table_budget_keeps_a_frame_asked_for_in_chunks(budget_tables, rebuilt):
    node_bytes = _prism_cache.TableCache(None, 0).nodes.itemsize
    table_bytes = 100 * _kernels_pack.TABLE_COLUMNS * node_bytes + len(_kernels_pack.META_COLUMNS) * 8
    budget = None if budget_tables is None else budget_tables * table_bytes
    cache = _prism_cache.TableCache(budget, floor_bytes=table_bytes)
    frame = np.arange(10, dtype=np.int64)
    for _ in range(2):  # two frames seeing the same keys: the whole frame at once, then in two chunks
        for keys in (frame, frame[:5], frame[5:]):
            rows = cache.rows(keys, _fake_tables)
            assert np.array_equal(cache.meta[rows, 1], keys)  # each key's own table
            assert np.array_equal(cache.nodes[cache.meta[rows, _prism._OFFSET].astype(np.int64), 0], keys)
    assert cache.builds > 10 if rebuilt else (cache.builds == 10 and cache.hits == 30)
    if budget is None:  # two new frames of 10 other keys: over two frames' budget, the 15 oldest go (to EVICT_TO)
        cache.rows(frame + 10, _fake_tables)
        assert sorted(cache.keys) == list(range(20))  # exactly the budget: nothing goes
        cache.rows(frame + 20, _fake_tables)
        assert _prism_cache.EVICT_TO == 0.75 and cache.limit_bytes == 20 * table_bytes
        assert sorted(cache.keys) == list(range(15, 30)) and cache.nbytes <= 0.75 * cache.limit_bytes


def test_an_eviction_keeps_room_so_the_next_tables_are_not_copied_again():
    node_bytes = _prism_cache.TableCache(None, 0).nodes.itemsize
    table_bytes = 100 * _kernels_pack.TABLE_COLUMNS * node_bytes + len(_kernels_pack.META_COLUMNS) * 8
    cache = _prism_cache.TableCache(6 * table_bytes, floor_bytes=0)
    cache.rows(np.arange(6, dtype=np.int64), _fake_tables)
    cache.rows(np.arange(6, 9, dtype=np.int64), _fake_tables)  # over budget: the five oldest go, to EVICT_TO of it
    assert sorted(cache.keys) == list(range(5, 9))
    room = cache._node_room
    assert room.shape[0] >= 1.5 * cache.nodes.shape[0] and np.shares_memory(room, cache.nodes)
    before = cache.nodes
    rows = cache.rows(np.arange(9, 11, dtype=np.int64), _fake_tables)  # within budget, into the room: no copy
    assert cache._node_room is room and sorted(cache.keys) == list(range(5, 11))
    assert np.array_equal(cache.nodes[cache.meta[rows, _prism._OFFSET].astype(np.int64), 0], [9, 10])
    for key in cache.keys:  # every kept table's nodes moved with it
        row = int(np.flatnonzero(cache.keys == key)[0])
        start, length = (int(v) for v in cache.meta[row, [_prism._OFFSET, _prism_cache._STORED]])
        assert np.all(cache.nodes[start : start + length] == key)
    assert np.shares_memory(before, room)  # the reader's earlier view still holds its tables
    assert np.all(before[:100] == 5)


def test_table_room_is_writable_memory_of_its_own_behind_the_rows_asked_for():
    room = _prism_cache._room_for(100)
    rows = _prism_cache.ROOM_GROWTH * 100
    assert room.shape == (rows, _kernels_pack.TABLE_COLUMNS) and room.dtype == np.float32 and room.flags.writeable
    room[:] = 7.0
    owner = room
    while isinstance(owner, np.ndarray):
        owner = owner.base
    assert isinstance(owner.obj, mmap.mmap)  # not the heap: dropping it gives the pages back at once
    assert _prism_cache._room_for(0).shape == (0, _kernels_pack.TABLE_COLUMNS)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the resident set from /proc")
def test_table_room_rows_cost_memory_only_once_written():
    def resident():
        return _meminfo_bytes("VmRSS", "/proc/self/status")

    n_rows = (256 << 20) // (_prism_cache.ROOM_GROWTH * _prism_cache._ROW_BYTES)  # a 256 MiB room
    before = resident()
    room = _prism_cache._room_for(n_rows)
    assert resident() - before < 16 << 20
    room[: n_rows // 2] = 1.0  # 32 MiB written: resident
    assert resident() - before > 24 << 20


@pytest.mark.parametrize(("depth", "max_range"), [(3.0, 200.0), (15.0, 20.0)])
def test_rate_derivatives_of_the_evidence_match_finite_differences(depth, max_range):
    """The tables' Taylor terms in log(lambda) come from moments; check them on log Z, far term included."""

    model = PrismModel(error_model=MIXTURE, focal_baseline=FB, far_depth_m=max_range)
    shift = _on_grid([depth])[0]
    mixture = model._mixture()
    geometry = Geometry(model.near_m, max_range, FB, model._ku())
    log_far = float(model._log_far(shift))

    def march(lam):
        return _kernels_march.prism_march(shift, lam, log_far, 0.25, -7.0, 0.0, 4, geometry, mixture)

    lam, eps = 0.8, 1e-3
    _, log_c, log_d, log_z, log_far_w, _ = march(lam)
    if max_range == 20.0:
        assert log_far_w - log_z > -12  # the far term matters here
    total = np.logaddexp(log_c[-1], log_d[-1])
    first, second = _kernels_table._log_rate_derivatives(total, log_far_w, lam, max_range - model.near_m)
    lo, mid, hi = (march(lam * np.exp(k * eps))[3] for k in (-1, 0, 1))
    assert first == pytest.approx((hi - lo) / (2 * eps), rel=1e-5, abs=1e-6)
    assert second == pytest.approx((hi - 2 * mid + lo) / eps**2, rel=1e-3, abs=1e-3)


def test_table_chunks_give_the_same_cells_as_one_chunk(monkeypatch):
    """Chunk boundaries (look-up reuse restarts, near-underflow cells patched per chunk) change nothing."""

    rng = np.random.default_rng(8)
    depths = np.exp(rng.uniform(np.log(0.5), np.log(30.0), 12))
    edges = np.geomspace(0.1, 60.0, 200)
    rays = np.repeat(np.arange(depths.size), edges.size - 1)
    cells = (rays, np.tile(edges[:-1], depths.size), np.tile(edges[1:], depths.size))
    args = (_on_grid(depths), rng.uniform(1.0, 1.3, depths.size), *cells)
    model = PrismModel(error_model=MIXTURE, focal_baseline=FB)
    whole = model.cell_posteriors(*args)
    assert np.any(whole[1] < -600)  # cells near 0.1 m take the log-space path
    monkeypatch.setattr(_prism, "_CHUNK_CELLS", 7)
    chunked = model.cell_posteriors(*args)
    np.testing.assert_array_equal(chunked[0], whole[0])
    np.testing.assert_array_equal(chunked[1], whole[1])


def test_endpoint_asymptotic_of_the_evidence_matches_fine_quadrature_where_steep():
    """The coarse front of a table uses C = q g / (q g)'; check it against quadrature with fine panels."""

    model = PrismModel(error_model=MIXTURE, focal_baseline=FB)
    mixture = model._mixture()
    geometry = Geometry(0.1, model.far_depth_m, FB, model._ku())
    shift, lam = _on_grid([3.0])[0], model.rate_per_m
    derivatives = _kernels_table._log_qg_derivatives
    for depth in (0.3, 0.8, 1.5):  # measured at 3 m
        _, slope, curvature = derivatives(depth, lam, shift, geometry, mixture)
        (phi_hi, slope_hi, _), (phi_lo, slope_lo, _) = (
            derivatives(depth * (1 + e), lam, shift, geometry, mixture) for e in (1e-5, -1e-5)
        )
        assert (phi_hi - phi_lo) / (2e-5 * depth) == pytest.approx(slope, rel=1e-6)  # the slope is d phi / dz
        assert (slope_hi - slope_lo) / (2e-5 * depth) == pytest.approx(curvature, rel=1e-5)  # and d^2 phi / dz^2
        asymptotic, asymptotic_slope = _kernels_table._log_c_asymptotic(depth, lam, shift, geometry, mixture)
        x = _kernels_march.x_of_z(depth, lam, geometry.ku)
        hi, lo = (
            _kernels_table._log_c_asymptotic(
                _kernels_march.z_of_x(x + dx, lam, geometry.ku), lam, shift, geometry, mixture
            )[0]
            for dx in (1e-4, -1e-4)
        )
        assert (hi - lo) / 2e-4 == pytest.approx(asymptotic_slope, rel=1e-5)  # its slope is d log C / dx
        quadrature = _kernels_march.log_integral(0.1, depth, lam, shift, 0.01, geometry, mixture)
        correction = abs(curvature) / slope**2  # the first neglected term, relative
        assert asymptotic < -40 and abs(asymptotic - quadrature) < 2 * correction + 1e-4


def test_table_keys_match_numpy_unique_of_the_packed_keys():

    rng = np.random.default_rng(21)
    disparity = np.round(rng.uniform(0.5, 80.0, 5000), 1)  # repeated disparities: few distinct keys
    log_norm = np.log(rng.choice([1.0, 1.02, 1.3, 1.9], 5000))
    step = _prism._LAMBDA_STEP
    tag = rng.integers(0, 3, 5000) * _prism_cache.KEY_TAG_SPAN  # three models sharing a cache
    unique, inverse, delta = _kernels_pack.table_keys(disparity, log_norm, tag, 1 / 16, step, _prism._KEY_L_SPAN)
    key_l = np.floor(log_norm / step).astype(np.int64)  # bins [k, k + 1) step of log|r|, tables at their centres
    key = tag + np.rint(disparity * 16).astype(np.int64) * _prism._KEY_L_SPAN + key_l
    np.testing.assert_array_equal(unique[inverse], key)
    np.testing.assert_allclose(delta, log_norm - (key_l + 0.5) * step, rtol=0, atol=1e-15)
    assert np.abs(delta).max() <= 0.5 * step
    np.testing.assert_array_equal(np.sort(unique), np.unique(key))


def test_tables_built_in_threads_equal_tables_built_in_one(monkeypatch):
    depths = np.linspace(1.0, 30.0, 9)
    cells = _one_ray_cells(np.linspace(0.5, 40.0, 80))
    rays = np.repeat(np.arange(depths.size), cells[1].size)
    args = (
        _on_grid(depths),
        np.linspace(1.0, 1.3, depths.size),
        rays,
        np.tile(cells[1], depths.size),
        np.tile(cells[2], depths.size),
    )
    monkeypatch.setattr(_prism, "_BUILD_THREADS", 1)
    serial = PrismModel(error_model=MIXTURE, focal_baseline=FB).cell_posteriors(*args)
    monkeypatch.setattr(_prism, "_BUILD_THREADS", 2)
    threaded = PrismModel(error_model=MIXTURE, focal_baseline=FB)
    np.testing.assert_array_equal(threaded.cell_posteriors(*args)[1], serial[1])
    assert threaded._cache.builds == depths.size


def test_vectorised_exp_and_log_match_numpy_over_the_whole_range():
    """``exp_into``/``log_into`` (PRISM's cell update) against numpy: 1e-13 relative where the result is normal,
    subnormal results to their spacing, and the special values (0, inf, NaN, underflow, overflow) exactly."""
    rng = np.random.default_rng(11)
    edges = [
        -np.inf,
        -800.0,
        -745.2,
        -745.1332191019412,
        -745.13,
        -708.4,
        -708.3964185322641,
        -708.39,
        -0.0,
        0.0,
        1e-300,
        709.78,
        709.782712893384,
        709.7827128933841,
        710.0,
        np.inf,
        np.nan,
    ]
    x = np.concatenate([rng.uniform(-760.0, 720.0, 200_000), rng.uniform(-1.0, 1.0, 20_000), edges])
    got = np.empty_like(x)
    _kernels_math.exp_into(x, got, x.size)
    with np.errstate(over="ignore", under="ignore"):
        want = np.exp(x)
    normal = np.isfinite(want) & (want >= np.finfo(np.float64).tiny)
    assert np.max(np.abs(got[normal] / want[normal] - 1.0)) <= 1e-13
    subnormal = ~normal & np.isfinite(want)
    assert subnormal.sum() > 100 and np.max(np.abs(got[subnormal] - want[subnormal])) <= 2e-323
    np.testing.assert_array_equal(got[~np.isfinite(want)], want[~np.isfinite(want)])
    assert got[x < -745.14].max() == 0.0 and np.all(got[x > 709.79] == np.inf)

    y = np.concatenate(
        [
            np.exp(rng.uniform(np.log(5e-324), np.log(1.79e308), 200_000)),
            1.0 + rng.normal(0, 1e-9, 1000),
            [
                5e-324,
                1e-310,
                np.finfo(np.float64).tiny,
                np.finfo(np.float64).max,
                1.0,
                0.5,
                2.0,
                0.0,
                -0.0,
                -1.0,
                np.inf,
                -np.inf,
                np.nan,
            ],
        ]
    )
    got = np.empty_like(y)
    _kernels_math.log_into(y, got, y.size)
    with np.errstate(divide="ignore", invalid="ignore"):
        want = np.log(y)
    finite = np.isfinite(want) & (want != 0.0)
    assert np.max(np.abs(got[finite] / want[finite] - 1.0)) <= 1e-13
    np.testing.assert_array_equal(got[~finite], want[~finite])
    partial = np.full(4, -7.0)
    _kernels_math.exp_into(np.zeros(4), partial, 2)  # only the first n elements are written
    np.testing.assert_array_equal(partial, [1.0, 1.0, -7.0, -7.0])


def test_fast_log1mexp_matches_numpy_on_both_sides_of_its_series_switch():
    """On its domain ``t <= -ln 2``, relative error below 2e-12: the series' truncation (u^3 / 4 at u = 1e-4) below
    the switch, the rounding of ``1 - u`` over ``u`` just above it."""
    switch = np.log(1e-4)
    t = np.concatenate(
        [-np.geomspace(np.log(2.0), 800.0, 400), np.nextafter(switch, [-np.inf, np.inf]), [switch, -745.2]]
    )
    got = np.array([_kernels_math.fast_log1mexp(v) for v in t])
    np.testing.assert_allclose(got, np.log1p(-np.exp(t)), rtol=2e-12, atol=0)  # exact enough for t <= -ln 2
    assert _kernels_math.fast_log1mexp(-np.inf) == 0.0


def test_cell_prior_matches_expm1_on_both_sides_of_its_series_switch():
    x = np.concatenate([np.geomspace(1e-12, 0.2, 200), np.nextafter(0.2, [0.0, 1.0]), np.geomspace(0.2, 60.0, 200)])
    p, q = np.array([_kernels_lookup._cell_prior(v) for v in x]).T
    np.testing.assert_allclose(p, -np.expm1(-x), rtol=1e-11, atol=0)
    np.testing.assert_allclose(q, np.exp(-x), rtol=1e-11, atol=0)


def test_log_sums_skip_underflowing_exps_without_changing_a_bit():
    """logaddexp and the streaming log-sum-exp skip exp where it underflows (libm's slow path); the results
    equal the plain formulas bit for bit on both sides of the cuts (exp subnormal below -708.4, 0 below
    -745.13)."""
    a = np.array([0.0, 1.5, -3.0, 700.0, -40.0])
    gaps = np.concatenate(
        [[0.0, -1.0, -37.0, -700.0], np.linspace(-708.0, -709.0, 9), [-744.0, -745.1, -745.2, -746.0, -1e4, -np.inf]]
    )
    for x in a:
        for gap in gaps:
            b = x + gap
            assert _kernels_math.logaddexp(x, b) == x + np.log1p(np.exp(b - x))
            assert _kernels_math.logaddexp(b, x) == _kernels_math.logaddexp(x, b)
    # a narrow component thousands of sigmas away from u contributes nothing, exactly as before
    log_wn = np.log([0.8, 0.2]) - np.log([0.3, 10.0]) - 0.5 * np.log(2 * np.pi)
    means, sigmas = np.array([0.0, -2.0]), np.array([0.3, 10.0])
    for u in (0.1, 5.0, 40.0, 400.0):
        t = (u - 1.0 - means) / sigmas
        v = log_wn - 0.5 * t * t
        best = v.max()
        plain = best + np.log(np.sum(np.exp(v - best)))
        np.testing.assert_allclose(
            _kernels_march.log_likelihood(u, 1.0, Mixture(log_wn, means, sigmas)), plain, rtol=1e-15
        )


def test_march_blocks_match_the_one_panel_rule_and_the_tail_bound():
    """_log_panel_block (6 points, 16 panels at once) against _log_panel_moments (8 points, one panel) on a street
    table's fine panels (x-width 0.5) and broad ones (x-width 8), and _log_sup_tail_block against _log_sup_tail."""
    model = make_sensor_model(
        "prism", focal_baseline=KITTI_FB, error_model=STREET, voxel_size_m=0.2, p0=0.05, near_m=1.5
    )
    mixture = model._mixture()
    means, sigmas = mixture.means, mixture.sigmas
    lam, ku, shift = model.rate_per_m * 1.1, model._ku(), KITTI_FB / 12.0
    geometry = Geometry(1.5, 80.0, KITTI_FB, ku)
    for width in (0.5, 8.0):
        z = np.array(
            [_kernels_march.z_of_x(x, lam, ku) for x in _kernels_march.x_of_z(1.5, lam, ku) + width * np.arange(40)]
        )
        out = np.full((z.size, 3), np.nan)
        sup = np.full(z.size, np.nan)
        scratch = np.empty((means.size + 5, _kernels_march._MARCH_GL * _kernels_march._MARCH_BLOCK))
        for first in range(1, z.size, _kernels_march._MARCH_BLOCK):
            count = min(_kernels_march._MARCH_BLOCK, z.size - first)
            _kernels_march._log_panel_block(z, first, count, lam, shift, geometry, mixture, 1 / sigmas, out, scratch)
            _kernels_march._log_sup_tail_block(z, first, count, shift, geometry, mixture, 1 / sigmas, sup, scratch)
        ref = np.array(
            [_kernels_march._log_panel_moments(a, b, lam, shift, geometry, mixture) for a, b in zip(z[:-1], z[1:])]
        )
        np.testing.assert_allclose(out[1:], ref, rtol=0, atol=1e-8 if width < 1 else 1e-6)
        sup_ref = [_kernels_march._log_sup_tail(v, shift, geometry, mixture) for v in z[1:]]
        np.testing.assert_allclose(sup[1:], sup_ref, rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("step", [1, -1])
def test_log_cumsum_block_matches_a_running_logaddexp_through_minus_inf_and_underflow(step):
    """Cumulative log-sum-exp of 16 rows at a time, forward and backward, against numpy's running logaddexp: terms
    spread over 60 nats (the linear path), with -inf terms and a -inf start, and over 2,000 nats (a block
    that would underflow: the row-by-row path)."""
    rng = np.random.default_rng(7)
    for spread in (60.0, 2000.0):
        terms = rng.uniform(-spread, 0.0, (41, 3))
        terms[5, 1] = terms[17, 0] = -np.inf
        out = np.full((41, 3), np.nan)
        if step > 0:
            out[0] = [-np.inf, -3.0, 1.0]
            for first in range(1, 41, 16):
                _kernels_march._log_cumsum_block(terms, out, first, min(16, 41 - first), 1, np.empty(48))
            ref = np.logaddexp.accumulate(np.vstack([out[:1], terms[1:]]), axis=0)
        else:
            out[40] = [-np.inf, -3.0, 1.0]
            for last in range(39, -1, -16):
                _kernels_march._log_cumsum_block(terms, out, last, min(16, last + 1), -1, np.empty(48))
            ref = np.logaddexp.accumulate(np.vstack([out[40:], terms[40:0:-1]]), axis=0)[::-1]
        np.testing.assert_allclose(out, ref, rtol=1e-14, atol=1e-13)
