"""Integrators as objects: the factory, per-ray classes reaching the model in both modes, the map refusing
a model built for another grid, and per-frame bounds refused up front under a memory cap."""

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from prismap.camera import integrate_disparity
from prismap.errors import PrismapInputError
from prismap.grid import INTEGRATOR_NAMES, OccupancyMap, RayBatch, _integrators, make_integrator
from prismap.grid._integrators import ProjectiveIntegrator, RayIntegrator, _class_chunks
from prismap.sensor_models import InverseSensorModel, make_sensor_model
from support import FB, planes_frame

OFFSETS = {-1: 0.0, 0: 0.3, 1: -0.4}
"""Depth offset (metres) of the measured surface per class of the test model below."""


class ClassModel(InverseSensorModel):
    """Two ideal models with different depth offsets, chosen per ray by its class (-1: no offset).

    In front of ``z^ + offset`` a cell gets ``-0.5``, the cell holding it ``+1.5``, nothing beyond
    (multiples of 2**-4: sums of them are exact in float32 and in the map's fixed point).
    """

    name = "test-class"
    default_policy = "sum"

    def __init__(self, classes_given=True, focal_baseline=FB):
        self.classes_given, self.focal_baseline = classes_given, focal_baseline

    def _surface(self, disparity_px, ray_class):
        offset = np.zeros(np.shape(disparity_px)) if ray_class is None else np.vectorize(OFFSETS.get)(ray_class)
        return self.focal_baseline / np.asarray(disparity_px) + offset

    def cell_posteriors(self, disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m, ray_class=None):
        assert (ray_class is not None) == self.classes_given
        if ray_class is not None:
            assert ray_class.shape == np.shape(disparity_px) and ray_class.dtype == np.int32
        z = self._surface(disparity_px, ray_class)[ray_of_cell]
        inc = np.where(depth_end_m <= z, -0.5, np.where(depth_start_m <= z, 1.5, 0.0))
        return 1 / (1 + np.exp(-inc)), inc

    def influence_depth(self, disparity_px, ray_norm, ray_class=None):
        assert (ray_class is not None) == self.classes_given
        return self._surface(disparity_px, ray_class) + 0.05

    def with_extra_noise(self, sigma_px):
        return self


class FixedClassModel(ClassModel):
    """The class-free model of one class: what the map built class by class uses."""

    def __init__(self, cls, focal_baseline=FB):
        super().__init__(classes_given=False, focal_baseline=focal_baseline)
        self.cls = cls

    def _surface(self, disparity_px, ray_class):
        return self.focal_baseline / np.asarray(disparity_px) + OFFSETS[self.cls]


def _log_by_key(grid):
    keys, log, _ = grid.known_voxels()
    return {tuple(k): v for k, v in zip(keys.tolist(), log.tolist())}


def test_factory_builds_both_integrators_and_refuses_unknown_names():
    assert INTEGRATOR_NAMES == ("ray", "projective")
    assert isinstance(make_integrator("ray", voxel_size_m=0.1), RayIntegrator)
    assert isinstance(make_integrator("projective", voxel_size_m=0.1), ProjectiveIntegrator)
    with pytest.raises(PrismapInputError, match=r"`mode` must be one of \['ray', 'projective'\]; got 'cone'"):
        make_integrator("cone", voxel_size_m=0.1)


def test_ray_batch_subset_keeps_every_per_ray_array_aligned():
    rng = np.random.default_rng(0)
    n = 10
    batch = RayBatch(
        np.zeros(3),
        rng.normal(size=(n, 3)),
        np.arange(n, dtype=float),
        np.ones(n),
        np.arange(n) * 0.1,
        np.arange(n, dtype=np.int32) % 3,
    )
    keep = np.arange(n) % 2 == 0
    sub = batch.subset(keep)
    np.testing.assert_array_equal(sub.measurement, [0, 2, 4, 6, 8])
    np.testing.assert_array_equal(sub.ray_class, [0, 2, 1, 0, 2])
    np.testing.assert_array_equal(sub.extra_noise_px, np.arange(0, n, 2) * 0.1)
    np.testing.assert_array_equal(sub.rays_w, batch.rays_w[keep])


