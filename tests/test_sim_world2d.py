"""2-D worlds and the 1-row stereo range sensor against hand-derived and brute-force references."""

import numpy as np
import pytest

from prismap import sim
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture


def _segment_hits(origin, directions, rectangles):
    """Brute force: nearest positive intersection of rays with the four edges of every rectangle."""
    best = np.full(len(directions), np.inf)
    for x0, y0, x1, y1 in rectangles:
        for (ax, ay), (bx, by) in [
            ((x0, y0), (x1, y0)),
            ((x1, y0), (x1, y1)),
            ((x1, y1), (x0, y1)),
            ((x0, y1), (x0, y0)),
        ]:
            edge = np.array([bx - ax, by - ay])
            for i, d in enumerate(directions):
                matrix = np.array([[d[0], -edge[0]], [d[1], -edge[1]]])
                if abs(np.linalg.det(matrix)) < 1e-12:
                    continue
                t, s = np.linalg.solve(matrix, np.array([ax, ay]) - origin)
                if t > 0 and -1e-12 <= s <= 1 + 1e-12:
                    best[i] = min(best[i], t)
    return best


def test_occupancy_matches_hand_computed_cells():
    world = sim.World2D(np.array([[0.5, 0.5, 1.0, 1.5], [2.2, 0.3, 2.4, 0.3]]), np.array([3.0, 2.0]))
    grid = world.occupancy(0.5)
    assert grid.shape == (5, 7)  # floor(2 / 0.5) + 1 rows, floor(3 / 0.5) + 1 columns
    expected = np.zeros((5, 7), dtype=bool)
    expected[1:4, 1:3] = True  # closed [0.5, 1.0] x [0.5, 1.5]: keys x 1..2, y 1..3
    expected[0, 4] = True  # a zero-thickness segment inside cell (4, 0)
    np.testing.assert_array_equal(grid, expected)


def test_builtin_worlds_are_closed_and_paths_stay_clear():
    for world in (sim.simple_world(), sim.office_world()):
        grid = world.occupancy(0.1)
        assert grid[0].all() and grid[-1].all() and grid[:, 0].all() and grid[:, -1].all()
        path = sim.waypoint_path(world.waypoints, step_m=0.1)
        clearance = np.full(len(path), np.inf)
        for x0, y0, x1, y1 in world.rectangles:
            dx = np.maximum.reduce([x0 - path[:, 0], np.zeros(len(path)), path[:, 0] - x1])
            dy = np.maximum.reduce([y0 - path[:, 1], np.zeros(len(path)), path[:, 1] - y1])
            clearance = np.minimum(clearance, np.hypot(dx, dy))
        assert clearance.min() >= 0.4, world.name


def test_waypoint_path_steps_and_turns():
    path = sim.waypoint_path([(0, 0), (1, 0), (1, 1)], step_m=0.25, turn_step_deg=30)
    np.testing.assert_allclose(path[:4, :2], [[0, 0], [0.25, 0], [0.5, 0], [0.75, 0]])
    np.testing.assert_allclose(path[4:6, 2], [np.pi / 6, np.pi / 3])  # turning in place at (1, 0)
    np.testing.assert_allclose(path[-1], [1, 1, np.pi / 2])
    assert np.all(np.abs(np.diff(path[:, 2])) <= np.pi / 6 + 1e-12)


def test_pose_axes_follow_the_documented_convention():
    pose = sim.pose_from_heading([1.0, 2.0], np.pi / 2)
    np.testing.assert_allclose(pose[:3, 2], [0, 1, 0], atol=1e-15)  # camera z along the heading
    np.testing.assert_allclose(pose[:3, 0], [1, 0, 0], atol=1e-15)  # camera x to the right
    np.testing.assert_allclose(pose[:3, 1], [0, 0, -1], atol=1e-15)  # camera y = world down
    np.testing.assert_allclose(pose[:3, 3], [1, 2, 0])
    assert np.isclose(np.linalg.det(pose[:3, :3]), 1.0)


