"""KITTI readers on small files written in the exact KITTI layouts, and their error messages."""

import cv2
import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.io._images import with_image_size
from prismap.io._kitti import KittiOdometry, KittiRaw, read_kitti_calib, read_kitti_disparity, read_kitti_poses
from prismap.io._sequence import read_sequence
from prismap.io._velodyne import read_velodyne_bin, velodyne_to_camera

F, CX, CY = 700.0, 600.0, 180.0
K = np.array([[F, 0, CX], [0, F, CY], [0, 0, 1.0]])
T2 = np.array([0.06, -0.001, 0.004])  # camera 2 in rectified camera-0 coordinates: x2 = x0 + T2
T3 = np.array([-0.48, 0.002, 0.003])


def _projection(t):
    return K @ np.hstack([np.eye(3), t[:, None]])


def _rotation(rx, ry, rz):
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


TR = np.hstack([_rotation(-1.57, 0.01, -1.56), [[0.01], [-0.07], [-0.3]]])  # velodyne -> camera 0
POSES = [np.hstack([_rotation(0.01 * i, 0.1 * i, -0.02 * i), [[i], [0.1 * i], [2.0 * i]]]) for i in range(3)]


def _line(name, matrix):
    return f"{name}: " + " ".join(f"{v:.12e}" for v in np.ravel(matrix)) + "\n"


def _images(folder, names, seed):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    images = []
    for name in names:
        image = rng.integers(0, 256, size=(6, 10, 3), dtype=np.uint8)
        cv2.imwrite(str(folder / name), image)
        images.append(image)
    return images


@pytest.fixture
def odometry(tmp_path):
    seq = tmp_path / "sequences" / "04"
    seq.mkdir(parents=True)
    (seq / "calib.txt").write_text(
        _line("P0", _projection(np.zeros(3)))
        + _line("P1", _projection(np.array([-0.54, 0, 0])))
        + _line("P2", _projection(T2))
        + _line("P3", _projection(T3))
        + _line("Tr", TR)
    )
    names = [f"{i:06d}.png" for i in range(3)]
    left = _images(seq / "image_2", names, 0)
    _images(seq / "image_3", names, 1)
    (tmp_path / "poses").mkdir()
    (tmp_path / "poses" / "04.txt").write_text("".join(" ".join(f"{v:.12e}" for v in p.ravel()) + "\n" for p in POSES))
    (seq / "velodyne").mkdir()
    scan = np.array([[5.0, 1.0, -0.5, 0.3], [12.0, -3.0, 1.0, 0.9]], dtype=np.float32)
    scan.tofile(seq / "velodyne" / "000001.bin")
    return tmp_path, left, scan


def test_odometry_frames_camera_and_poses(odometry):
    root, left_bgr, _ = odometry
    seq = KittiOdometry(root, "04")
    assert len(seq) == 3 and len(list(seq)) == 3
    assert seq.camera.focal_px == F and seq.camera.cx_px == CX and seq.camera.cy_px == CY
    assert seq.camera.baseline_m == pytest.approx(0.54)
    frame = seq[-2]
    np.testing.assert_array_equal(frame.left, left_bgr[1][..., ::-1])  # BGR on disk, RGB in memory
    assert frame.camera.width == 10 and frame.camera.height == 6
    assert frame.name.endswith("04/000001")
    # a world point projects to the same pixel through P2 from camera 0 and through K from our camera-2 pose
    X = np.array([3.0, -1.0, 15.0, 1.0])
    for T_world_cam0, T_world_cam in zip(POSES, seq.poses):
        x0 = np.linalg.inv(np.vstack([T_world_cam0, [0, 0, 0, 1]])) @ X
        expected = _projection(T2) @ x0
        ours = K @ (np.linalg.inv(T_world_cam) @ X)[:3]
        np.testing.assert_allclose(ours[:2] / ours[2], expected[:2] / expected[2], atol=1e-9)
    np.testing.assert_allclose(
        seq.poses[0][:3, 3], -T2, atol=1e-12
    )  # first frame: camera 2 offset from the world origin