def test_ray_class_reaches_the_model_in_ray_mode_as_a_map_built_class_by_class():
    rng = np.random.default_rng(1)
    n = 600
    rays = np.column_stack([rng.uniform(-0.6, 0.6, (n, 2)), np.ones(n)])
    disparity = FB / rng.uniform(1.0, 4.0, n)
    disparity[::17] = np.nan  # invalid rays are dropped: the classes must follow
    classes = rng.integers(-1, 2, n)
    noise = np.where(rng.random(n) < 0.5, 0.0, rng.uniform(0.02, 1.0, n))  # pose-noise groups subset the rays too
    origin = [0.05, -0.02, 0.01]
    grid = OccupancyMap(0.1, p0=0.5)
    grid.integrate_rays(origin, rays, disparity, ClassModel(), ray_class=classes, extra_noise_px=noise)
    by_hand = OccupancyMap(0.1, p0=0.5)
    for cls in (-1, 0, 1):
        mine = classes == cls
        by_hand.integrate_rays(origin, rays[mine], disparity[mine], FixedClassModel(cls))
    assert grid.n_known > 2000 and _log_by_key(grid) == _log_by_key(by_hand)
    # without classes the model is called exactly as before (no ray_class keyword)
    OccupancyMap(0.1, p0=0.5).integrate_rays(origin, rays, disparity, ClassModel(classes_given=False))


def test_ray_chunks_hold_one_class_each_in_image_order_within_the_chunk_bounds(monkeypatch):
    monkeypatch.setattr(_integrators, "RAYS_PER_CHUNK", 5)
    monkeypatch.setattr(_integrators, "CELLS_PER_CHUNK", 40)
    rng = np.random.default_rng(3)
    ray_class = rng.integers(-1, 3, 60).astype(np.int32)
    limits = rng.integers(1, 30, 60)
    limits[7] = 55  # a ray beyond the cell bound is a chunk of its own
    order, parts = _class_chunks(ray_class, limits)
    np.testing.assert_array_equal(np.sort(order), np.arange(60))
    np.testing.assert_array_equal(np.concatenate([order[part] for part in parts]), order)  # the chunks tile it
    for part in parts:
        chunk = order[part]
        assert np.unique(ray_class[chunk]).size == 1 and np.all(np.diff(chunk) > 0)
        assert chunk.size <= 5 and (limits[chunk].sum() <= 40 or chunk.size == 1)
    assert len(parts) > np.unique(ray_class).size  # the bounds split the classes' runs too
    no_classes = _class_chunks(None, limits)
    assert no_classes[0] == slice(None) and no_classes[1] == _integrators._chunks(limits)


