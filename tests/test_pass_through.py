"""PRISM's pass-through: the thinned odds by brute force, the model against them, the ground truth's ratio."""

import itertools

import numpy as np
import pytest

from prismap import sim
from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import PrismModel, prism_discrete_posteriors
from prismap.sensor_models._prism import TABLE_TOLERANCE

FB = 61.5
MIXTURE = GaussianMixture([0.85, 0.15], [0.05, -0.3], [0.4, 2.5])


def _logit(p):
    return np.log(p) - np.log1p(-p)


def _brute_force(d_hat, edges, p0, m, cell):
    """Enumerate the other cells (1-D model: independent, prior p0, the first occupied one stops the ray)
    and the queried cell's occupancy and whether it stops the ray (with probability 1 - m when occupied)."""
    u = FB / edges
    lik = (MIXTURE.cdf(u[:-1] - d_hat) - MIXTURE.cdf(u[1:] - d_hat)) / (u[:-1] - u[1:])
    lik_far = (MIXTURE.cdf(u[-1] - d_hat) - MIXTURE.cdf(-d_hat)) / u[-1]
    n = edges.size - 1
    joint, total = 0.0, 0.0
    for others in itertools.product((0, 1), repeat=n - 1):
        stops = np.insert(np.array(others), cell, 0)
        weight_others = np.prod(np.where(np.delete(stops, cell) == 1, p0, 1 - p0))
        for occupied, stop, weight_cell in ((0, 0, 1 - p0), (1, 0, p0 * m), (1, 1, p0 * (1 - m))):
            stops[cell] = stop
            first = np.flatnonzero(stops)
            weight = weight_others * weight_cell * (lik[first[0]] if first.size else lik_far)
            total += weight
            joint += weight * occupied
    return joint / total


@pytest.mark.parametrize(("depth", "p0", "m"), [(2.2, 0.2, 0.1), (3.1, 0.05, 0.4)])
def test_pass_through_odds_match_brute_force(depth, p0, m):
    """Posterior odds = prior odds x (m + (1 - m) R), R the 1-D model's likelihood ratio of the cell."""
    edges = 1.0 + 0.5 * np.arange(8)
    d_hat = FB / depth
    one_d = prism_discrete_posteriors(d_hat, edges, MIXTURE, focal_baseline=FB, p0=p0)
    ratio = np.exp(_logit(one_d) - _logit(p0))
    odds = p0 / (1 - p0) * (m + (1 - m) * ratio)
    expected = [_brute_force(d_hat, edges, p0, m, cell) for cell in range(edges.size - 1)]
    np.testing.assert_allclose(odds / (1 + odds), expected, rtol=0, atol=1e-12)


def _cells(n_rays, rng, depths=None):
    """160 random cells a ray, from 0.2 to 40 m (or, given each ray's true depth z, to 2.5 z + 1 m)."""
    starts, ends, rays = [], [], []
    for r in range(n_rays):
        edges = np.sort(rng.uniform(0.2, 40.0 if depths is None else 2.5 * depths[r] + 1.0, 161))
        starts.append(edges[:-1])
        ends.append(edges[1:])
        rays.append(np.full(160, r))
    return np.concatenate(rays), np.concatenate(starts), np.concatenate(ends)


