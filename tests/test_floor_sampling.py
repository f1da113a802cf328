"""Ray mode's floor sampling: levels, bands and weights against brute force, casts from a start depth, the model's
floor depth against its own cell increments, and maps whose sums and counts keep their expectation."""

from dataclasses import replace

import numpy as np
import pytest

from prismap.camera import StereoCamera, disparity_batch, integrate_disparity
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.grid import OccupancyMap, _accumulator, image_levels, pack_keys
from prismap.grid._floor_sampling import MAX_BAND, cell_weights, floor_plan
from prismap.sensor_models import ConditionedModel, make_sensor_model
from support import assert_same_map, planes_frame

STREET = GaussianMixture(
    [0.9, 0.1], [0.02, 0.1], [0.25, 1.5], failure_weight=0.08, search_range_px=(0.0, 64.0)
)  # SGBM-like: a narrow core, a wide component and matcher failures


def prism(mixture=STREET, **params):
    return make_sensor_model(
        "prism", focal_baseline=525.0 * 0.1, doffs_px=0.0, voxel_size_m=0.1, p0=0.05, error_model=mixture, **params
    )


def trailing_zeros(n):
    return MAX_BAND if n == 0 else min((n & -n).bit_length() - 1, MAX_BAND)


def test_image_levels_are_the_trailing_zero_bits_of_row_and_column():
    levels = image_levels(37, 53, 0.01)
    expected = [min(trailing_zeros(r), trailing_zeros(c)) for r in range(37) for c in range(53)]
    np.testing.assert_array_equal(levels.level, expected)
    for k in range(MAX_BAND + 1):  # level >= k: every 2^k-th row and column
        assert np.sum(levels.level >= k) == len(range(0, 37, 1 << k)) * len(range(0, 53, 1 << k))
    line = image_levels(1, 40, 0.01)  # one row: every 2^k-th ray along it, a share 2^-k
    assert line.base == 2 and line.level.tolist() == [trailing_zeros(c) for c in range(40)]
    assert image_levels(37, 53, 0.01).base == 4
    with pytest.raises(PrismapInputError, match="spacing_rad"):
        image_levels(4, 4, 0.0)


def test_cell_weights_are_four_to_the_band_before_the_floor_and_one_after():
    rng = np.random.default_rng(0)
    t_out = rng.uniform(0.01, 40.0, 2000)
    ray_of_cell = rng.integers(0, 50, 2000)
    floor_end = rng.uniform(0.0, 40.0, 50)
    band_depth = 24.0
    got = cell_weights(ray_of_cell, t_out, floor_end, band_depth, 4)
    for z, r, w in zip(t_out, ray_of_cell, got):
        band = max(j for j in range(MAX_BAND + 1) if j == 0 or z <= band_depth / 2**j)
        assert w == (4.0**band if z <= floor_end[r] else 1.0)


def test_each_ray_casts_exactly_the_floor_bands_of_its_level():
    rng = np.random.default_rng(1)
    levels = image_levels(16, 16, 0.002)
    floor_end = rng.uniform(0.0, 60.0, 256)
    t_start, band_depth = floor_plan(floor_end, levels, 0.2, 4)
    assert band_depth == pytest.approx(0.2 / (4 * 0.002))
    depths = np.linspace(0.01, 60.0, 3000)
    for r in range(256):
        sampled = depths <= floor_end[r]
        band = np.zeros(depths.size, dtype=int)
        for j in range(1, MAX_BAND + 1):
            band[depths <= band_depth / 2**j] = j
        cast = depths > t_start[r]
        # before its floor a ray casts the cells of the bands up to its level; after it, every cell
        np.testing.assert_array_equal(cast[sampled], band[sampled] <= levels.level[r])
        assert cast[~sampled].all()