def test_ray_mode_calls_the_model_with_one_class_a_chunk(monkeypatch):
    monkeypatch.setattr(_integrators, "RAYS_PER_CHUNK", 64)
    calls = []

    class Recording(ClassModel):
        def cell_posteriors(self, disparity_px, *args, ray_class=None):
            calls.append((np.unique(ray_class), len(disparity_px)))
            return super().cell_posteriors(disparity_px, *args, ray_class=ray_class)

    rng = np.random.default_rng(4)
    n = 500
    rays = np.column_stack([rng.uniform(-0.6, 0.6, (n, 2)), np.ones(n)])
    disparity = FB / rng.uniform(1.0, 4.0, n)
    classes = rng.integers(-1, 2, n)
    grid = OccupancyMap(0.1, p0=0.5)
    grid.integrate_rays(np.zeros(3), rays, disparity, Recording(), ray_class=classes)
    assert all(seen.size == 1 for seen, _ in calls)
    for cls in (-1, 0, 1):  # each class in ceil(n_k / 64) calls
        sizes = [size for seen, size in calls if seen[0] == cls]
        assert sum(sizes) == np.sum(classes == cls) and len(sizes) == -(-sum(sizes) // 64)
    by_hand = OccupancyMap(0.1, p0=0.5)
    for cls in (-1, 0, 1):
        mine = classes == cls
        by_hand.integrate_rays(np.zeros(3), rays[mine], disparity[mine], FixedClassModel(cls))
    assert _log_by_key(grid) == _log_by_key(by_hand)


@pytest.mark.parametrize("pose_covariance", [None, np.diag([1e-4, 1e-4, 1e-4])])
def test_ray_class_image_reaches_the_model_in_projective_mode(pose_covariance):
    """Each voxel takes the ray of the pixel its centre projects to, so the map equals the sum of maps made
    from each class's pixels alone, voxel for voxel (counts included)."""
    camera, pose, depth = planes_frame(width=80, height=60)
    disparity = camera.focal_baseline / depth
    rng = np.random.default_rng(2)
    classes = rng.integers(-1, 2, disparity.shape)
    grid = OccupancyMap(0.1, p0=0.5)
    integrate_disparity(
        grid,
        disparity,
        camera,
        pose,
        ClassModel(focal_baseline=camera.focal_baseline),
        mode="projective",
        ray_class=classes,
        max_range_m=12.0,
        pose_covariance=pose_covariance,
    )
    parts = []
    for cls in (-1, 0, 1):
        part = OccupancyMap(0.1, p0=0.5)
        integrate_disparity(
            part,
            np.where(classes == cls, disparity, np.nan),
            camera,
            pose,
            FixedClassModel(cls, camera.focal_baseline),
            mode="projective",
            max_range_m=12.0,
        )
        parts.append(part)
    merged = parts[0].merge(parts[1]).merge(parts[2])
    assert grid.n_known > 1000
    assert _log_by_key(grid) == _log_by_key(merged)
    np.testing.assert_array_equal(np.sort(grid.known_voxels()[2]), np.sort(merged.known_voxels()[2]))


@pytest.mark.parametrize("mode", ["ray", "projective"])
def test_hit_miss_models_ignore_ray_class(mode):
    """A model with hit/miss increments is never given a class (the library's takes no ``ray_class``)."""
    camera, pose, depth = planes_frame(width=40, height=30)
    model = make_sensor_model("hitmiss", focal_baseline=camera.focal_baseline, p0=0.5, voxel_size_m=0.1)
    classes = np.random.default_rng(3).integers(-1, 2, depth.shape)
    with_class, without = OccupancyMap(0.1, p0=0.5), OccupancyMap(0.1, p0=0.5)
    integrate_disparity(with_class, camera.focal_baseline / depth, camera, pose, model, mode=mode, ray_class=classes)
    integrate_disparity(without, camera.focal_baseline / depth, camera, pose, model, mode=mode)
    assert with_class.n_known > 100
    assert _log_by_key(with_class) == _log_by_key(without)


def test_bad_ray_class_is_refused():
    grid = OccupancyMap(0.1, p0=0.5)
    with pytest.raises(PrismapInputError, match=r"`ray_class` must be an integer array of shape \(2,\)"):
        grid.integrate_rays([0, 0, 0], [[0, 0, 1.0], [0, 0, 1.0]], [1.0, 1.0], ClassModel(), ray_class=[0.5, 1])
    with pytest.raises(PrismapInputError, match=r"classes >= 0 or -1 \(no class\); got values in \[-2, 0\]"):
        grid.integrate_rays([0, 0, 0], [[0, 0, 1.0], [0, 0, 1.0]], [1.0, 1.0], ClassModel(), ray_class=[-2, 0])


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"p0": 0.05, "voxel_size_m": 0.1}, r"built with p0=0.05 but the map has p0=0.5"),
        ({"p0": 0.5, "voxel_size_m": 0.2}, r"built with voxel_size_m=0.2 but the map has voxel_size_m=0.1"),
    ],
)
def test_the_map_refuses_a_model_built_for_another_prior_or_voxel_size(params, message):
    grid = OccupancyMap(0.1, p0=0.5)
    model = make_sensor_model("hitmiss", focal_baseline=FB, **params)
    with pytest.raises(PrismapInputError, match=message):
        grid.integrate_rays([0.05, 0.05, 0.05], [[0.0, 0.0, 1.0]], [FB / 2], model)
    assert grid.n_frames == 0
    grid.integrate_rays(
        [0.05, 0.05, 0.05],
        [[0.0, 0.0, 1.0]],
        [FB / 2],
        make_sensor_model("hitmiss", focal_baseline=FB, p0=0.5, voxel_size_m=0.1),
    )
    assert grid.n_frames == 1


