"""``prismap lidar-truth`` on tiny KITTI odometry and raw folders whose Velodyne scans see a known wall,
then ``prismap evaluate`` against the result, and the one-line errors."""

import json

import cv2
import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.cli import main
from prismap.io import KittiOdometry, read_ground_truth, save_map
from prismap.pipeline import lidar_reference_map
from prismap.pipeline._lidar import in_camera_view, kitti_lidar_scans

VOXEL = 0.1
F, CX, CY, W, H = 20.0, 19.5, 14.5, 40, 30  # a 90 x 74 degree view
K = np.array([[F, 0, CX], [0, F, CY], [0, 0, 1.0]])
T2 = np.array([0.06, 0.0, 0.0])  # colour camera in rectified camera-0 coordinates: x2 = x0 + T2
T3 = np.array([-0.48, 0.0, 0.0])
R_CAM_VELO = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])  # Velodyne x forward, y left, z up
T_CAM0_VELO = np.eye(4)
T_CAM0_VELO[:3, :3] = R_CAM_VELO
T_CAM0_VELO[:3, 3] = [0.01, -0.08, -0.27]  # the laser sits above and behind camera 0
WALL_Z = 5.05  # world z of the wall: mid-voxel, so float32 scans cannot change a key


def _rotation_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _pose(angle, t):
    pose = np.eye(4)
    pose[:3, :3] = _rotation_y(angle)
    pose[:3, 3] = t
    return pose


POSES_CAM0 = [_pose(0.0, [0, 0, 0]), _pose(0.05, [0.3, 0.02, 0.4]), _pose(-0.04, [0.6, 0.0, 0.8])]
T_CAM0_CAM2 = np.eye(4)
T_CAM0_CAM2[:3, 3] = -T2
POSES_CAM2 = [p @ T_CAM0_CAM2 for p in POSES_CAM0]  # T_world_cam2, derived here independently of the reader


def _wall_points(frame):
    """World points of the wall seen by ``frame``: mid-voxel grid, shifted per frame so every scan adds voxels."""
    x, y = np.meshgrid(np.arange(-15, 12) * VOXEL + 0.05 + 0.3 * frame, np.arange(-8, 8) * VOXEL + 0.05)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, WALL_Z)], axis=1)


def _behind_points(frame):
    """World points behind every camera (mid-voxel): out of its view, in the 360-degree scan."""
    return np.array([[0.05, 0.05, -2.55], [1.05, -0.55, -2.55], [-2.05, 0.35, -3.05]]) + [0.1 * frame, 0, 0]


def _T_world_velo(frame):
    T_cam2_velo = np.linalg.inv(T_CAM0_CAM2) @ T_CAM0_VELO
    return POSES_CAM2[frame] @ T_cam2_velo


def _scan(frame):
    """The frame's Velodyne scan (N, 4) float32 in the Velodyne frame, reflectance 0.5."""
    points_w = np.vstack([_wall_points(frame), _behind_points(frame)])
    T_velo_world = np.linalg.inv(_T_world_velo(frame))
    points_velo = points_w @ T_velo_world[:3, :3].T + T_velo_world[:3, 3]
    return np.c_[points_velo, np.full(len(points_velo), 0.5)].astype(np.float32)


def _line(name, matrix):
    return f"{name}: " + " ".join(f"{v:.12e}" for v in np.ravel(matrix)) + "\n"


def _pose_lines(poses):
    return "".join(" ".join(f"{v:.17g}" for v in p[:3].ravel()) + "\n" for p in poses)


def _projection(t):
    return K @ np.hstack([np.eye(3), t[:, None]])


def _images(folder, names):
    folder.mkdir(parents=True)
    for name in names:
        cv2.imwrite(str(folder / name), np.full((H, W, 3), 128, np.uint8))


@pytest.fixture(scope="module")
def kitti_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("kitti")
    seq = root / "sequences" / "07"
    seq.mkdir(parents=True)
    (seq / "calib.txt").write_text(
        _line("P0", _projection(np.zeros(3)))
        + _line("P1", _projection(T3 - T2))
        + _line("P2", _projection(T2))
        + _line("P3", _projection(T3))
        + _line("Tr", T_CAM0_VELO[:3])
    )
    names = [f"{i:06d}.png" for i in range(3)]
    _images(seq / "image_2", names)
    _images(seq / "image_3", names)
    (root / "poses").mkdir()
    (root / "poses" / "07.txt").write_text(_pose_lines(POSES_CAM0))
    (seq / "velodyne").mkdir()
    for i in range(3):
        _scan(i).tofile(seq / "velodyne" / f"{i:06d}.bin")
    return root


