"""Whole frames through the map: ray versus projective mode, merge equals sequential integration,
queries, 2-D maps, pose uncertainty and hostile input."""

import pickle

import numpy as np
import pytest

from prismap.camera import integrate_disparity, pose_noise_px
from prismap.errors import PrismapInputError
from prismap.grid import FREE, OCCUPIED, OCTOMAP_CLAMP, UNKNOWN, OccupancyMap
from support import FB, HitMissModel, assert_same_map, planes_frame


def small_frame():
    camera, pose, depth = planes_frame(160, 120)
    camera = type(camera)(131.25, 79.5, 59.5, 0.1, width=160, height=120)
    return camera, pose, camera.focal_baseline / depth


def test_projective_and_ray_modes_agree_on_a_frame():
    camera, pose, disparity = small_frame()
    model = HitMissModel(camera.focal_baseline)
    maps = {}
    for mode in ("ray", "projective"):
        maps[mode] = OccupancyMap(0.1, p0=0.5)
        integrate_disparity(maps[mode], disparity, camera, pose, model, mode=mode, max_range_m=12.0)
    keys = np.unique(np.concatenate([m.known_voxels()[0] for m in maps.values()]), axis=0)
    ray, proj = (maps[m].state_at_keys(keys) for m in ("ray", "projective"))
    # Stated tolerance: the modes differ only where a voxel is crossed by several rays but its centre
    # projects onto one of them (frustum edges, grazing floor); >= 90 % of the union agrees.
    assert np.mean(ray == proj) >= 0.90
    # Occupied voxels (thin for hit/miss): projective finds at least 75 % of those ray mode finds (measured 79 %).
    occ = ray == OCCUPIED
    assert np.mean(proj[occ] == OCCUPIED) >= 0.75


@pytest.mark.parametrize("policy", ["occupied-wins", "mean"])
def test_projective_hit_miss_without_a_model_call_gives_the_map_of_the_cell_path(policy):
    """A model with hit_miss_increments gets its increments in the walking threads; hiding them takes the cell
    path (cells ->
    sort by ray -> cell_posteriors -> scatter): the same voxels, counts and log-odds, with rays cut at max
    range, pose-noise groups, subsampled pixels and fresh accumulators grown from empty."""
    from prismap.sensor_models import HitMissModel as LibraryHitMiss

    class CellPath(LibraryHitMiss):
        def hit_miss_increments(self):
            return None

    camera, pose, disparity = small_frame()
    maps = []
    for cls in (LibraryHitMiss, CellPath):
        model = cls(focal_baseline=camera.focal_baseline, voxel_size_m=0.1, p0=0.3)
        grid = OccupancyMap(0.1, p0=0.3)
        for subsample, cov in ((1, None), (2, np.eye(3) * 0.05**2)):
            integrate_disparity(
                grid,
                disparity,
                camera,
                pose,
                model,
                mode="projective",
                policy=policy,
                max_range_m=6.0,
                subsample=subsample,
                pose_covariance=cov,
            )
        maps.append(grid)
    assert maps[0].n_known > 20_000
    assert_same_map(*maps)


def test_merge_of_any_split_equals_sequential_integration():
    camera, pose, disparity = small_frame()
    model = HitMissModel(camera.focal_baseline)
    rng = np.random.default_rng(7)
    poses = []
    for _ in range(4):
        p = pose.copy()
        p[:3, 3] += rng.normal(scale=0.3, size=3)
        poses.append(p)
    whole = OccupancyMap(0.1, p0=0.5)
    for p in poses:
        integrate_disparity(whole, disparity, camera, p, model, max_range_m=12.0)
    for split in ([0, 1], [2], [0, 3]):
        a, b = OccupancyMap(0.1, p0=0.5), OccupancyMap(0.1, p0=0.5)
        for i, p in enumerate(poses):
            integrate_disparity(a if i in split else b, disparity, camera, p, model, max_range_m=12.0)
        merged = b.merge(a)
        keys, log, count = whole.known_voxels()
        got_log, got_count = merged.lookup_keys(keys)
        # fixed-point log-odds: sums in another order are the same integers
        np.testing.assert_array_equal(got_log, log)
        np.testing.assert_array_equal(got_count, count)
        assert merged.n_known == whole.n_known and merged.n_frames == 4