_CAPPED = textwrap.dedent("""
    import resource, sys
    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    from prismap.errors import PrismapInputError
    from prismap.grid import OccupancyMap
    from prismap.camera import StereoCamera, integrate_disparity
    from prismap.sensor_models import make_sensor_model
    from support import planes_frame

    camera, pose, depth = planes_frame(width=320, height=240)
    fb = camera.focal_baseline

    def model(voxel):
        return make_sensor_model("ideal", focal_baseline=fb, voxel_size_m=voxel, p0=0.5)

    def hitmiss(voxel):
        return make_sensor_model("hitmiss", focal_baseline=fb, voxel_size_m=voxel, p0=0.5)

    def tiny_pixel():  # one pixel of 1e-5 px: ~4e3 km away
        d = np.full(depth.shape, np.nan); d[100, 100] = 1e-5
        integrate_disparity(OccupancyMap(0.1, p0=0.5), d, camera, pose, model(0.1), max_range_m=3e5)

    def tiny_frame():  # a frame of tiny disparities
        integrate_disparity(OccupancyMap(0.1, p0=0.5), np.full(depth.shape, 1e-3), camera, pose, model(0.1),
                                                      max_range_m=3e5)

    def millimetre(mode, width=640, height=480):  # 1 mm voxels over a normal frame
        def run():
            cam, pose_, depth_ = planes_frame(width=width, height=height)
            integrate_disparity(OccupancyMap(1e-3, p0=0.5), cam.focal_baseline / depth_, cam, pose_, model(1e-3),
                                                          mode=mode, max_range_m=12.0)
        return run

    def lidar_far():  # LiDAR points 1e5 m away, as lidar_reference_map casts them
        rng = np.random.default_rng(0)
        directions = rng.normal(size=(5000, 3))
        rays = directions / np.abs(directions).max(axis=1, keepdims=True)
        OccupancyMap(0.2, p0=0.5).integrate_rays(np.zeros(3), rays, np.full(5000, fb / 1e5), hitmiss(0.2))

    for name, case in [("tiny pixel", tiny_pixel), ("tiny frame", tiny_frame), ("1 mm ray", millimetre("ray")),
                       ("1 mm projective", millimetre("projective")), ("lidar 1e5 m", lidar_far),
                       ("1 mm small frame", millimetre("ray", 320, 240))]:
        try:
            case()
        except PrismapInputError as exc:
            print(name, "|", exc)
        else:
            print(name, "| no error")
""")


def test_frames_beyond_the_bounds_are_refused_up_front_under_a_memory_cap():
    tests = Path(__file__).resolve().parent
    run = subprocess.run(
        [sys.executable, "-c", _CAPPED, str(tests)], capture_output=True, text=True, timeout=600, check=False
    )
    assert run.returncode == 0, run.stderr[-2000:]
    lines = dict(line.split(" | ", 1) for line in run.stdout.strip().splitlines())
    assert "a ray would cross" in lines["tiny pixel"] and "1048576" in lines["tiny pixel"]
    assert "voxel visits" in lines["tiny frame"] and "1073741824" in lines["tiny frame"]
    assert "voxel visits" in lines["1 mm ray"] and "`voxel_size_m`=0.001" in lines["1 mm ray"]
    assert "frustum's key box" in lines["1 mm projective"]
    assert "a ray would cross" in lines["lidar 1e5 m"] and "`voxel_size_m`=0.2" in lines["lidar 1e5 m"]
    # fewer visits than the bound, yet too many distinct blocks: refused when the accumulator reaches its bound
    assert "the frame accumulator's bound" in lines["1 mm small frame"]


def test_blocks_expected_by_a_frame_are_reserved_within_the_frame_budget(monkeypatch):
    """``_accumulator.expect`` reserves room for an estimate of a frame's blocks in one allocation, never
    below what the accumulator holds and never beyond the frame budget (an estimate is no error)."""
    from prismap.grid import _accumulator

    acc = _accumulator.new_accumulator((2, 2, 2))
    _accumulator.expect(acc, 1000)
    assert acc.block_keys.size == 1000 and len(acc) == 0
    _accumulator.expect(acc, 10)  # room enough: nothing changes
    assert acc.block_keys.size == 1000
    monkeypatch.setattr(_accumulator, "frame_budget_bytes", lambda: 5000 * acc.bytes_per_block())
    _accumulator.expect(acc, 1e12)
    assert acc.block_keys.size == 5000


def test_projective_hit_miss_increments_follow_the_rule_cell_by_cell():
    rng = np.random.default_rng(3)
    z_hit = np.concatenate([rng.uniform(1.0, 9.0, 40), [np.inf] * 10])  # the last rays end in misses
    ray_of_cell = rng.integers(0, z_hit.size, 5000)
    t_in = np.round(rng.uniform(0.0, 10.0, 5000), 1)  # on a 0.1 m grid: cells that end or start at the hit too
    t_out = t_in + 0.1
    t_in[:50], t_out[:50] = z_hit[ray_of_cell[:50]], z_hit[ray_of_cell[:50]] + 0.1  # starting exactly at the hit
    got = _integrators._hit_miss_increments(ray_of_cell, t_in, t_out, z_hit, 0.85, -0.4)
    expected = [
        -0.4 if b <= z_hit[r] else (0.85 if a <= z_hit[r] else 0.0) for r, a, b in zip(ray_of_cell, t_in, t_out)
    ]
    np.testing.assert_array_equal(got, expected)
    assert {-0.4, 0.85, 0.0} <= set(got.tolist())
    assert np.all(got[ray_of_cell >= 40][t_out[ray_of_cell >= 40] <= 1e9] == -0.4)