def test_a_weighted_scatter_counts_each_cell_its_weight():
    acc = _accumulator.new_accumulator((2, 2, 2))
    rows = _accumulator.cast_into(
        acc, np.zeros(3), np.array([[1.0, 0.3, 0.2]]), np.zeros(1), np.array([2.0]), np.array([False]), 0.1
    )[1]
    increment = np.linspace(-2.0, 1.0, rows.size)
    weight = np.where(np.arange(rows.size) % 2 == 0, 16.0, 1.0).astype(np.float32)
    _accumulator.scatter(acc, rows, increment, weight)
    _accumulator.scatter(acc, rows, increment)
    flat = acc.payload["acc"][: len(acc)].reshape(-1, 4)[rows]
    np.testing.assert_allclose(flat[:, 0], (weight + 1) * increment.astype(np.float32), rtol=1e-6)
    np.testing.assert_array_equal(flat[:, 1], weight + 1)
    np.testing.assert_allclose(flat[:, 2], increment, rtol=1e-6)


def test_cells_before_the_floor_depth_carry_the_floor_increment_of_their_length():
    model = prism()
    disparity = np.array([2.0, 5.0, 12.0, 30.0])  # 26, 10.5, 4.4 and 1.75 m
    norm = np.array([1.0, 1.1, 1.2, 1.3])
    floor = model.floor_depth(disparity, norm)
    assert np.all(floor > 0.2) and np.all(floor < model.focal_baseline / disparity)
    length = 0.05
    for r in range(disparity.size):
        early = np.linspace(0.6 * floor[r], floor[r] - length, 5)  # cells of one length, all ending before the floor
        late = np.array([model.focal_baseline / disparity[r] - length])  # one ending at the measurement
        start = np.concatenate([early, late])
        _, inc = model.cell_posteriors(disparity[[r]], norm[[r]], np.zeros(6, dtype=int), start, start + length)
        np.testing.assert_allclose(inc[:5], inc[0], rtol=1e-9)
        assert abs(inc[5] - inc[0]) > 1e-3


def test_a_conditioned_model_takes_each_class_models_floor_depth():
    mixtures = [STREET, GaussianMixture([1.0], [0.0], [0.6], failure_weight=0.2, search_range_px=(0.0, 64.0))]
    plain, *classes = [prism(m) for m in (STREET, *mixtures)]
    model = ConditionedModel(plain, tuple(classes))
    rng = np.random.default_rng(3)
    disparity = rng.uniform(1.0, 40.0, 200)
    norm = rng.uniform(1.0, 1.3, 200)
    ray_class = rng.integers(-1, 2, 200).astype(np.int32)
    got = model.floor_depth(disparity, norm, ray_class=ray_class)
    for k, sub in enumerate((plain, *classes), start=-1):
        mine = ray_class == k
        np.testing.assert_allclose(got[mine], sub.floor_depth(disparity[mine], norm[mine]), rtol=1e-12)


def model_cache_keys(model):
    """Keys the model's table cache has been asked for (found or not)."""
    cache = getattr(model, "plain", model)._cache
    return cache.hits + cache.builds


def test_influence_and_floor_depths_are_the_two_methods_of_one_look_up():
    """Ray mode's one call gives each ray's ``influence_depth`` and ``floor_depth`` as the two methods do, for a PRISM
    model (with its overhang stretch), a conditioned one (classes, and none), and no floor where the look-up has none;
    it looks the rays' tables up once where the two methods look them up twice."""
    mixtures = [STREET, GaussianMixture([1.0], [0.0], [0.6], failure_weight=0.2, search_range_px=(0.0, 64.0))]
    plain, *classes = [prism(m, overhang_fraction=0.5) for m in (STREET, *mixtures)]
    conditioned = ConditionedModel(plain, tuple(classes))
    rng = np.random.default_rng(5)
    disparity, norm = rng.uniform(1.0, 40.0, 300), rng.uniform(1.0, 1.3, 300)
    overhang = rng.uniform(0.0, 0.2, 300)
    ray_class = rng.integers(-1, 2, 300).astype(np.int32)
    for model, kwargs in [
        (plain, {"voxel_overhang_m": overhang}),
        (conditioned, {"ray_class": ray_class, "voxel_overhang_m": overhang}),
        (conditioned, {"voxel_overhang_m": overhang}),
    ]:
        searched = model_cache_keys(model)
        influence, floor = model.influence_and_floor_depths(disparity, norm, **kwargs)
        one_call = model_cache_keys(model) - searched
        np.testing.assert_array_equal(influence, model.influence_depth(disparity, norm, **kwargs))
        np.testing.assert_array_equal(floor, model.floor_depth(disparity, norm, **kwargs))
        assert model_cache_keys(model) - searched == 3 * one_call > 0  # the two methods search twice as many keys
        assert np.any(floor > 0) and np.any(influence > floor)
    direct = prism(method="direct")
    influence, floor = direct.influence_and_floor_depths(disparity[:5], norm[:5])
    assert floor is None and direct.floor_depth(disparity[:5], norm[:5]) is None
    np.testing.assert_array_equal(influence, direct.influence_depth(disparity[:5], norm[:5]))


