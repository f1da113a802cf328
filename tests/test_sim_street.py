"""The street world: KITTI-like rig, exact disparity of known façades, voxelised truth, the drive, seeds."""

import numpy as np
import pytest

from prismap import sim
from prismap.errors import PrismapInputError
from prismap.sim._street import CAMERA_HEIGHT_M, DRIVE_START_M, STREET_LENGTH_M

HALF = sim.kitti_camera(scale=0.5)


def test_kitti_rig_full_and_half_size():
    full = sim.kitti_camera()
    assert (full.width, full.height, full.focal_px, full.baseline_m) == (1242, 375, 720.0, 0.54)
    assert (HALF.width, HALF.height, HALF.focal_px, HALF.baseline_m) == (621, 188, 360.0, 0.54)
    # pixel centres are kept: the full image's centre (620.5, 187) maps to (310, 93.25) at half size
    assert (HALF.cx_px, HALF.cy_px) == (310.0, 93.25)
    assert sim.tsukuba_camera(scale=0.25).width == 160
    with pytest.raises(PrismapInputError, match="`scale`"):
        sim.kitti_camera(scale=0.0)


def test_facade_disparities_equal_f_b_over_z_at_hand_computed_pixels():
    scene = sim.street_scene(seed=0)
    position = np.array([DRIVE_START_M, -1.5, CAMERA_HEIGHT_M])
    frame = scene.render(HALF, sim.pose_from_heading(position, 0.0), noise_sigma=0.0)
    fb = 360.0 * 0.54
    # the building closing the street is fronto-parallel at x = 84 m: z = 80 m at the centre pixel
    assert frame.extras["depth_m"][93, 310] == pytest.approx(STREET_LENGTH_M - DRIVE_START_M, rel=1e-12)
    assert frame.disparity_gt[93, 310] == pytest.approx(fb / 80.0, rel=1e-6)
    # pixel (u, v) = (0, 20) looks left and up: camera x = -310/360 of z is world +y. It meets the left façade
    # y = y_face at z = (y_face + 1.5) / (310/360); the façade is the front of the left building spanning that x
    slope = 310.0 / 360.0
    left = [(lo, hi) for lo, hi in zip(scene.box_lo, scene.box_hi) if lo[1] >= 8.0 and hi[1] - lo[1] == 2.0]
    for lo, hi in left:
        z = (lo[1] + 1.5) / slope
        if lo[0] <= position[0] + z <= hi[0]:
            break
    else:
        raise AssertionError("no left façade on the ray")
    assert CAMERA_HEIGHT_M + (93.25 - 20) / 360.0 * z < hi[2]  # below the roof: the façade, not the sky
    assert frame.extras["depth_m"][20, 0] == pytest.approx(z, rel=1e-12)
    assert frame.disparity_gt[20, 0] == pytest.approx(fb / z, rel=1e-6)
    sky = np.isnan(frame.disparity_gt)
    assert sky[0, 310] and 0.005 < sky.mean() < 0.2 and np.isinf(frame.extras["depth_m"][sky]).all()


def test_depths_span_2_to_80_m_along_the_drive():
    scene = sim.street_scene(seed=1)
    poses = sim.street_trajectory(12, seed=1)
    small = sim.kitti_camera(scale=0.25)
    depths = np.concatenate([scene.cast(small, pose).ravel() for pose in poses])
    hit = depths[np.isfinite(depths)]
    assert 1.0 < hit.min() < 3.0 and 75.0 < hit.max() < 81.0


@pytest.mark.parametrize(("voxel", "n_keys"), [(0.2, 4), (0.25, 2)])  # x 6.92-7.08, y 5.52-5.68: keys 34-35 x 27-28
def test_a_pole_is_voxelised_at_its_hand_computed_keys(voxel, n_keys):  # at 0.2 m; 27-28 x 22 at 0.25 m
    scene = sim.street_scene(seed=0)
    pole = next(
        i
        for i, (lo, hi) in enumerate(zip(scene.box_lo, scene.box_hi))
        if hi[2] == 6.0 and hi[0] - lo[0] < 0.2 and lo[0] < 8.0 and lo[1] > 0
    )
    lo, hi = scene.box_lo[pole], scene.box_hi[pole]
    np.testing.assert_allclose([lo, hi], [[6.92, 5.52, 0.15], [7.08, 5.68, 6.0]])
    keys = scene.ground_truth([], voxel).occupied_keys
    k_lo, k_hi = np.floor(lo / voxel).astype(int), np.floor(hi / voxel).astype(int)
    near = keys[np.all((keys[:, :2] >= k_lo[:2] - 2) & (keys[:, :2] <= k_hi[:2] + 2), axis=1)]
    layer = int(np.floor(3.0 / voxel))  # 3 m up: nothing but the pole is there
    expected = {(x, y, layer) for x in range(k_lo[0], k_hi[0] + 1) for y in range(k_lo[1], k_hi[1] + 1)}
    assert set(map(tuple, near[near[:, 2] == layer].tolist())) == expected and len(expected) == n_keys
    top = int(np.floor(6.0 / voxel))
    assert near[:, 2].max() == top and near[:, 2].min() == int(np.floor(-0.3 / voxel))  # pole top, road bottom