@pytest.mark.parametrize("read_only", [False, True])
def test_a_pickled_map_is_its_fixed_point_blocks_and_keeps_integrating_like_the_original(read_only):
    """What a Dask chunk map goes through: the int64 sums, counts, frames, policies and settings come back bit for
    bit, without the frame accumulator or spare capacity; the copy (even from read-only buffers, as a Dask message
    gives them) then integrates and merges exactly as the original."""
    camera, pose, disparity = small_frame()
    model = HitMissModel(camera.focal_baseline)
    grid = OccupancyMap(0.1, p0=0.5, clamp=OCTOMAP_CLAMP, occupied_threshold=0.6, free_threshold=0.3)
    integrate_disparity(grid, disparity, camera, pose, model, max_range_m=12.0)
    integrate_disparity(grid, disparity, camera, pose, model, max_range_m=12.0, policy="max-abs")
    buffers = []
    data = pickle.dumps(grid, protocol=5, buffer_callback=buffers.append)
    if read_only:
        buffers = [memoryview(bytes(b.raw())) for b in buffers]
    twin = pickle.loads(data, buffers=buffers)
    stored = grid._store
    used = len(stored) * (stored.bytes_per_block() - 16)  # the blocks' payload and packed keys, no hash table
    assert len(data) + sum(memoryview(b).nbytes for b in buffers) < used + 4096  # no accumulator (16 B a voxel)
    assert len(twin._accumulator) == 0 and twin.nbytes() <= grid.nbytes()
    for mine, theirs in zip(grid.known_voxels(), twin.known_voxels()):
        assert mine.dtype == theirs.dtype and np.array_equal(mine, theirs)
    for attr in ("voxel_size_m", "p0", "ndim", "clamp", "fusion", "prior_q", "policies", "n_frames", "free_threshold"):
        assert getattr(twin, attr) == getattr(grid, attr), attr
    moved = pose.copy()
    moved[:3, 3] += [0.3, -0.2, 0.5]  # new blocks and old ones
    before = grid.copy()
    for g in (grid, twin):
        integrate_disparity(g, disparity, camera, moved, model, max_range_m=12.0)
        g.merge(before)
    assert twin.n_frames == grid.n_frames == 5
    for mine, theirs in zip(grid.known_voxels(), twin.known_voxels()):
        np.testing.assert_array_equal(mine, theirs)


def test_clamping_keeps_log_odds_inside_octomap_bounds():
    grid = OccupancyMap(0.1, p0=0.5, clamp=OCTOMAP_CLAMP)
    for _ in range(10):
        grid.integrate_rays([0.05, 0.05, 0.05], [[1.0, 0.0, 0.0]], [FB / 0.53], HitMissModel(FB))
    prob = grid.probability_at_keys(grid.known_voxels()[0])
    np.testing.assert_allclose([prob.min(), prob.max()], OCTOMAP_CLAMP, rtol=1e-6)
    assert np.all(grid.known_voxels()[2] == 10)