def mapped_both_ways(monkeypatch, camera, pose, disparity):
    """``{floor_rays: (map, cells cast, weighted cells)}`` of one frame mapped exactly (0) and sampled (4)."""
    out = {}
    for floor_rays in (0, 4):
        cast, weighted = [], []
        real = _accumulator.scatter

        def counting(acc, rows, inc, weight=None, real=real, cast=cast, weighted=weighted):
            cast.append(rows.size)
            weighted.append(rows.size if weight is None else float(weight.sum()))
            real(acc, rows, inc, weight)

        monkeypatch.setattr(_accumulator, "scatter", counting)
        grid = OccupancyMap(0.1, p0=0.05)
        integrate_disparity(grid, disparity, camera, pose, prism(), max_range_m=12.0, floor_rays=floor_rays)
        out[floor_rays] = grid, sum(cast), sum(weighted)
    return out


def test_sampled_and_exact_ray_maps_agree_and_keep_the_expected_counts(monkeypatch):
    camera, pose, depth = planes_frame(320, 240)
    both = mapped_both_ways(monkeypatch, camera, pose, camera.focal_baseline / depth)
    (exact, cells, _), (sampled, sampled_cells, weighted) = both[0], both[4]
    assert sampled_cells < 0.8 * cells and weighted == pytest.approx(cells, rel=0.02)  # fewer, weighed back
    keys_e, log_e, _ = exact.known_voxels()
    keys_s, log_s, _ = sampled.known_voxels()
    seen = pack_keys(keys_s)
    common = np.isin(pack_keys(keys_e), seen)
    assert np.isin(seen, pack_keys(keys_e)).all() and common.mean() > 0.999  # a few floor voxels no sampled ray crossed
    at = np.argsort(seen)[np.searchsorted(np.sort(seen), pack_keys(keys_e)[common])]
    diff = np.abs(log_s[at] - log_e[common])
    assert np.mean(diff) < 1e-3 and np.quantile(diff, 0.99) < 0.01 and diff.max() < 0.2  # 6e-5, 1.4e-3, 0.058
    np.testing.assert_array_equal(log_s[at] > 0, log_e[common] > 0)  # the same voxels called occupied


def test_a_single_line_of_rays_weighs_its_sampled_cells_by_powers_of_two(monkeypatch):
    camera, pose, depth = planes_frame(1280, 240)
    line = StereoCamera(camera.focal_px, camera.cx_px, 0.0, camera.baseline_m, width=1280, height=1)
    both = mapped_both_ways(monkeypatch, line, pose, line.focal_baseline / depth[120:121])
    (_, cells, _), (_, sampled_cells, weighted) = both[0], both[4]
    assert sampled_cells < 0.9 * cells and weighted == pytest.approx(cells, rel=0.02)


def test_batches_without_levels_and_a_disabled_sampling_give_the_exact_map():
    camera, pose, depth = planes_frame(160, 120)
    disparity = camera.focal_baseline / depth
    model = prism()
    batch = disparity_batch(disparity, camera, pose)
    assert batch.levels is not None
    grids = []
    for levels in (batch.levels, None):
        grid = OccupancyMap(0.1, p0=0.05)
        grid.integrate(replace(batch, levels=levels), model, max_range_m=12.0, floor_rays=0 if levels else 4)
        grids.append(grid)
    assert_same_map(*grids)