def test_scanner_hits_equal_analytic_wall_depth():
    world = sim.World2D(np.array([[5.0, 8.0, 6.0, 12.0]]), np.array([20.0, 20.0]))
    scanner = sim.StereoScanner2D(n_rays=101, fov_deg=60, baseline_m=0.12)
    frame = scanner.scan(world, sim.pose_from_heading([0.0, 10.0], 0.0))
    camera = frame.camera
    assert (camera.height, camera.width, camera.cy_px, camera.cx_px) == (1, 101, 0.0, 50.0)
    x = scanner.ray_directions_cam[:, 0]  # world ray (1, -x): the face x = 5 at depth 5, y = 10 - 5 x
    inside = np.abs(x) < 0.4 - 1e-9
    outside = np.abs(x) > 0.4 + 1e-9
    np.testing.assert_allclose(frame.disparity_gt[0, inside], camera.focal_px * 0.12 / 5.0, rtol=1e-12)
    np.testing.assert_allclose(frame.range_m[0, inside], 5.0 * np.hypot(1.0, x[inside]), rtol=1e-12)
    np.testing.assert_allclose(frame.disparity[0, inside], frame.disparity_gt[0, inside], rtol=1e-6)
    assert np.all(np.isnan(frame.disparity_gt[0, outside])) and np.all(np.isinf(frame.range_m[0, outside]))
    assert np.isclose(camera.focal_px, 50.5 / np.tan(np.radians(30)))


def test_scanner_ranges_equal_brute_force_segment_intersection():
    world = sim.office_world()
    scanner = sim.StereoScanner2D(n_rays=90, fov_deg=120)
    for x, y, heading in [(1.5, 10.0, 0.3), (11.25, 6.0, -2.0), (26.0, 10.2, 1.7)]:
        pose = sim.pose_from_heading([x, y], heading)
        frame = scanner.scan(world, pose)
        directions = scanner.ray_directions_cam @ pose[:3, :3].T
        units = directions[:, :2] / np.linalg.norm(directions[:, :2], axis=1, keepdims=True)
        expected = _segment_hits(np.array([x, y]), units, world.rectangles)
        np.testing.assert_allclose(frame.range_m[0], expected, rtol=1e-9)


def test_measured_disparity_errors_follow_the_mixture_and_are_seeded():
    world = sim.simple_world()
    mixture = GaussianMixture([0.7, 0.3], [0.2, -0.5], [0.3, 1.0])
    scanner = sim.StereoScanner2D(n_rays=200, baseline_m=1.0, max_depth_m=50.0, error_model=mixture)
    poses = sim.waypoint_path(world.waypoints, step_m=1.0)
    frames = list(scanner.frames(world, poses, seed=3))
    errors = np.concatenate([(f.disparity_gt - f.disparity).ravel() for f in frames])
    errors = errors[np.isfinite(errors)]
    assert errors.size > 0.99 * len(frames) * 200
    assert abs(errors.mean() - mixture.mean()) < 0.02 and abs(errors.std() - mixture.std()) < 0.02
    again = list(scanner.frames(world, poses[:3], seed=3))
    for a, b in zip(frames, again):
        np.testing.assert_array_equal(a.disparity, b.disparity)
        assert a.disparity.dtype == np.float32 and a.disparity.shape == (1, 200)


def test_hits_beyond_max_range_are_not_measured():
    world = sim.World2D(np.array([[5.0, 0.0, 6.0, 20.0], [2.0, 9.0, 3.0, 9.5]]), np.array([20.0, 20.0]))
    scanner = sim.StereoScanner2D(n_rays=64, max_depth_m=4.0)
    frame = scanner.scan(world, sim.pose_from_heading([0.0, 10.0], 0.0))
    depth = frame.camera.focal_baseline / frame.disparity_gt[0]
    assert np.all(np.isfinite(depth))
    np.testing.assert_array_equal(np.isnan(frame.disparity[0]), depth > 4.0)


