"""Textured 3-D box scenes: exact disparity, left/right consistency, trajectory, ground-truth occupancy."""

import cv2
import numpy as np
import pytest

from prismap import sim
from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.io import StereoFrame

SMALL = StereoCamera(60.0, 31.5, 23.5, 0.1, width=64, height=48)


def test_fronto_parallel_wall_has_disparity_f_b_over_z():
    camera = sim.tsukuba_camera()
    depth = camera.focal_baseline / 20.0  # 3.075 m: disparity exactly 20 px
    scene = sim.Scene3D.from_boxes([[-20, -20, depth]], [[20, 20, depth + 0.2]])
    frame = scene.render(camera, np.eye(4), noise_sigma=0.0)
    assert isinstance(frame, StereoFrame) and frame.disparity_gt.dtype == np.float32
    np.testing.assert_allclose(frame.disparity_gt, 20.0, rtol=1e-6)
    np.testing.assert_allclose(frame.extras["depth_m"], depth, rtol=1e-12)
    # the right pixel u - 20 sees the same wall point as the left pixel u: equal colour up to rounding
    diff = np.abs(frame.left[:, 20:].astype(int) - frame.right[:, :-20].astype(int))
    assert diff.max() <= 1 and frame.left.std() > 20


def test_floor_depth_matches_analytic_ray_plane_intersection():
    camera = sim.tsukuba_camera()
    scene = sim.Scene3D.from_boxes([[-50, -50, -1.0]], [[50, 50, 0.0]])
    pose = sim.pose_from_heading([0.0, 0.0, 1.5], 0.7)
    frame = scene.render(camera, pose, noise_sigma=0.0)
    rows = np.array([260, 300, 400, 479])
    expected = 1.5 * camera.focal_px / (rows - camera.cy_px)  # level camera: down by (v - cy) / f per metre
    np.testing.assert_allclose(frame.extras["depth_m"][rows, 100], expected, rtol=1e-12)
    np.testing.assert_allclose(frame.disparity_gt[rows, 100], camera.focal_baseline / expected, rtol=1e-6)
    assert np.all(np.isnan(frame.disparity_gt[: int(camera.cy_px) + 1]))  # at and above the horizon: no hit


def test_disparity_offset_shifts_the_right_view():
    camera = StereoCamera(60.0, 31.5, 23.5, 0.1, doffs_px=2.0, width=64, height=48)
    plain = StereoCamera(60.0, 31.5, 23.5, 0.1, width=64, height=48)
    scene = sim.Scene3D.from_boxes([[-9, -9, 2.0]], [[9, 9, 2.5]], texture="astronaut")
    shifted = scene.render(camera, np.eye(4), noise_sigma=0.0)
    base = scene.render(plain, np.eye(4), noise_sigma=0.0)
    np.testing.assert_allclose(shifted.disparity_gt, 60 * 0.1 / 2.0 - 2.0, rtol=1e-6)
    np.testing.assert_array_equal(shifted.right[:, 2:], base.right[:, :-2])  # cx_right = cx + doffs