@pytest.fixture(scope="module")
def raw_drive(tmp_path_factory, kitti_root):
    date = tmp_path_factory.mktemp("raw") / "2011_09_26"
    drive = date / "2011_09_26_drive_0001_sync"
    date.mkdir()
    (date / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\n"
        + _line("R_rect_00", np.eye(3))
        + _line("P_rect_02", _projection(T2))
        + _line("P_rect_03", _projection(T3))
    )
    (date / "calib_velo_to_cam.txt").write_text(_line("R", T_CAM0_VELO[:3, :3]) + _line("T", T_CAM0_VELO[:3, 3]))
    names = [f"{i:010d}.png" for i in range(3)]
    _images(drive / "image_02" / "data", names)
    _images(drive / "image_03" / "data", names)
    (drive / "velodyne_points" / "data").mkdir(parents=True)
    for i in range(3):
        _scan(i).tofile(drive / "velodyne_points" / "data" / f"{i:010d}.bin")
    (date / "poses.txt").write_text(_pose_lines(POSES_CAM2))
    return drive


def _keys(points_w):
    return np.unique(np.floor(points_w / VOXEL).astype(np.int64), axis=0)


def _truth(args, tmp_path, capsys, name="truth.npz"):
    out = tmp_path / name
    assert main(["lidar-truth", *args, "--voxel", str(VOXEL), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    truth = read_ground_truth(out)
    assert f"{len(truth.observed_keys)} voxels observed, {len(truth.observed_occupied_keys)} occupied" in printed
    return truth


def test_occupied_voxels_are_the_wall_points_and_free_space_runs_from_the_laser(kitti_root, tmp_path, capsys):
    truth = _truth(["--kitti", str(kitti_root), "--sequence", "7"], tmp_path, capsys)
    wall = np.vstack([_wall_points(i) for i in range(3)])
    np.testing.assert_array_equal(truth.occupied_keys, _keys(wall))
    np.testing.assert_array_equal(truth.observed_occupied_keys, truth.occupied_keys)
    # the voxel halfway along every ray, from the laser's world position to the point, is observed and free
    free = {tuple(k) for k in truth.free_keys}
    for i in range(3):
        laser_w = _T_world_velo(i)[:3, 3]
        halfway = _keys(laser_w + 0.5 * (_wall_points(i) - laser_w))
        assert all(tuple(k) in free for k in halfway)
    # free space starts at the laser (behind camera 0), ends before the wall's layer; nothing behind is known
    assert truth.free_keys[:, 2].min() == np.floor(_T_world_velo(0)[2, 3] / VOXEL)
    assert truth.free_keys[:, 2].max() == 49 and truth.observed_keys[:, 2].max() == 50


def test_full_scan_adds_the_points_behind_the_camera(kitti_root, tmp_path, capsys):
    truth = _truth(["--kitti", str(kitti_root), "--sequence", "07", "--full-scan"], tmp_path, capsys)
    points = np.vstack([_wall_points(i) for i in range(3)] + [_behind_points(i) for i in range(3)])
    np.testing.assert_array_equal(truth.occupied_keys, _keys(points))


def test_frames_every_and_max_range(kitti_root, tmp_path, capsys):
    args = ["--kitti", str(kitti_root), "--sequence", "07"]
    one = _truth([*args, "--frames", "1:2"], tmp_path, capsys, "one.npz")
    np.testing.assert_array_equal(one.occupied_keys, _keys(_wall_points(1)))
    every = _truth([*args, "--frames", ":", "--every", "2"], tmp_path, capsys, "every.npz")
    np.testing.assert_array_equal(every.occupied_keys, _keys(np.vstack([_wall_points(0), _wall_points(2)])))
    # a range shorter than the wall: no hit, free space only within 3 m of some laser position
    short = _truth([*args, "--max-range", "3"], tmp_path, capsys, "short.npz")
    assert len(short.occupied_keys) == 0 and len(short.free_keys) > 0
    centres = (short.free_keys + 0.5) * VOXEL
    lasers = np.array([_T_world_velo(i)[:3, 3] for i in range(3)])
    nearest = np.linalg.norm(centres[:, None] - lasers[None], axis=2).min(axis=1)
    assert nearest.max() <= 3.0 + np.sqrt(3) / 2 * VOXEL and nearest.max() > 3.0 - VOXEL


def test_raw_drive_with_colour_camera_poses_equals_the_odometry_truth(kitti_root, raw_drive, tmp_path, capsys):
    odometry = _truth(["--kitti", str(kitti_root), "--sequence", "07"], tmp_path, capsys, "odometry.npz")
    raw = _truth(["--raw", str(raw_drive), "--poses", str(raw_drive.parent / "poses.txt")], tmp_path, capsys)
    np.testing.assert_array_equal(raw.occupied_keys, odometry.occupied_keys)
    np.testing.assert_array_equal(raw.observed_keys, odometry.observed_keys)
    # the same colour-camera poses given to the odometry sequence replace its camera-0 poses/07.txt
    kitti = _truth(
        ["--kitti", str(kitti_root), "--sequence", "07", "--poses", str(raw_drive.parent / "poses.txt")],
        tmp_path,
        capsys,
        "kitti_poses.npz",
    )
    np.testing.assert_array_equal(kitti.observed_keys, odometry.observed_keys)


def test_evaluate_scores_a_map_against_the_lidar_truth(kitti_root, tmp_path, capsys):
    truth_path = tmp_path / "truth.npz"
    _truth(["--kitti", str(kitti_root), "--sequence", "07", "--frames", "0:2"], tmp_path, capsys)
    # the map of frame 0 alone: its voxels are right, frame 1's new voxels score as its prior 0.5
    grid = lidar_reference_map(kitti_lidar_scans(KittiOdometry(kitti_root, 7), frames=[0]), VOXEL, progress=False)
    save_map(grid, tmp_path / "map.npz")
    assert main(["evaluate", "--map", str(tmp_path / "map.npz"), "--gt", str(truth_path)]) == 0
    capsys.readouterr()
    scores = json.loads((tmp_path / "map.scores.json").read_text())["scores"]
    truth = read_ground_truth(truth_path)
    assert scores["n_voxels"] == len(truth.observed_keys)
    assert scores["n_occupied"] == len(truth.observed_occupied_keys)
    assert scores["occupied_called_free"] == 0 and scores["free_called_occupied"] == 0
    # Brier score by hand: voxels the map never saw (frame 1's) count at its prior 0.5
    probability = grid.probability_at_keys(truth.observed_keys)
    occupied = (truth.observed_keys[:, None] == truth.occupied_keys[None]).all(axis=2).any(axis=1)
    unseen = grid.lookup_keys(truth.observed_keys)[1] == 0
    assert unseen.sum() > 100 and np.all(probability[unseen] == 0.5)
    assert scores["brier"] == pytest.approx(np.mean((probability - occupied) ** 2), rel=1e-9)


def test_in_camera_view_against_the_projection():
    camera = StereoCamera(F, CX, CY, 0.54, width=W, height=H)
    rng = np.random.default_rng(7)
    points = rng.uniform([-6, -5, -2], [6, 5, 5], size=(2000, 3))
    pixels = points @ K.T
    u, v = pixels[:, 0] / pixels[:, 2], pixels[:, 1] / pixels[:, 2]
    expected = (points[:, 2] > 0) & (np.round(u) >= 0) & (np.round(u) < W) & (np.round(v) >= 0) & (np.round(v) < H)
    np.testing.assert_array_equal(in_camera_view(points, camera), expected)


def _error(args, capsys):
    assert main(["lidar-truth", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err
    return err


def test_errors_are_one_line_with_exit_status_2(kitti_root, raw_drive, tmp_path, capsys):
    out = ["--out", str(tmp_path / "t.npz")]
    kitti = ["--kitti", str(kitti_root), "--sequence", "07", *out]
    assert "`--voxel` must be a finite number > 0; got 0.0" in _error([*kitti, "--voxel", "0"], capsys)
    assert "no frame of the 3" in _error([*kitti, "--voxel", "0.1", "--frames", "5:"], capsys)
    assert "range is empty" in _error([*kitti, "--voxel", "0.1", "--frames", "2:1"], capsys)
    assert "`--max-range` must be a finite number > 0" in _error(
        [*kitti, "--voxel", "0.1", "--max-range", "-1"], capsys
    )
    assert "--every must be >= 1" in _error([*kitti, "--voxel", "0.1", "--every", "0"], capsys)
    assert "a raw drive has no camera poses; give --poses" in _error(
        ["--raw", str(raw_drive), "--voxel", "0.1", *out], capsys
    )
    bad_poses = tmp_path / "poses.txt"
    bad_poses.write_text(_pose_lines(POSES_CAM2[:2]))
    assert "2 poses for 3 frames" in _error(
        ["--raw", str(raw_drive), "--poses", str(bad_poses), "--voxel", "0.1", *out], capsys
    )
    assert "--kitti needs --sequence" in _error(["--kitti", str(kitti_root), "--voxel", "0.1", *out], capsys)
    poses = kitti_root / "poses" / "07.txt"
    poses.rename(poses.with_name("hidden.txt"))
    try:
        assert "sequence 07 has no poses/07.txt" in _error([*kitti, "--voxel", "0.1"], capsys)
    finally:
        poses.with_name("hidden.txt").rename(poses)
    velodyne = kitti_root / "sequences" / "07" / "velodyne"
    velodyne.rename(velodyne.with_name("hidden"))
    try:
        assert "velodyne: Velodyne scan folder not found" in _error([*kitti, "--voxel", "0.1"], capsys)
    finally:
        velodyne.with_name("hidden").rename(velodyne)
    assert not (tmp_path / "t.npz").exists()


def test_kitti_lidar_scans_input_errors(kitti_root):
    from prismap.errors import PrismapInputError

    sequence = KittiOdometry(kitti_root, 7)
    with pytest.raises(PrismapInputError, match=r"`frames` must lie in 0..2 \(the sequence's frames\); got 3"):
        kitti_lidar_scans(sequence, frames=[0, 3])
    with pytest.raises(PrismapInputError, match="`frames` is empty"):
        kitti_lidar_scans(sequence, frames=[])
    with pytest.raises(PrismapInputError, match=r"`poses` must be \(3, 4, 4\), one pose per frame .* got \(2, 4, 4\)"):
        kitti_lidar_scans(sequence, poses=np.stack(POSES_CAM2[:2]))
    with pytest.raises(PrismapInputError, match="the KITTI sequence has no poses"):
        kitti_lidar_scans(KittiOdometry(kitti_root, 7, load_poses=False))
    scans = kitti_lidar_scans(sequence, frames=[2], camera_view=False)
    points, T_world_sensor = scans[0]
    # the sensor frame: the laser's origin, the colour camera's axes
    np.testing.assert_allclose(T_world_sensor[:3, 3], _T_world_velo(2)[:3, 3], atol=1e-12)
    np.testing.assert_allclose(T_world_sensor[:3, :3], POSES_CAM2[2][:3, :3], atol=1e-12)
    world = points @ T_world_sensor[:3, :3].T + T_world_sensor[:3, 3]
    np.testing.assert_allclose(world, np.vstack([_wall_points(2), _behind_points(2)]), atol=1e-5)  # float32 scan


def test_a_voxel_of_0_1_mm_is_refused_in_bounded_memory(kitti_root, tmp_path):
    """``--voxel 1e-4``: every laser ray crosses ~5e4 voxels; under a 3 GB address-space cap the frame
    accumulator's bound refuses the frame (exit 2, one line) instead of running out of memory."""
    import subprocess
    import sys
    import textwrap

    out = tmp_path / "t.npz"
    script = textwrap.dedent(f"""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))
        from prismap.cli import main
        sys.exit(main(["lidar-truth", "--kitti", {str(kitti_root)!r}, "--sequence", "07", "--voxel", "1e-4",
                       "--out", {str(out)!r}]))
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, check=False)
    err = run.stderr.strip()
    assert run.returncode == 2, err[-2000:]
    assert err.count("\n") == 0 and "the frame accumulator's bound" in err and "`voxel_size_m`" in err
    assert not out.exists()