def _visible_reference(world, frames, cell, max_range):
    """Slow numpy twin of the visibility kernel plus the hit cells: the observed set of the ground truth."""
    nx, ny = (np.floor(world.size_m / cell).astype(int) + 1).tolist()
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    centres = np.stack([(ix + 0.5) * cell, (iy + 0.5) * cell, np.zeros_like(ix, dtype=float)], axis=-1).reshape(-1, 3)
    seen = set()
    for frame in frames:
        cam, pose = frame.camera, frame.T_world_cam
        p_cam = (centres - pose[:3, 3]) @ pose[:3, :3]
        z = p_cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.floor(cam.focal_px * p_cam[:, 0] / z + cam.cx_px + 0.5)
        depth = cam.depth_from_disparity(frame.disparity_gt)[0]
        ok = (z > 0) & (z <= max_range) & (u >= 0) & (u < cam.width)
        idx = np.flatnonzero(ok)
        ok_depth = z[idx] <= np.nan_to_num(depth[u[idx].astype(int)], nan=np.inf)
        seen |= {(int(a), int(b), 0) for a, b in np.floor(centres[idx[ok_depth], :2] / cell)}
        hit = np.isfinite(depth) & (depth <= max_range)
        points = cam.pixel_rays()[0, hit] * depth[hit, None] @ pose[:3, :3].T + pose[:3, 3]
        seen |= {(int(a), int(b), 0) for a, b in np.floor(points[:, :2] / cell)}
    return seen


def test_ground_truth_matches_numpy_reference_and_hand_checks():
    world = sim.simple_world()
    scanner = sim.StereoScanner2D(n_rays=120)
    poses = sim.waypoint_path(world.waypoints, step_m=2.0)[::3] + [0.013, 0.007, 0.0]  # no ties on pixel edges
    frames = list(scanner.frames(world, poses))
    truth = world.ground_truth(frames, 0.25, max_depth_m=8.0)
    assert set(map(tuple, truth.observed_keys.tolist())) == _visible_reference(world, frames, 0.25, 8.0)
    occupied = np.argwhere(world.occupancy(0.25))[:, ::-1]
    np.testing.assert_array_equal(truth.occupied_keys[:, :2], occupied[np.lexsort(occupied.T[::-1])])
    assert np.all(truth.occupied_keys[:, 2] == 0)
    # the first pose stands at (2.513, 2.507) facing +y with nothing within 8 m straight ahead
    first = set(map(tuple, world.ground_truth(frames[:1], 0.25, max_depth_m=8.0).free_keys.tolist()))
    assert (10, 9, 0) not in first  # behind the camera
    assert {(10, k, 0) for k in range(10, 42)} <= first  # ahead: centres up to y = 10.375 m (depth 7.87 m)
    assert (10, 42, 0) not in first  # its centre lies 8.118 m ahead, beyond the maximum range
    assert len(truth.observed_occupied_keys) + len(truth.free_keys) == len(truth.observed_keys)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: sim.World2D(np.array([[1.0, 0.0, 0.5, 1.0]]), np.array([2.0, 2.0])), "bad rows \\[0\\]"),
        (lambda: sim.World2D(np.array([[1.0, 0.0, 3.0, 1.0]]), np.array([2.0, 2.0])), "inside \\[0, 2.0\\]"),
        (lambda: sim.StereoScanner2D(fov_deg=180), "`fov_deg` must lie in \\(0, 180\\)"),
        (lambda: sim.StereoScanner2D(n_rays=2.5), "`n_rays` must be a positive integer"),
        (lambda: sim.StereoScanner2D(error_model=0.5), "`error_model` must be a GaussianMixture"),
        (lambda: sim.simple_world().occupancy(0.0), "`cell_size_m` must be a finite number > 0"),
        (lambda: sim.waypoint_path([(0.0, 0.0)]), "at least 2 points"),
        (
            lambda: sim.StereoScanner2D().scan(sim.simple_world(), sim.pose_from_heading([1, 1, 0.5], 0.0)),
            "plane z = 0",
        ),
        (lambda: sim.StereoScanner2D().scan(sim.simple_world(), np.eye(3)), "`T_world_cam` must have shape"),
    ],
)
def test_bad_input_is_reported(call, message):
    with pytest.raises(PrismapInputError, match=message):
        call()