def test_left_right_consistency_in_the_indoor_scene():
    scene = sim.indoor_scene(seed=1)
    camera = sim.tsukuba_camera()
    pose = sim.indoor_trajectory(8, seed=1)[3]
    frame = scene.render(camera, pose, noise_sigma=0.0)
    disparity = frame.disparity_gt
    assert np.all(np.isfinite(disparity))  # a closed room
    u, v = np.meshgrid(np.arange(640, dtype=np.float32), np.arange(480, dtype=np.float32))
    warped = cv2.remap(frame.right, u - disparity, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    # occluded pixels: the right camera sees something nearer at u - d
    right_depth = scene.cast(camera, pose, right=True)
    ur = np.clip(np.rint(u - disparity).astype(int), 0, 639)
    visible = (u - disparity >= 1) & (np.abs(right_depth[v.astype(int), ur] - frame.extras["depth_m"]) < 0.02)
    error = np.abs(warped.astype(float) - frame.left)[visible].max(axis=-1)
    assert visible.mean() > 0.8
    assert np.median(error) <= 2 and np.mean(error < 12) > 0.97


def test_noise_is_seeded_and_has_the_requested_sigma():
    scene = sim.indoor_scene()
    pose = sim.indoor_trajectory(4)[0]
    clean = scene.render(SMALL, pose, noise_sigma=0.0)
    a = scene.render(SMALL, pose, noise_sigma=3.0, rng=7)
    b = scene.render(SMALL, pose, noise_sigma=3.0, rng=7)
    np.testing.assert_array_equal(a.left, b.left)
    np.testing.assert_array_equal(a.right, b.right)
    residual = a.left.astype(float) - clean.left
    inside = (clean.left > 10) & (clean.left < 245)
    assert abs(residual[inside].std() - 3.0) < 0.3
    np.testing.assert_array_equal(a.disparity_gt, clean.disparity_gt)


def test_trajectory_is_smooth_and_clear_of_every_box():
    scene = sim.indoor_scene(seed=4)
    poses = sim.indoor_trajectory(40, seed=4)
    assert poses.shape == (40, 4, 4)
    np.testing.assert_allclose(
        poses[:, :3, :3] @ poses[:, :3, :3].transpose(0, 2, 1), np.broadcast_to(np.eye(3), (40, 3, 3)), atol=1e-12
    )
    positions = poses[:, :3, 3]
    gaps = np.maximum(np.maximum(scene.box_lo[None] - positions[:, None], positions[:, None] - scene.box_hi[None]), 0)
    assert np.linalg.norm(gaps, axis=-1).min() >= 0.5
    assert np.linalg.norm(np.diff(positions, axis=0), axis=1).max() < 0.8
    depths = np.concatenate([scene.cast(SMALL, pose).ravel() for pose in poses])
    assert 0.5 < depths.min() and depths.max() < 16.0


def test_solid_voxels_match_hand_computed_keys():
    scene = sim.Scene3D.from_boxes([[0.0, 0.0, 0.0], [-0.05, 0.31, 0.0]], [[0.25, 0.1, 0.05], [-0.01, 0.39, 0.0]])
    truth = scene.ground_truth([], 0.1)
    expected = {(x, y, 0) for x in range(3) for y in range(2)} | {(-1, 3, 0)}  # faces on y = 0.1 mark y key 1
    assert set(map(tuple, truth.occupied_keys.tolist())) == expected
    assert truth.observed_keys.shape == (0, 3)


def _observed_reference(scene, frames, voxel):
    """Slow numpy twin of the ground truth's observed set (3-D, nearest-pixel visibility plus hit voxels)."""
    lo = np.floor(scene.box_lo.min(axis=0) / voxel).astype(int)
    hi = np.floor(scene.box_hi.max(axis=0) / voxel).astype(int)
    keys = np.stack(np.meshgrid(*(np.arange(a, b + 1) for a, b in zip(lo, hi)), indexing="ij"), -1).reshape(-1, 3)
    centres = (keys + 0.5) * voxel
    seen = set()
    for frame in frames:
        cam, pose = frame.camera, frame.T_world_cam
        p = (centres - pose[:3, 3]) @ pose[:3, :3]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.floor(cam.focal_px * p[:, 0] / p[:, 2] + cam.cx_px + 0.5)
            v = np.floor(cam.focal_px * p[:, 1] / p[:, 2] + cam.cy_px + 0.5)
        ok = (p[:, 2] > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        depth = frame.extras["depth_m"]
        idx = np.flatnonzero(ok)
        idx = idx[p[idx, 2] <= depth[v[idx].astype(int), u[idx].astype(int)]]
        seen |= set(map(tuple, keys[idx].tolist()))
        points = cam.pixel_rays() * depth[..., None]
        points = points[np.isfinite(depth)] @ pose[:3, :3].T + pose[:3, 3]
        seen |= set(map(tuple, np.floor(points / voxel).astype(int).tolist()))
    return seen


def test_ground_truth_observed_voxels_match_numpy_reference():
    scene = sim.indoor_scene(seed=2)
    poses = sim.indoor_trajectory(6, seed=2)
    frames = list(scene.frames(SMALL, poses, noise_sigma=0.0))
    truth = scene.ground_truth(frames, 0.25)
    observed = set(map(tuple, truth.observed_keys.tolist()))
    reference = _observed_reference(scene, frames, 0.25)
    assert observed == reference
    assert len(truth.observed_occupied_keys) > 100 and len(truth.free_keys) > 1000
    camera_keys = {tuple(k) for k in np.floor(poses[:, :3, 3] / 0.25).astype(int).tolist()}
    assert not camera_keys & set(map(tuple, truth.occupied_keys.tolist()))


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: sim.Scene3D.from_boxes([[0, 0, 1]], [[1, 1, 0]]), "bad rows \\[0\\]"),
        (lambda: sim.Scene3D.from_boxes([[0, 0, 0]], [[1, 1, 1]], texture=99), "`box_texture` must be 1 indices"),
        (lambda: sim.Scene3D.from_boxes([[0, 0, 0]], [[1, 1, 1]], texel_m=0.0), "`box_texel_m` must be > 0"),
        (
            lambda: sim.Scene3D.from_boxes([[0, 0, 1]], [[1, 1, 2]]).render(StereoCamera(100, 5, 5, 0.1), np.eye(4)),
            "needs `width` and `height`",
        ),
        (
            lambda: sim.Scene3D.from_boxes([[0, 0, 1]], [[1, 1, 2]]).render(SMALL, np.eye(4), noise_sigma=-1),
            "`noise_sigma`",
        ),
        (
            lambda: sim.Scene3D.from_boxes([[0, 0, 1]], [[1, 1, 2]]).render(SMALL, np.full((4, 4), np.nan)),
            "`T_world_cam` must be finite",
        ),
        (lambda: sim.indoor_trajectory(0), r"`n_frames` must be an integer in \[1, 360\]"),
        (lambda: sim.indoor_trajectory(361), r"`n_frames` must be an integer in \[1, 360\].*got 361"),
        (lambda: sim.indoor_trajectory(True), r"`n_frames` must be an integer"),
        (lambda: sim.indoor_scene().ground_truth([], 0.001), "choose a larger one"),
    ],
)
def test_bad_input_is_reported(call, message):
    with pytest.raises(PrismapInputError, match=message):
        call()


