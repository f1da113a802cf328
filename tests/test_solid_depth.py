"""PRISM's solid depth: the stretched event by brute force, the model against it, the ground truth's depth."""

import itertools
from types import SimpleNamespace

import numpy as np
import pytest

from prismap import sim
from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import PrismModel
from prismap.sensor_models._prism import TABLE_TOLERANCE

FB = 61.5
MIXTURE = GaussianMixture([0.85, 0.15], [0.05, -0.3], [0.4, 2.5])


def _cell_likelihoods(d_hat, edges):
    """``g`` averaged uniformly in disparity over each cell, and over ``(0, f b / z_n]`` beyond the last."""
    u = FB / edges
    lik = (MIXTURE.cdf(u[:-1] - d_hat) - MIXTURE.cdf(u[1:] - d_hat)) / (u[:-1] - u[1:])
    lik_far = (MIXTURE.cdf(u[-1] - d_hat) - MIXTURE.cdf(-d_hat)) / u[-1]
    return lik, lik_far


def _brute_force(d_hat, edges, p0, behind, cell):
    """P(cell occupied | d^) over all 2^n surface maps: cells hold surfaces independently (prior p0), the first
    one produces d^, and each surface's solid fills the ``behind`` cells after it."""
    lik, lik_far = _cell_likelihoods(d_hat, edges)
    surfaces = np.array(list(itertools.product((0, 1), repeat=edges.size - 1)), dtype=bool)
    any_surface = surfaces.any(axis=1)
    produced = np.where(any_surface, lik[np.argmax(surfaces, axis=1)], lik_far)
    weight = np.prod(np.where(surfaces, p0, 1 - p0), axis=1) * produced
    occupied = surfaces[:, max(cell - behind, 0) : cell + 1].any(axis=1)
    return weight[occupied].sum() / weight.sum()


def _stretched_formula(d_hat, edges, p0, behind, cell):
    """The closed form: the cell is occupied when a surface lies in the stretch of cells ``cell - behind ..
    cell``: the first surface in it, or one before it and another in it anyway (prior of the stretch)."""
    lik, lik_far = _cell_likelihoods(d_hat, edges)
    n = edges.size - 1
    first = p0 * (1 - p0) ** np.arange(n) * lik  # first surface in cell k
    evidence = first.sum() + (1 - p0) ** n * lik_far
    lo = max(cell - behind, 0)
    stretch_prior = 1 - (1 - p0) ** (cell + 1 - lo)
    return (stretch_prior * first[:lo].sum() + first[lo : cell + 1].sum()) / evidence


@pytest.mark.parametrize(("depth", "p0", "behind"), [(2.2, 0.2, 1), (3.1, 0.05, 3)])
def test_stretched_event_matches_brute_force(depth, p0, behind):
    """Solids that fill the cells behind each surface: the posterior is the formula on the stretch before the cell."""
    edges = 1.0 + 0.4 * np.arange(9)
    d_hat = FB / depth
    for cell in range(edges.size - 1):
        expected = _brute_force(d_hat, edges, p0, behind, cell)
        assert _stretched_formula(d_hat, edges, p0, behind, cell) == pytest.approx(expected, rel=1e-12, abs=1e-15)
    # the solid changes the answer: behind the measurement the stretch reaches back to the surface
    assert _brute_force(d_hat, edges, p0, behind, 5) > _brute_force(d_hat, edges, p0, 0, 5) + 0.05


def _model(**params):
    return PrismModel(error_model=MIXTURE, focal_baseline=FB, voxel_size_m=0.1, p0=0.08, near_m=0.5, **params)


@pytest.mark.parametrize("method", ["direct", "table"])
def test_solid_depth_evaluates_the_stretch_before_each_cell(method):
    """``solid_depth_m = T``: each cell ``[a, c]`` is the 1-D model's cell ``[a - T / |r|, c]`` (clipped at near_m)."""
    rng = np.random.default_rng(3)
    disparity = np.round(rng.uniform(6.0, 40.0, 5) * 16) / 16
    norm = rng.uniform(1.0, 1.4, 5)
    rays = np.repeat(np.arange(5), 40)
    start = np.concatenate([np.linspace(0.5, 12.0, 41)[:-1] for _ in range(5)])
    end = start + 11.5 / 40
    solid = 0.3
    posterior, increment = _model(solid_depth_m=solid).cell_posteriors(disparity, norm, rays, start, end, method=method)
    stretched = np.maximum(start - solid / norm[rays], 0.5)
    ref_posterior, ref_increment = _model().cell_posteriors(disparity, norm, rays, stretched, end, method="direct")
    np.testing.assert_allclose(posterior, ref_posterior, rtol=0, atol=TABLE_TOLERANCE["posterior"])
    finite = np.abs(ref_increment) < TABLE_TOLERANCE["large"]
    np.testing.assert_array_less(
        np.abs(increment - ref_increment)[finite],
        (TABLE_TOLERANCE["abs"] + TABLE_TOLERANCE["rel"] * np.abs(ref_increment))[finite],
    )
    plain, _ = _model().cell_posteriors(disparity, norm, rays, start, end, method=method)
    measured = FB / disparity[rays]  # cells starting just behind each measured surface gain; the first cell does not
    behind = (start > measured) & (start < measured + 0.3)
    assert behind.sum() >= 5 and (posterior - plain)[behind].min() > 0
    assert posterior[0] == pytest.approx(plain[0], rel=1e-9)