def test_odometry_velodyne_matches_devkit_projection(odometry):
    root, _, scan = odometry
    seq = KittiOdometry(root, 4)
    points = seq.velodyne(1)
    assert points.shape == (2, 3) and points.dtype == np.float64
    # devkit: pixel = P2 @ Tr @ X_velo
    expected = _projection(T2) @ np.vstack([TR, [0, 0, 0, 1]]) @ np.c_[scan[:, :3], np.ones(2)].T
    ours = K @ points.T
    np.testing.assert_allclose(ours[:2] / ours[2], expected[:2] / expected[2], atol=1e-6)
    np.testing.assert_allclose(
        points, velodyne_to_camera(read_velodyne_bin(root / "sequences/04/velodyne/000001.bin"), seq.T_cam_velo)
    )


def test_odometry_without_poses_or_tr(odometry):
    root, _, _ = odometry
    (root / "poses" / "04.txt").unlink()
    calib = root / "sequences" / "04" / "calib.txt"
    calib.write_text("".join(line for line in calib.read_text().splitlines(True) if not line.startswith("Tr")))
    seq = KittiOdometry(root, 4)
    assert seq.poses is None and seq[0].T_world_cam is None
    with pytest.raises(PrismapInputError, match="no Velodyne transform"):
        seq.velodyne(1)


def test_raw_drive(tmp_path):
    date = tmp_path / "2011_09_26"
    drive = date / "2011_09_26_drive_0001_sync"
    R_rect = _rotation(0.01, -0.02, 0.005)
    (date).mkdir()
    (date / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\ncorner_dist: 9.950000e-02\n"
        + _line("R_rect_00", R_rect)
        + _line("P_rect_02", _projection(T2))
        + _line("P_rect_03", _projection(T3))
    )
    (date / "calib_velo_to_cam.txt").write_text(
        "calib_time: 15-Mar-2012 11:37:16\n" + _line("R", TR[:, :3]) + _line("T", TR[:, 3]) + "delta_f: 0 0\n"
    )
    names = ["0000000000.png", "0000000001.png"]
    _images(drive / "image_02" / "data", names, 2)
    _images(drive / "image_03" / "data", names, 3)
    (drive / "velodyne_points" / "data").mkdir(parents=True)
    scan = np.array([[8.0, 2.0, -1.0, 0.5]], dtype=np.float32)
    scan.tofile(drive / "velodyne_points" / "data" / "0000000001.bin")
    seq = KittiRaw(drive)
    assert len(seq) == 2 and seq.poses is None
    assert seq.camera.baseline_m == pytest.approx(0.54)
    expected = (
        _projection(T2)
        @ np.vstack([np.c_[R_rect, np.zeros(3)], [0, 0, 0, 1]])
        @ np.vstack([TR, [0, 0, 0, 1]])
        @ [8, 2, -1, 1]
    )
    ours = K @ seq.velodyne(1)[0]
    np.testing.assert_allclose(ours[:2] / ours[2], expected[:2] / expected[2], atol=1e-6)


def test_disparity_png_round_trip(tmp_path):
    truth = np.array([[0.0, 1.5], [100.25, 255.99609375]], dtype=np.float32)
    cv2.imwrite(str(tmp_path / "000000_10.png"), np.round(truth * 256).astype(np.uint16))
    disparity = read_kitti_disparity(tmp_path / "000000_10.png")
    assert disparity.dtype == np.float32 and np.isnan(disparity[0, 0])
    np.testing.assert_array_equal(disparity.ravel()[1:], truth.ravel()[1:])