def _cast_reference(origin, directions, lo, hi):
    """Slow numpy slab test: nearest positive entry parameter and box of each ray (inf, -1 on a miss)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo[None] - origin) / directions[:, None]
        t1 = (hi[None] - origin) / directions[:, None]
    near = np.nanmax(np.minimum(t0, t1), axis=-1)
    far = np.nanmin(np.maximum(t0, t1), axis=-1)
    near = np.where((near <= far) & (near > 0), near, np.inf)
    return near.min(axis=1), np.where(np.isfinite(near.min(axis=1)), near.argmin(axis=1), -1)


def test_ray_casting_kernel_matches_numpy_slab_reference():
    rng = np.random.default_rng(11)
    lo = rng.uniform(-6, 6, (40, 3))
    hi = lo + rng.uniform(0.05, 2.0, (40, 3))
    outside = ~np.any(np.all((lo <= 0) & (hi >= 0), axis=1))
    assert outside  # the camera at the origin is in no box
    scene = sim.Scene3D.from_boxes(lo, hi)
    for heading, pitch in [(0.3, 0.1), (2.0, -0.4), (-1.2, 0.8)]:
        pose = sim.pose_from_heading([0.0, 0.0, 0.0], heading, pitch_rad=pitch)
        depth = scene.cast(SMALL, pose)
        directions = SMALL.pixel_rays().reshape(-1, 3) @ pose[:3, :3].T
        expected, _ = _cast_reference(np.zeros(3), directions, lo, hi)
        np.testing.assert_allclose(depth.ravel(), expected, rtol=1e-12)
        assert 0.0 < np.isfinite(depth).mean() < 1.0  # both hits and misses are compared


def test_rendered_frames_survive_the_sequence_files(tmp_path):
    from prismap.io._sequence import read_sequence, write_sequence

    scene = sim.indoor_scene(seed=5)
    frames = list(scene.frames(SMALL, sim.indoor_trajectory(3, seed=5), seed=5))
    truth = scene.ground_truth(frames, 0.2)
    write_sequence(frames, tmp_path, occupancy=truth)
    seq = read_sequence(tmp_path)
    assert seq.camera == SMALL and len(seq) == 3
    for frame, back in zip(frames, seq):
        np.testing.assert_array_equal(back.left, frame.left)
        np.testing.assert_allclose(back.disparity_gt, frame.disparity_gt, atol=0.5 / 256)
        np.testing.assert_array_equal(back.T_world_cam, frame.T_world_cam)
    np.testing.assert_array_equal(seq.ground_truth.observed_keys, truth.observed_keys)
    np.testing.assert_array_equal(seq.ground_truth.occupied_keys, truth.occupied_keys)