def test_queries_on_a_hand_made_ray():
    grid = OccupancyMap(0.1, p0=0.5)
    grid.integrate_rays([0.05, 0.05, 0.05], [[1.0, 0.0, 0.0]], [FB / 0.53], HitMissModel(FB))
    points = [[0.05, 0.05, 0.05], [0.55, 0.05, 0.05], [0.65, 0.05, 0.05]]
    np.testing.assert_array_equal(grid.state(points), [FREE, OCCUPIED, UNKNOWN])
    np.testing.assert_allclose(grid.probability(points), [0.4, 0.7, 0.5], atol=1e-6)
    keys, centers, prob = grid.occupied_voxels()
    assert keys.tolist() == [[5, 0, 0]]
    np.testing.assert_allclose(centers, [[0.55, 0.05, 0.05]])
    lo, hi = grid.bounding_box()
    np.testing.assert_allclose(lo, [0, 0, 0]), np.testing.assert_allclose(hi, [0.6, 0.1, 0.1])
    image, extent = grid.slice_image(layer=0)
    np.testing.assert_allclose(image, [[0.4] * 5 + [0.7]], atol=1e-6)
    np.testing.assert_allclose(extent, [0, 0.6, 0, 0.1])
    image, _ = grid.slice_image(z_range_m=(-1.0, 1.0))
    assert image.shape == (1, 6)
    hit, hit_keys, distance = grid.first_occupied(
        [0.0, 0.05, 0.05], [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], max_range_m=2.0
    )
    assert hit.tolist() == [True, False] and hit_keys[0].tolist() == [5, 0, 0]
    np.testing.assert_allclose(distance, [0.5, np.nan])


def test_two_dimensional_map_is_one_layer():
    grid = OccupancyMap(0.1, p0=0.5, ndim=2)
    grid.integrate_rays([0.05, 0.05], [[1.0, 0.0]], [FB / 0.33], HitMissModel(FB))
    keys, log, _ = grid.known_voxels()
    assert sorted(keys.tolist()) == [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]
    image, _ = grid.slice_image()
    assert image.shape == (1, 4)
    np.testing.assert_array_equal(grid.state([[0.35, 0.05]]), [OCCUPIED])
    with pytest.raises(PrismapInputError, match="z key 0"):
        grid.state_at_keys([[0, 0, 1]])


def test_pose_noise_formula_and_grouping():
    rays = np.array([[0.0, 0.0, 1.0], [0.5, -0.2, 1.0]])
    disparity = np.array([FB / 2.0, FB / 4.0])
    # Position only, along the optical axis: sigma_d = f b sigma_z / z^2.
    cov = np.diag([0.0, 0.0, 0.01**2])
    np.testing.assert_allclose(
        pose_noise_px(disparity, rays, np.eye(3), cov, FB, 0.0), FB * 0.01 / np.array([4.0, 16.0])
    )
    # Rotation about the camera y axis moves depth by -p_x dtheta_y: only the off-axis ray feels it.
    cov6 = np.zeros((6, 6))
    cov6[4, 4] = 0.001**2
    sigma = pose_noise_px(disparity, rays, np.eye(3), cov6, FB, 0.0)
    np.testing.assert_allclose(sigma, [0.0, FB * (0.5 * 4.0) * 0.001 / 16.0])
    seen = []

    class Spy(HitMissModel):
        def with_extra_noise(self, sigma_px):
            seen.append(sigma_px)
            return super().with_extra_noise(sigma_px)

    camera, pose, disp = small_frame()
    grid = OccupancyMap(0.1, p0=0.5)
    integrate_disparity(
        grid, disp, camera, pose, Spy(camera.focal_baseline), pose_covariance=np.eye(3) * 0.05**2, max_range_m=12.0
    )
    assert len(seen) >= 2 and all(s > 0 for s in seen)


def test_projective_noise_groups_give_each_cell_its_own_rays_measurement():
    """Pose noise splits the rays into groups, each its own model call on its rays; with models that ignore
    the noise, the map equals the one without groups (a cell handed another ray's disparity would differ)."""
    seen = []

    class Spy(HitMissModel):
        def with_extra_noise(self, sigma_px):
            seen.append(sigma_px)
            return super().with_extra_noise(sigma_px)

    camera, pose, disp = small_frame()
    maps = []
    for cov in (None, np.eye(3) * 0.05**2):
        grid = OccupancyMap(0.1, p0=0.5)
        integrate_disparity(
            grid,
            disp,
            camera,
            pose,
            Spy(camera.focal_baseline),
            mode="projective",
            pose_covariance=cov,
            max_range_m=12.0,
        )
        maps.append(grid)
    assert len(seen) >= 3
    assert_same_map(*maps)