def test_the_drive_moves_forward_level_and_clear_of_every_box():
    scene = sim.street_scene(seed=2)
    poses = sim.street_trajectory(30, step_m=1.5, seed=2)
    assert poses.shape == (30, 4, 4)
    rotations = poses[:, :3, :3]
    np.testing.assert_allclose(
        rotations @ rotations.transpose(0, 2, 1), np.broadcast_to(np.eye(3), (30, 3, 3)), atol=1e-12
    )
    positions = poses[:, :3, 3]
    np.testing.assert_allclose(positions[:, 0], DRIVE_START_M + 1.5 * np.arange(30))
    np.testing.assert_allclose(positions[:, 2], CAMERA_HEIGHT_M)
    assert np.all(np.abs(positions[:, 1] + 1.5) <= 0.3)
    forward = rotations[:, :, 2]
    yaw = np.degrees(np.arctan2(forward[:, 1], forward[:, 0]))
    pitch_down = np.degrees(np.arcsin(-forward[:, 2]))
    assert np.abs(yaw).max() <= 6.0 and np.ptp(yaw) > 2.0
    assert np.all((pitch_down >= 1.0 - 1e-9) & (pitch_down <= 2.0 + 1e-9))
    gaps = np.maximum(np.maximum(scene.box_lo[None] - positions[:, None], positions[:, None] - scene.box_hi[None]), 0)
    assert np.linalg.norm(gaps, axis=-1).min() >= 0.15  # above the cars, beside the poles


def test_scene_trajectory_and_images_are_determined_by_the_seed():
    a, b, c = sim.street_scene(seed=3), sim.street_scene(seed=3), sim.street_scene(seed=4)
    np.testing.assert_array_equal(a.box_lo, b.box_lo)
    np.testing.assert_array_equal(a.box_tint, b.box_tint)
    assert a.box_lo.shape != c.box_lo.shape or not np.array_equal(a.box_lo, c.box_lo)
    np.testing.assert_array_equal(sim.street_trajectory(5, seed=3), sim.street_trajectory(5, seed=3))
    assert not np.array_equal(sim.street_trajectory(5, seed=3), sim.street_trajectory(5, seed=4))
    small = sim.kitti_camera(scale=0.1)
    poses = sim.street_trajectory(2, seed=3)
    first = [f.left for f in a.frames(small, poses, seed=9)]
    again = [f.left for f in b.frames(small, poses, seed=9)]
    other = [f.left for f in b.frames(small, poses, seed=10)]
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)


def test_a_drive_started_half_a_step_on_follows_the_same_path_between_the_first_drives_positions():
    first = sim.street_trajectory(8, seed=2)
    between = sim.street_trajectory(16, step_m=0.5, start_m=4.25, seed=2)
    np.testing.assert_allclose(between[:, 0, 3], 4.25 + 0.5 * np.arange(16))
    assert np.abs(between[:, 0, 3][:, None] - first[:, 0, 3][None, :]).min() == pytest.approx(0.25)
    # the path is a function of x: a drive with another start and step through x = 6 m has the pose at x = 6 m
    through_six = sim.street_trajectory(3, step_m=0.5, start_m=5.0, seed=2)
    np.testing.assert_allclose(through_six[2], first[2], atol=1e-12)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: sim.street_trajectory(0), "`n_frames` must be a positive integer"),
        (lambda: sim.street_trajectory(3, start_m=-1.0), "`start_m` must be a finite number >= 0"),
        (lambda: sim.street_trajectory(3, step_m=0.0), r"`step_m` must lie in \(0, 5\]"),
        (lambda: sim.street_trajectory(60), "60 frames of 1.0 m end at x = 63 m"),
    ],
)
def test_bad_drive_options_are_named(call, message):
    with pytest.raises(PrismapInputError, match=message):
        call()