@pytest.mark.parametrize("method", ["direct", "table"])
def test_model_thins_the_one_dimensional_likelihood_ratio(method):
    rng = np.random.default_rng(11)
    p0, m, voxel = 0.08, 0.3, 0.1
    disparity = np.round(FB / np.exp(rng.uniform(np.log(0.5), np.log(30.0), 12)) * 16) / 16
    norm = rng.uniform(1.0, 1.3, disparity.size)
    cells = _cells(disparity.size, rng)
    model = PrismModel(error_model=MIXTURE, focal_baseline=FB, voxel_size_m=voxel, p0=p0, pass_through=m, method=method)
    post, inc = model.cell_posteriors(disparity, norm, *cells)
    one_d = PrismModel(error_model=MIXTURE, focal_baseline=FB, voxel_size_m=voxel, p0=p0, method=method)
    _, inc_1d = one_d.cell_posteriors(disparity, norm, *cells)
    rays, start, end = cells
    length = model.rate_per_m * norm[rays] * (np.minimum(end, model.far_depth_m) - np.maximum(start, model.near_m))
    expected = np.logaddexp(np.log(m), np.log1p(-m) + inc_1d)
    changed = inc_1d != 0
    assert changed.sum() >= 300
    np.testing.assert_allclose(inc[changed], expected[changed], rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(inc[~changed], 0.0)
    np.testing.assert_allclose(post, 1 / (1 + np.exp(-(_logit(-np.expm1(-length)) + inc))), rtol=1e-9, atol=1e-12)
    # free evidence is bounded by log(m) a ray, and far in front of the measurement it reaches it
    assert inc.min() >= np.log(m) - 1e-12
    assert inc.min() < np.log(m) + 1e-3


def test_table_agrees_with_direct_with_pass_through():
    rng = np.random.default_rng(5)
    depths = np.exp(rng.uniform(np.log(0.4), np.log(40.0), 20))
    disparity = np.round(FB / depths * 16) / 16
    norm = rng.uniform(1.0, 1.3, depths.size)
    cells = _cells(depths.size, rng, depths)
    model = PrismModel(error_model=MIXTURE, focal_baseline=FB, voxel_size_m=0.1, p0=0.05, pass_through=0.2)
    p_table, inc_table = model.cell_posteriors(disparity, norm, *cells)
    p_direct, inc_direct = model.cell_posteriors(disparity, norm, *cells, method="direct")
    moderate = np.abs(inc_direct) <= TABLE_TOLERANCE["large"]
    err = np.abs(inc_table - inc_direct)
    assert np.all(err[moderate] <= TABLE_TOLERANCE["abs"] + TABLE_TOLERANCE["rel"] * np.abs(inc_direct[moderate]))
    assert np.all(err[~moderate] <= TABLE_TOLERANCE["large_rel"] * np.abs(inc_direct[~moderate]))
    assert np.abs(p_table - p_direct).max() <= TABLE_TOLERANCE["posterior"]


def test_underflowing_cells_keep_the_bound():
    """Cells far in front of a sharp measurement: log C/Z below -600 (the log-space path)."""
    sharp = GaussianMixture.gaussian(0.05)
    model = PrismModel(error_model=sharp, focal_baseline=FB, voxel_size_m=0.1, p0=0.05, pass_through=0.1)
    rays, start, end = np.zeros(3, np.int64), np.array([0.2, 1.0, 4.0]), np.array([1.0, 4.0, 7.0])
    for method in ("table", "direct"):
        post, inc = model.cell_posteriors([FB / 10.0], [1.0], rays, start, end, method=method)
        prior = -np.expm1(-model.rate_per_m * (end - start))
        np.testing.assert_allclose(inc, np.log(0.1), rtol=1e-9)
        np.testing.assert_allclose(post, 0.1 * prior / (0.1 * prior + 1 - prior), rtol=1e-9)


def test_zero_pass_through_is_the_one_dimensional_model():
    rng = np.random.default_rng(2)
    cells = _cells(5, rng)
    disparity, norm = np.array([30.0, 12.5, 4.0, 2.0, 0.75]), np.ones(5)
    base = PrismModel(error_model=MIXTURE, focal_baseline=FB, voxel_size_m=0.1, p0=0.05)
    zero = PrismModel(error_model=MIXTURE, focal_baseline=FB, voxel_size_m=0.1, p0=0.05, pass_through=0.0)
    for got, want in zip(zero.cell_posteriors(disparity, norm, *cells), base.cell_posteriors(disparity, norm, *cells)):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("bad", [1.0, -0.1, True, "0.1", np.nan])
def test_bad_pass_through_is_named(bad):
    with pytest.raises(PrismapInputError, match="pass_through"):
        PrismModel(error_model=MIXTURE, focal_baseline=FB, voxel_size_m=0.1, p0=0.05, pass_through=bad)


# ------------------------------------------------------------------ the ground truth's ratio
CAMERA = StereoCamera(40.0, 7.5, 7.5, 0.1, width=16, height=16)
VOXEL = 0.1


def _frame(scene):
    return scene.render(CAMERA, np.eye(4), noise_sigma=0.0)


def _reference_passes(scene, frame):
    """(H * W,) passes of each ray by dense sampling along it instead of the voxel traversal; the overhang of a
    wall seen head-on."""
    depth = frame.extras["depth_m"]
    rays = CAMERA.pixel_rays(depth.shape).reshape(-1, 3)
    depth = depth.reshape(-1)
    key_lo = np.floor(scene.box_lo / VOXEL).astype(int)
    key_hi = np.floor(scene.box_hi / VOXEL).astype(int)
    passes = np.zeros(depth.size, dtype=np.int64)
    for index, (ray, z) in enumerate(zip(rays, depth)):
        norm = np.linalg.norm(ray)
        overhang = VOXEL / (1.0 / norm)  # normal (0, 0, 1): |n|_1 = 1, cos = 1/|r|
        samples = np.floor(np.arange(0.0, z, 1e-4)[:, None] * ray / VOXEL).astype(np.int64)
        changes = np.flatnonzero(np.any(np.diff(samples, axis=0) != 0, axis=1)) + 1
        for key in samples[np.concatenate(([0], changes))]:  # the voxels in the order the ray meets them
            exit_t = min(((key[a] + (ray[a] > 0)) * VOXEL) / ray[a] for a in range(3) if ray[a] != 0)
            occupied = np.any(np.all((key >= key_lo) & (key <= key_hi), axis=1))
            passes[index] += occupied and exit_t < z - overhang / norm
    return passes


def _reference_ratio(scene, frame):
    passes = _reference_passes(scene, frame)
    return passes.sum() / (passes.sum() + passes.size)


def _jeffreys(passes):
    """The ratio's estimate from each ray's passes: the posterior mean under Jeffreys' prior."""
    return (passes.sum() + 0.5) / (passes.sum() + passes.size + 1.0)


WALL = ([-9.0, -9.0, 3.05], [9.0, 9.0, 3.5])
RAIL = ([-9.0, 0.012, 1.512], [9.0, 0.03, 1.53])


def _rail_scene():
    """A wall at 3.05 m and a thin rail in front of it that fills a voxel row only partly."""
    return sim.Scene3D.from_boxes([WALL[0], RAIL[0]], [WALL[1], RAIL[1]])


def test_pass_through_ratio_of_a_thin_rail_matches_dense_sampling():
    scene = _rail_scene()
    frame = _frame(scene)
    got = scene.pass_through_ratio([frame], VOXEL)
    assert 0 < got < 0.2
    assert got == pytest.approx(_reference_ratio(scene, frame), abs=1e-12)
    alone = sim.Scene3D.from_boxes([WALL[0]], [WALL[1]])
    assert alone.pass_through_ratio([_frame(alone)], VOXEL) == 0.0  # a wall seen head-on: every ray stops on it


def test_pass_through_ratio_bad_input_is_named():
    scene = sim.Scene3D.from_boxes([[-9.0, -9.0, 3.05]], [[9.0, 9.0, 3.5]])
    frame = _frame(scene)
    with pytest.raises(PrismapInputError, match="subsample"):
        scene.pass_through_ratio([frame], VOXEL, subsample=0)
    with pytest.raises(PrismapInputError, match="no ray"):
        scene.pass_through_ratio([frame], VOXEL, max_depth_m=1.0)


def test_pass_through_ratio_by_class_matches_dense_sampling_of_each_class():
    """Rows through the rail's silhouette in one class, the others in another, one column without a class."""
    scene = _rail_scene()
    frame = _frame(scene)
    passes = _reference_passes(scene, frame).reshape(16, 16)
    labels = np.where(passes.any(axis=1)[:, None], 0, 1) * np.ones((1, 16), dtype=np.int64)
    labels[:, 3] = -1
    got = scene.pass_through_ratio([frame], VOXEL, ray_classes=[labels], n_classes=3)
    for k in (0, 1):
        assert got[k] == pytest.approx(_jeffreys(passes[labels == k]), abs=1e-12)
    assert got[0] > 0.3 and got[1] < 0.01  # the passes are all on the rows that cross the rail
    assert got[2] == pytest.approx(_reference_ratio(scene, frame), abs=1e-12)  # no ray: the whole ratio
    alone = sim.Scene3D.from_boxes([WALL[0]], [WALL[1]])  # no ray passes: Jeffreys' half a pass in 257
    only = alone.pass_through_ratio([_frame(alone)], VOXEL, ray_classes=[np.zeros((16, 16), int)], n_classes=1)
    assert only[0] == pytest.approx(0.5 / 257, rel=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_classes": 2}, "`n_classes` .* needs `ray_classes`"),
        ({"ray_classes": [np.zeros((16, 16), int)] * 2, "n_classes": 1}, r"one array per frame \(1\); got 2"),
        ({"ray_classes": [np.zeros((8, 16), int)], "n_classes": 1}, r"frame's shape \(16, 16\); got shape \(8, 16\)"),
        ({"ray_classes": [np.full((16, 16), 2)], "n_classes": 2}, r"must lie in \[-1, 1\]"),
        ({"ray_classes": [np.zeros((16, 16), int)]}, "n_classes"),
    ],
)
def test_bad_ray_classes_are_named(kwargs, message):
    scene = _rail_scene()
    with pytest.raises(PrismapInputError, match=message):
        scene.pass_through_ratio([_frame(scene)], VOXEL, **kwargs)