def test_nan_disparities_are_skipped_and_bad_poses_are_errors():
    camera, pose, disparity = small_frame()
    model = HitMissModel(camera.focal_baseline)
    holes = disparity.copy()
    holes[:, :80] = np.nan
    grid = OccupancyMap(0.1, p0=0.5)
    integrate_disparity(grid, holes, camera, pose, model, max_range_m=12.0)
    assert 0 < grid.n_known
    for bad in (np.nan, np.inf):
        broken = pose.copy()
        broken[0, 3] = bad
        with pytest.raises(PrismapInputError, match="T_world_cam"):
            integrate_disparity(grid, disparity, camera, broken, model)
    with pytest.raises(PrismapInputError, match="T_world_cam"):
        integrate_disparity(grid, disparity, camera, np.eye(3), model)
    with pytest.raises(PrismapInputError, match="origin_w"):
        grid.integrate_rays([np.nan, 0, 0], [[0, 0, 1.0]], [1.0], model)
    with pytest.raises(PrismapInputError, match="rays_w"):
        grid.integrate_rays([0, 0, 0], [[0, 0, 0.5]], [1.0], model)
    with pytest.raises(PrismapInputError, match="subsample"):
        integrate_disparity(grid, disparity, camera, pose, model, subsample=0)
    with pytest.raises(PrismapInputError, match="mode"):
        integrate_disparity(grid, disparity, camera, pose, model, mode="cone")


def test_rays_without_a_bound_are_an_error_not_a_hang():
    class Endless(HitMissModel):
        def influence_depth(self, disparity_px, ray_norm):
            return np.full(np.shape(disparity_px), np.inf)

    grid = OccupancyMap(0.1, p0=0.5)
    with pytest.raises(PrismapInputError, match="max_range_m"):
        grid.integrate_rays([0, 0, 0], [[0, 0, 1.0]], [1.0], Endless(FB))
    grid.integrate_rays([0, 0, 0], [[0, 0, 1.0]], [1.0], Endless(FB), max_range_m=1.0)
    assert grid.n_known == 10


def test_subsampling_uses_every_nth_pixel():
    camera, pose, disparity = small_frame()
    model = HitMissModel(camera.focal_baseline)
    full, sub = OccupancyMap(0.1, p0=0.5), OccupancyMap(0.1, p0=0.5)
    integrate_disparity(
        full,
        disparity[::4, ::4],
        type(camera)(camera.focal_px / 4, camera.cx_px / 4, camera.cy_px / 4, 0.4),
        pose,
        HitMissModel(camera.focal_baseline),
        max_range_m=12.0,
    )
    integrate_disparity(sub, disparity, camera, pose, model, subsample=4, max_range_m=12.0)
    assert 0 < sub.n_known
    assert sub.n_known == pytest.approx(full.n_known, rel=0.05)


