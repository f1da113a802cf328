"""New Tsukuba reader on small files written in the published layout, and its error messages."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from prismap.errors import PrismapInputError
from prismap.io._tsukuba import (
    TSUKUBA_CAMERA,
    NewTsukuba,
    read_tsukuba_depth,
    read_tsukuba_disparity,
    read_tsukuba_track,
)

TRACK = np.array([[100.0, 200.0, 300.0, 0.0, 0.0, 0.0], [-5.5, 12.0, 40.0, 10.0, -20.0, 35.0], [0, 0, 0, 1, 2, 3]])


def _write_xml(path, depth_cm):
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("depth", depth_cm)
    storage.release()


def test_track_identity_by_hand(tmp_path):
    path = tmp_path / "camera_track.txt"
    path.write_text("100, 200, 300, 0, 0, 0\n")
    (T,) = read_tsukuba_track(path)
    # world y, z negated; the left camera sits 5 cm to the left (-x) of the rig centre
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], [0.95, -2.0, -3.0])


def test_track_matches_published_converter(tmp_path):
    path = tmp_path / "camera_track.txt"
    path.write_text("".join(", ".join(f"{v:g}" for v in row) + "\n" for row in TRACK))
    poses = read_tsukuba_track(path)
    flip = np.diag([1.0, -1, -1, 1])
    for row, T in zip(TRACK, poses):
        rig = np.eye(4)
        rig[:3, :3] = Rotation.from_euler("xyz", row[3:], degrees=True).as_matrix()  # static x, y, z
        rig[:3, 3] = row[:3] / 100
        left = np.eye(4)
        left[0, 3] = -0.05
        np.testing.assert_allclose(T, flip @ rig @ flip @ left, atol=1e-12)
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    # spaces instead of commas read the same
    path.write_text("".join(" ".join(f"{v:g}" for v in row) + "\n" for row in TRACK))
    np.testing.assert_allclose(read_tsukuba_track(path), poses)


def test_depth_and_disparity_maps(tmp_path):
    depth_cm = np.array([[100.0, 250.5], [615.0, 1230.0]], dtype=np.float32)
    _write_xml(tmp_path / "d.xml", depth_cm)
    np.testing.assert_allclose(read_tsukuba_depth(tmp_path / "d.xml"), depth_cm / 100.0)
    cv2.imwrite(str(tmp_path / "disp.png"), np.array([[0, 61], [5, 255]], np.uint8))
    disparity = read_tsukuba_disparity(tmp_path / "disp.png")
    assert disparity.dtype == np.float32 and np.isnan(disparity[0, 0])
    np.testing.assert_array_equal(disparity.ravel()[1:], [61, 5, 255])


@pytest.fixture
def dataset(tmp_path):
    root = tmp_path / "NewTsukubaStereoDataset"
    rng = np.random.default_rng(0)
    for side in ("left", "right"):
        folder = root / "illumination" / "lamps" / side
        folder.mkdir(parents=True)
        for number in (2, 3):
            image = rng.integers(0, 256, size=(4, 6, 3), dtype=np.uint8)
            cv2.imwrite(str(folder / f"tsukuba_lamps_{side[0].upper()}_{number:05d}.png"), image)
    truth = root / "groundtruth"
    (truth / "disparity_maps" / "left").mkdir(parents=True)
    (truth / "depth_maps" / "left").mkdir(parents=True)
    for number in (2, 3):
        cv2.imwrite(
            str(truth / "disparity_maps/left" / f"tsukuba_disparity_L_{number:05d}.png"),
            np.full((4, 6), 30 + number, np.uint8),
        )
        _write_xml(
            truth / "depth_maps/left" / f"tsukuba_depth_L_{number:05d}.xml", np.full((4, 6), 100.0 * number, np.float32)
        )
    (truth / "camera_track.txt").write_text("".join(", ".join(f"{v:g}" for v in row) + "\n" for row in TRACK))
    return root


def test_sequence(dataset):
    seq = NewTsukuba(dataset, illumination="lamps")
    assert len(seq) == 2
    frame = seq[0]
    raw = cv2.imread(str(dataset / "illumination/lamps/left/tsukuba_lamps_L_00002.png"))
    np.testing.assert_array_equal(frame.left, raw[..., ::-1])
    np.testing.assert_array_equal(frame.disparity_gt, np.full((4, 6), 32.0))
    np.testing.assert_allclose(frame.T_world_cam, read_tsukuba_track(dataset / "groundtruth/camera_track.txt")[1])
    assert frame.name == "tsukuba/lamps/00002" and frame.camera.width == 6
    assert frame.camera.focal_px == 615 and frame.camera.baseline_m == 0.1 and TSUKUBA_CAMERA.cx_px == 320
    by_depth = NewTsukuba(dataset, illumination="lamps", ground_truth="depth")[1]
    np.testing.assert_allclose(by_depth.disparity_gt, 61.5 / 3.0, rtol=1e-6)  # f b / z = 615 * 0.1 / 3 m
    assert NewTsukuba(dataset, illumination="lamps", ground_truth=None)[1].disparity_gt is None


def test_sequence_errors(dataset):
    with pytest.raises(PrismapInputError, match="`ground_truth` must be one of"):
        NewTsukuba(dataset, illumination="lamps", ground_truth="lidar")
    with pytest.raises(PrismapInputError, match="daylight/left: no images named like tsukuba_daylight_L_00001.png"):
        NewTsukuba(dataset)
    (dataset / "groundtruth/disparity_maps/left/tsukuba_disparity_L_00003.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    with pytest.raises(PrismapInputError, match="tsukuba_disparity_L_00003.png: Tsukuba disparity cannot be decoded"):
        NewTsukuba(dataset, illumination="lamps")[1]
    (dataset / "groundtruth/camera_track.txt").write_text("0, 0, 0, 0, 0, 0\n")
    with pytest.raises(PrismapInputError, match="1 poses do not cover frames 2-3"):
        NewTsukuba(dataset, illumination="lamps")
    (dataset / "illumination/lamps/right/tsukuba_lamps_R_00003.png").unlink()
    with pytest.raises(PrismapInputError, match=r"missing 1 right image\(s\), first tsukuba_lamps_R_00003.png"):
        NewTsukuba(dataset, illumination="lamps")


@pytest.mark.parametrize(
    "text, match",
    [
        ("1, 2, 3, 4, 5\n", r"line 1: expected 6 numbers \(X, Y, Z, A, B, C\); got 5"),
        ("1, 2, 3, 4, 5, 6\n1, 2, 3, 4, 5, 6, 7\n", "line 2: expected 6 numbers"),
        ("1, 2, 3, nan, 5, 6\n", "line 1: numbers must be finite"),
        ("1, 2, 3, 4, 5, six\n", "line 1: expected numbers"),
        ("\n", "camera track is empty"),
    ],
)
def test_track_errors(tmp_path, text, match):
    path = tmp_path / "camera_track.txt"
    path.write_text(text)
    with pytest.raises(PrismapInputError, match=match):
        read_tsukuba_track(path)


def test_depth_errors(tmp_path):
    path = tmp_path / "d.xml"
    with pytest.raises(PrismapInputError, match="d.xml: Tsukuba depth map not found"):
        read_tsukuba_depth(path)
    path.write_bytes(b"\x00garbage")
    with pytest.raises(PrismapInputError, match="d.xml: Tsukuba depth map is not a readable OpenCV XML file"):
        read_tsukuba_depth(path)
    path.write_text('<?xml version="1.0"?>\n<opencv_storage>\n<other>3</other>\n</opencv_storage>\n')
    with pytest.raises(PrismapInputError, match="must hold a 2-D single-channel matrix named 'depth'"):
        read_tsukuba_depth(path)
    _write_xml(path, np.zeros((2, 2, 3), np.float32))
    with pytest.raises(PrismapInputError, match="matrix named 'depth'"):
        read_tsukuba_depth(path)
    _write_xml(path, np.array([[100.0, -1.0]], np.float32))
    with pytest.raises(PrismapInputError, match=r"depths must be finite and > 0; got values in \[-0.01, 1.0\] m"):
        read_tsukuba_depth(path)


def test_disparity_of_wrong_type(tmp_path):
    cv2.imwrite(str(tmp_path / "d.png"), np.full((2, 2), 300, np.uint16))
    with pytest.raises(
        PrismapInputError, match="Tsukuba disparity must be a single-channel uint8 PNG; got 1-channel uint16"
    ):
        read_tsukuba_disparity(tmp_path / "d.png")