def test_solid_depth_moves_the_influence_depth_back():
    disparity, norm = np.array([24.0]), np.array([1.3])
    plain, solid = _model().influence_depth(disparity, norm), _model(solid_depth_m=0.4).influence_depth(disparity, norm)
    np.testing.assert_allclose(solid - plain, 0.4 / norm)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"solid_depth_m": -0.1}, "`solid_depth_m` must be a finite number >= 0; got -0.1"),
        ({"solid_depth_m": float("nan")}, "`solid_depth_m` must be a finite number >= 0"),
        ({"solid_depth_m": 0.2, "prior": "map"}, "`solid_depth_m` (0.2 m) works with prior='p0' only"),
    ],
)
def test_bad_solid_depth_is_refused(params, message):
    with pytest.raises(PrismapInputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        _model(**params)


def _march(lo, hi, origin, direction, hit, cap, step=1e-4):
    """Brute force: sample the ray every ``step`` metres from 1 mm behind the hit (where the march starts);
    depth = distance from the hit to the first sample in no box (0 if that is the first one)."""
    t = np.arange(hit + 1e-3, hit + cap, step)
    points = origin + t[:, None] * direction
    inside = np.any(np.all((points[:, None] >= lo) & (points[:, None] <= hi), axis=2), axis=1)
    outside = np.flatnonzero(~inside)
    if outside.size == 0:
        return cap
    return 0.0 if outside[0] == 0 else t[outside[0]] - hit


def test_solid_depth_along_rays_matches_hand_derived_depths():
    lo = np.array([[1.0, -1.0, -1.0], [2.0, -1.0, -1.0], [2.3, -0.2, -0.2], [5.0, -1.0, -1.0]])
    hi = np.array([[2.0, 1.0, 1.0], [2.2, 1.0, 1.0], [3.0, 0.2, 0.2], [5.1, 1.0, 1.0]])
    diagonal = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    origins = np.zeros((4, 3))
    directions = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], diagonal, [1.0, 0.0, 0.0]])
    hits = np.array([1.0, 5.0, np.sqrt(2.0), 3.5])  # the last one lies in no box
    depth = sim.solid_depth_along_rays(lo, hi, origins, directions, hits, cap_m=1.5)
    # touching boxes continue the solid ([1, 2] then [2, 2.2]); the gap to 2.3 ends it; the slab [5, 5.1];
    # 45 degrees through x in [1, 2] leaves by y = 1 at x = 1: the wall's depth along the ray is 0 there
    np.testing.assert_allclose(depth, [1.2, 0.1, 0.0, 0.0], atol=1e-5)
    assert sim.solid_depth_along_rays(lo, hi, origins[:1], directions[:1], hits[:1], cap_m=0.5)[0] == pytest.approx(0.5)


def test_solid_depth_along_rays_matches_brute_force():
    rng = np.random.default_rng(11)
    lo = rng.uniform(-2.0, 2.0, (12, 3))
    hi = lo + rng.uniform(0.05, 1.5, (12, 3))
    directions = rng.normal(size=(40, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    box = rng.integers(12, size=40)
    entry = rng.uniform(lo[box], hi[box])  # a point inside a box, reached from 3 m before it
    origins, hits = entry - 3.0 * directions, np.full(40, 3.0)
    depth = sim.solid_depth_along_rays(lo, hi, origins, directions, hits, cap_m=2.0)
    expected = [_march(lo, hi, o, d, 3.0, 2.0) for o, d in zip(origins, directions)]
    np.testing.assert_allclose(depth, expected, atol=2e-4)


def test_scene_solid_depth_is_the_quantile_of_the_hits_depths():
    """A camera facing two walls at 2 m: left half 0.3 m thick, right half 0.1 m; along a ray of norm |r| the
    solid is ``thickness |r|`` deep, so the quantile is that of those values."""
    camera = StereoCamera(focal_px=20.0, cx_px=7.5, cy_px=5.5, baseline_m=0.1, width=16, height=12)
    lo = np.array([[-5.0, -5.0, 2.0], [0.0, -5.0, 2.0]])
    hi = np.array([[0.0, 5.0, 2.3], [5.0, 5.0, 2.1]])
    depth = np.full((12, 16), 2.0)
    depth[:, 7:9] = np.inf  # the seam (x = 0) and nothing behind it
    frame = SimpleNamespace(
        camera=camera, T_world_cam=np.eye(4), disparity_gt=camera.disparity_from_depth(depth), extras={"depth_m": depth}
    )
    norm = np.linalg.norm(camera.pixel_rays(), axis=2)
    thickness = np.where(np.arange(16) < 7, 0.3, 0.1)[None, :] * norm
    keep = np.isfinite(depth)
    scene = sim.Scene3D.from_boxes(lo, hi)
    for quantile in (0.1, 0.5, 0.9):
        measured = scene.solid_depth([frame], 0.1, quantile=quantile)
        assert measured == pytest.approx(np.quantile(thickness[keep], quantile), abs=1e-5)
    sub = scene.solid_depth([frame], 0.1, subsample=2, quantile=0.5)
    assert sub == pytest.approx(np.quantile(thickness[::2, ::2][keep[::2, ::2]], 0.5), abs=1e-5)
    with pytest.raises(PrismapInputError, match="no ray of `frames` meets a surface within `max_depth_m`"):
        scene.solid_depth([frame], 0.1, max_depth_m=1.0)