@pytest.mark.parametrize("overhang_fraction", [0.0, 0.25])
def test_projective_prism_maps_do_not_depend_on_the_walks_parts(monkeypatch, overhang_fraction):
    """The projective walk hands its cells to the model part by part (the model in a worker thread beside the
    walk); one part, three and one per line or so give the same map voxel for voxel: PRISM with and without
    the overhang's stretch (without it a cell reuses its ray's previous look-up), pose-noise groups, and an
    accumulator grown from empty in the middle of parts (no blocks reserved before the walk) or reserved."""
    from prismap.gmm import GaussianMixture
    from prismap.grid import _integrators
    from prismap.sensor_models import make_sensor_model

    camera, pose, disparity = small_frame()
    mixture = GaussianMixture(np.array([0.9, 0.1]), np.array([0.0, 0.0]), np.array([0.3, 3.0]))
    maps = []
    for parts, block_fill in ((1, 1e9), (3, 1e9), (1000, 1e9), (3, _integrators.BLOCK_FILL)):
        monkeypatch.setattr(_integrators, "PROJECTIVE_PARTS", parts)
        monkeypatch.setattr(_integrators, "BLOCK_FILL", block_fill)
        model = make_sensor_model(
            "prism",
            focal_baseline=camera.focal_baseline,
            voxel_size_m=0.1,
            p0=0.1,
            error_model=mixture,
            near_m=0.5,
            overhang_fraction=overhang_fraction,
        )
        grid = OccupancyMap(0.1, p0=0.1)
        for cov in (None, np.eye(3) * 0.03**2):
            integrate_disparity(
                grid,
                disparity,
                camera,
                pose,
                model,
                mode="projective",
                max_range_m=6.0,
                subsample=2,
                pose_covariance=cov,
            )
        maps.append(grid)
    assert maps[0].n_known > 5_000
    for other in maps[1:]:
        assert_same_map(maps[0], other)


def test_a_frame_projecting_onto_more_cells_than_the_memory_bound_is_refused(monkeypatch):
    # The bound holds for the cells of all parts together (each part's walk only counts beyond it), checked by
    # the integrator before any part's voxels enter the accumulator; the map is left as it was.
    from prismap.grid import _accumulator, _integrators

    camera, pose, disparity = small_frame()
    grid = OccupancyMap(0.1, p0=0.5)
    model = HitMissModel(camera.focal_baseline)  # cells through cell_posteriors, not the hit/miss walk
    cells = 20
    for parts in (1, 3):
        monkeypatch.setattr(_integrators, "PROJECTIVE_PARTS", parts)
        monkeypatch.setattr(_accumulator, "frame_budget_bytes", lambda: 32 * cells)
        with pytest.raises(
            PrismapInputError,
            match=rf"the frame projects onto at least \d+ voxels, more than {cells} "
            r"\(docs/errors.md\)",
        ):
            integrate_disparity(grid, disparity, camera, pose, model, mode="projective", max_range_m=12.0)
        assert grid.n_known == 0


def test_ray_mode_models_in_threads_give_the_map_of_one_thread(monkeypatch):
    """Ray mode runs the model on chunks in MODEL_THREADS threads beside the cast (and in the casting thread while
    it would wait) and adds the increments in chunk order; the map is the same voxel for voxel whatever the threads
    and the chunks queued ahead (none: the casting thread runs most chunks itself), with PRISM's overhang stretch,
    small chunks of odd sizes and an accumulator grown from empty while models run."""
    from prismap.gmm import GaussianMixture
    from prismap.grid import _integrators
    from prismap.sensor_models import make_sensor_model

    camera, pose, disparity = small_frame()
    mixture = GaussianMixture(np.array([0.9, 0.1]), np.array([0.0, 0.0]), np.array([0.3, 3.0]))
    model = make_sensor_model(
        "prism", focal_baseline=camera.focal_baseline, voxel_size_m=0.1, p0=0.1, error_model=mixture, near_m=0.5
    )
    monkeypatch.setattr(_integrators, "RAYS_PER_CHUNK", 301)
    maps = []
    for threads, ahead in ((1, 0), (1, 3), (2, 1), (3, 5)):
        monkeypatch.setattr(_integrators, "MODEL_THREADS", threads)
        monkeypatch.setattr(_integrators, "CHUNKS_AHEAD", ahead)
        grid = OccupancyMap(0.1, p0=0.1)
        integrate_disparity(grid, disparity, camera, pose, model, mode="ray", max_range_m=6.0, subsample=3)
        maps.append(grid)
    assert maps[0].n_known > 5_000
    for other in maps[1:]:
        assert_same_map(maps[0], other)