def test_calib_reader_keeps_every_numeric_field(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text("calib_time: 09-Jan-2012 13:57:47\nS_02: 1.392000e+03 5.120000e+02\n\nP0: 1 2 3\n")
    calib = read_kitti_calib(path)
    assert set(calib) == {"S_02", "P0"}
    np.testing.assert_array_equal(calib["P0"], [1, 2, 3])


CALIB_ERRORS = [
    ("P0: 1 2 3\nP2: 1 2 x 4\n", r"line 2, field P2: expected numbers; got '1 2 x 4'"),
    ("P2: 1 2 nan\n", r"line 1, field P2: numbers must be finite"),
    ("P2 1 2 3\n", r"line 1: expected 'name: numbers'"),
    ("P2: 1\nP2: 2\n", "line 2: field P2 appears twice"),
]


@pytest.mark.parametrize("text, match", CALIB_ERRORS)
def test_calib_errors(tmp_path, text, match):
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(PrismapInputError, match=match) as info:
        read_kitti_calib(path)
    assert str(path) in str(info.value)


def test_calib_missing_or_short_field(odometry):
    root, _, _ = odometry
    calib = root / "sequences" / "04" / "calib.txt"
    lines = calib.read_text().splitlines(True)
    calib.write_text("".join(line for line in lines if not line.startswith("P3")))
    with pytest.raises(PrismapInputError, match=r"calib.txt: missing field P3; found \['P0', 'P1', 'P2', 'Tr'\]"):
        KittiOdometry(root, 4)
    calib.write_text("".join(lines).replace("P3: ", "P3: 1 "))
    with pytest.raises(PrismapInputError, match="field P3 must have 12 numbers; got 13"):
        KittiOdometry(root, 4)
    calib.write_text("".join(lines).replace("P3: 7", "P3: -7"))
    with pytest.raises(PrismapInputError, match="calib.txt: `P3` must be a rectified projection"):
        KittiOdometry(root, 4)


@pytest.mark.parametrize(
    "line, match",
    [
        ("1 0 0 0 0 1 0 0 0 0 1 nan", r"line 2: numbers must be finite"),
        ("1 0 0 0 0 1 0 0 0 0 1", r"line 2: expected 12 numbers \(3x4 pose\); got 11"),
        ("1 0 0 0 0 1 0 0 0 0 1 0 5", "got 13"),
        ("2 0 0 0 0 1 0 0 0 0 1 0", "line 2: rotation is not orthonormal"),
        ("-1 0 0 0 0 1 0 0 0 0 1 0", "line 2: rotation is not orthonormal with det"),
    ],
)
def test_pose_errors(tmp_path, line, match):
    path = tmp_path / "00.txt"
    path.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" + line + "\n")
    with pytest.raises(PrismapInputError, match=match):
        read_kitti_poses(path)


def test_pose_file_identity_and_empty(tmp_path):
    path = tmp_path / "00.txt"
    path.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 2 0 1 0 0 0 0 1 0\n\n")
    poses = read_kitti_poses(path)
    assert poses.shape == (2, 4, 4) and poses[1, 0, 3] == 2 and poses[1, 3, 3] == 1
    path.write_text("\n \n")
    with pytest.raises(PrismapInputError, match="pose file is empty"):
        read_kitti_poses(path)
    path.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(PrismapInputError, match=r"line 2: expected 12 numbers"):
        read_kitti_poses(path)


def test_sequence_errors(odometry):
    root, _, _ = odometry
    seq_dir = root / "sequences" / "04"
    with pytest.raises(PrismapInputError, match="`sequence` must be a sequence number"):
        KittiOdometry(root, "four")
    with pytest.raises(PrismapInputError, match="calib.txt: KITTI calibration file not found"):
        KittiOdometry(root, 5)
    with (root / "poses" / "04.txt").open("a") as handle:
        handle.write("1 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(PrismapInputError, match="4 poses for 3 frames"):
        KittiOdometry(root, 4)
    (root / "poses" / "04.txt").unlink()
    data = (seq_dir / "image_2" / "000002.png").read_bytes()
    (seq_dir / "image_2" / "000002.png").write_bytes(data[: len(data) // 2])
    seq = KittiOdometry(root, 4)
    with pytest.raises(
        PrismapInputError, match=r"000002.png: left image cannot be decoded \(truncated or corrupt PNG\)"
    ):
        seq[2]
    (seq_dir / "image_2" / "000002.png").write_bytes(b"GIF89a" + data)
    with pytest.raises(PrismapInputError, match="left image is not a PNG file"):
        seq[2]
    with pytest.raises(IndexError):
        seq[3]
    (seq_dir / "image_3" / "000001.png").unlink()
    with pytest.raises(PrismapInputError, match=r"image_3: missing 1 right image\(s\), first '000001.png'"):
        KittiOdometry(root, 4)


def test_disparity_and_velodyne_errors(tmp_path):
    cv2.imwrite(str(tmp_path / "d8.png"), np.full((2, 2), 7, np.uint8))
    with pytest.raises(
        PrismapInputError, match="d8.png: KITTI disparity must be a single-channel uint16 PNG; got 1-channel uint8"
    ):
        read_kitti_disparity(tmp_path / "d8.png")
    cv2.imwrite(str(tmp_path / "rgb16.png"), np.full((2, 2, 3), 7, np.uint16))
    with pytest.raises(PrismapInputError, match="got 3-channel uint16"):
        read_kitti_disparity(tmp_path / "rgb16.png")
    with pytest.raises(PrismapInputError, match="none.png: KITTI disparity not found"):
        read_kitti_disparity(tmp_path / "none.png")
    (tmp_path / "scan.bin").write_bytes(b"\0" * 36)
    with pytest.raises(
        PrismapInputError, match=r"scan.bin: velodyne scan size must be a multiple of 16 bytes .*got 36 bytes"
    ):
        read_velodyne_bin(tmp_path / "scan.bin")
    np.array([[0, 0, 0, 1], [np.nan, 0, 0, 1]], np.float32).tofile(tmp_path / "scan.bin")
    with pytest.raises(PrismapInputError, match="velodyne point 1 is not finite"):
        read_velodyne_bin(tmp_path / "scan.bin")
    with pytest.raises(PrismapInputError, match=r"`points_velo` must have shape \(N, 3\) or \(N, 4\)"):
        velodyne_to_camera(np.zeros((2, 2)), np.eye(4))


# ----------------------------------------------------------------------------- read_sequence on a KITTI download


def test_read_sequence_opens_a_kitti_odometry_sequence_with_kittiodometrys_poses(odometry):
    root, left_bgr, _ = odometry
    seq = read_sequence(root / "sequences" / "04")
    kitti = KittiOdometry(root, 4)
    assert seq.pose_path == root / "poses" / "04.txt"
    np.testing.assert_array_equal(seq.poses, kitti.poses)  # one conversion, shared
    for T_world_cam0, T_world_cam in zip(POSES, seq.poses):  # the colour camera sits at t2 in camera 0
        np.testing.assert_allclose(T_world_cam[:3, :3], T_world_cam0[:, :3], atol=1e-15)
        np.testing.assert_allclose(T_world_cam[:3, 3], T_world_cam0[:, 3] - T_world_cam0[:, :3] @ T2, atol=1e-12)
    assert seq.camera == with_image_size(kitti.camera, left_bgr[0])
    frame = seq[2]
    np.testing.assert_array_equal(frame.T_world_cam, kitti.poses[2])
    np.testing.assert_array_equal(frame.left, kitti[2].left)


def test_read_sequence_prefers_poses_txt_and_recognises_only_a_kitti_tree(odometry):
    root, _, _ = odometry
    seq_dir = root / "sequences" / "04"
    own = np.tile(np.eye(4), (3, 1, 1))
    own[:, :3, 3] = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
    (seq_dir / "poses.txt").write_text("".join(" ".join(map(str, p[:3].ravel())) + "\n" for p in own))
    seq = read_sequence(seq_dir)
    assert seq.pose_path == seq_dir / "poses.txt"
    np.testing.assert_array_equal(seq.poses, own)  # prismap's own file holds image_2 poses: no conversion
    (seq_dir / "poses.txt").unlink()
    renamed = root / "sequences" / "04a"  # not a KITTI sequence number: poses/04.txt is not looked up
    seq_dir.rename(renamed)
    (root / "poses" / "04a.txt").write_text((root / "poses" / "04.txt").read_text())
    assert read_sequence(renamed).poses is None and read_sequence(renamed).pose_path is None


def test_read_sequence_of_a_kitti_sequence_without_poses(odometry):
    root, _, _ = odometry
    (root / "poses" / "04.txt").rename(root / "poses" / "11.txt")
    seq = read_sequence(root / "sequences" / "04")  # like sequences 11-21: no pose file published
    assert seq.poses is None and seq.pose_path is None and seq[0].T_world_cam is None


@pytest.mark.parametrize(
    ("lines", "match"),
    [
        (lambda lines: lines[:2], r"poses[/\\]04\.txt: 2 poses for 3 frames"),
        (
            lambda lines: [lines[0], "1 0 0 0 0 2 0 0 0 0 1 0\n", lines[2]],
            r"04\.txt line 2: rotation is not orthonormal",
        ),
    ],
)
def test_read_sequence_kitti_pose_errors_name_the_pose_file(odometry, lines, match):
    root, _, _ = odometry
    path = root / "poses" / "04.txt"
    path.write_text("".join(lines(path.read_text().splitlines(True))))
    with pytest.raises(PrismapInputError, match=match):
        read_sequence(root / "sequences" / "04")
