"""KITTI-layout sequences on disk: write -> read round trips and the errors of broken directories."""

import cv2
import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.io import StereoFrame
from prismap.io._sequence import GroundTruthOccupancy, read_ground_truth, read_sequence, write_sequence

CAMERA = StereoCamera(120.5, 15.25, 9.75, 0.25, doffs_px=1.5, width=32, height=20)


def _frames(n=3, *, colour=True, seed=0):
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        shape = (20, 32, 3) if colour else (20, 32)
        disparity = rng.uniform(0.5, 200.0, (20, 32)).astype(np.float32)
        disparity[rng.random((20, 32)) < 0.2] = np.nan
        pose = np.eye(4)
        pose[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        pose[:3, 3] = rng.normal(size=3) * 10
        left, right = (rng.integers(0, 256, shape, dtype=np.uint8) for _ in range(2))
        frames.append(StereoFrame(left, right, CAMERA, disparity, pose, name=f"f{i}"))
    return frames


def _truth():
    occupied = np.array([[0, 0, 0], [1, -2, 3], [-5, 4, 0]])
    observed = np.array([[0, 0, 0], [1, 1, 1], [2, 1, 1], [-5, 4, 0]])
    return GroundTruthOccupancy(0.05, occupied, observed)


def test_round_trip_of_a_short_sequence(tmp_path):
    frames = _frames()
    assert write_sequence(frames, tmp_path, occupancy=_truth()) == 3
    seq = read_sequence(tmp_path)
    assert len(seq) == 3 and seq.names == ["000000.png", "000001.png", "000002.png"]
    assert seq.camera == CAMERA
    for original, frame in zip(frames, seq):
        np.testing.assert_array_equal(frame.left, original.left)
        np.testing.assert_array_equal(frame.right, original.right)
        np.testing.assert_array_equal(frame.T_world_cam, original.T_world_cam)  # %.17g is exact
        np.testing.assert_array_equal(np.isnan(frame.disparity_gt), np.isnan(original.disparity_gt))
        np.testing.assert_allclose(frame.disparity_gt, original.disparity_gt, atol=0.5 / 256, equal_nan=True)
        assert frame.camera == CAMERA and frame.disparity_gt.dtype == np.float32
    np.testing.assert_array_equal(seq.poses, np.array([f.T_world_cam for f in frames]))
    np.testing.assert_array_equal(seq[-1].left, frames[-1].left)
    truth = seq.ground_truth
    assert truth.voxel_size_m == 0.05
    np.testing.assert_array_equal(truth.free_keys, [[1, 1, 1], [2, 1, 1]])
    np.testing.assert_array_equal(truth.observed_occupied_keys, [[-5, 4, 0], [0, 0, 0]])
    with pytest.raises(IndexError):
        seq[3]


def test_calibration_follows_kitti_projection_matrices(tmp_path):
    write_sequence(_frames(1), tmp_path)
    rows = {
        line.split(":")[0]: np.array(line.split()[1:], float).reshape(3, 4)
        for line in (tmp_path / "calib.txt").read_text().splitlines()
    }
    assert sorted(rows) == ["P0", "P1", "P2", "P3"]
    p2, p3 = rows["P2"], rows["P3"]
    assert (p2[0, 3] - p3[0, 3]) / p2[0, 0] == pytest.approx(0.25)
    assert p3[0, 2] - p2[0, 2] == pytest.approx(1.5) and p2[1, 2] == 9.75
    png = cv2.imread(str(tmp_path / "disp" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16 and (png == 0).any()


def test_grey_frames_without_pose_or_disparity(tmp_path):
    frames = [StereoFrame(f.left, f.right, CAMERA) for f in _frames(2, colour=False)]
    write_sequence(frames, tmp_path)
    seq = read_sequence(tmp_path)
    assert seq.poses is None and seq.ground_truth is None
    frame = seq[1]
    assert frame.left.shape == (20, 32) and frame.disparity_gt is None and frame.T_world_cam is None
    np.testing.assert_array_equal(frame.right, frames[1].right)


def test_ground_truth_file_round_trip_and_errors(tmp_path):
    from prismap.io._sequence import write_ground_truth

    path = tmp_path / "occupancy.npz"
    write_ground_truth(path, _truth())
    back = read_ground_truth(path)
    np.testing.assert_array_equal(back.occupied_keys, _truth().occupied_keys)
    np.testing.assert_array_equal(back.observed_keys, _truth().observed_keys)
    np.savez(
        tmp_path / "other.npz",
        format=np.array("prismap-ground-truth-occupancy"),
        version=np.array(7),
        voxel_size_m=np.array(0.1),
        occupied_keys=np.zeros((0, 3), int),
        observed_keys=np.zeros((0, 3), int),
    )
    with pytest.raises(PrismapInputError, match="other.npz: expected format .* version 1; got .* version 7"):
        read_ground_truth(tmp_path / "other.npz")
    np.savez(tmp_path / "short.npz", voxel_size_m=np.array(0.1))
    with pytest.raises(PrismapInputError, match="short.npz: ground-truth occupancy file lacks field"):
        read_ground_truth(tmp_path / "short.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(PrismapInputError, match="junk.npz: not a readable .npz"):
        read_ground_truth(tmp_path / "junk.npz")
    with pytest.raises(PrismapInputError, match="`occupied_keys` must be an \\(N, 3\\) integer array"):
        GroundTruthOccupancy(0.1, np.zeros((2, 2), int), np.zeros((0, 3), int))
    with pytest.raises(
        PrismapInputError,
        match=r"`observed_keys` must lie in \[-1048576, 1048576\) \(\+-104858 m at 0.1 m voxels\); got values in \[0, 1048576\]",
    ):
        GroundTruthOccupancy(0.1, np.zeros((0, 3), int), np.array([[0, 1 << 20, 0]]))


def test_ground_truth_keys_are_sorted_and_unique():
    keys = np.array([[2, 0, 0], [-1, 5, 5], [2, 0, 0], [-1, 5, -7], [0, -3, 9]])
    truth = GroundTruthOccupancy(0.1, keys, keys[:2])
    np.testing.assert_array_equal(truth.occupied_keys, np.unique(keys, axis=0))
    np.testing.assert_array_equal(truth.observed_keys, [[-1, 5, 5], [2, 0, 0]])
    assert truth.free_keys.shape == (0, 3)


def _written(tmp_path, n=2):
    write_sequence(_frames(n), tmp_path)
    return tmp_path


def _replace_line(path, number, text):
    lines = path.read_text().splitlines()
    lines[number - 1] = text
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda d: _replace_line(d / "calib.txt", 4, "P3: 1 2 3"), "calib.txt: field P3 must have 12 numbers; got 3"),
        (
            lambda d: _replace_line(d / "calib.txt", 4, "Q3: 1 2 3"),
            r"calib.txt: missing field P3; found \['P0', 'P1', 'P2', 'Q3'\]",
        ),
        (
            lambda d: _replace_line(d / "calib.txt", 3, "P2: 1 2 x 4"),
            "calib.txt line 3, field P2: expected numbers; got '1 2 x 4'",
        ),
        (
            lambda d: _replace_line(d / "calib.txt", 2, "no colon here"),
            "calib.txt line 2: expected 'name: numbers'; got 'no colon here'",
        ),
        (lambda d: (d / "calib.txt").unlink(), "calib.txt: KITTI calibration file not found"),
        (
            lambda d: _replace_line(d / "poses.txt", 2, "1 0 0 0 0 1 0 0 0 0 1"),
            r"poses.txt line 2: expected 12 numbers \(3x4 pose\); got 11",
        ),
        (
            lambda d: _replace_line(d / "poses.txt", 1, "1 0 0 nan 0 1 0 0 0 0 1 0"),
            "poses.txt line 1: numbers must be finite",
        ),
        (
            lambda d: _replace_line(d / "poses.txt", 1, "1 0 0 a 0 1 0 0 0 0 1 0"),
            "poses.txt line 1: expected numbers; got '1 0 0 a 0 1 0 0 0 0 1 0'",
        ),
        (lambda d: (d / "poses.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n"), "poses.txt: 1 poses for 2 frames"),
        (
            lambda d: (d / "image_3" / "000001.png").unlink(),
            r"image_3: missing 1 right image\(s\), first \'000001.png\'",
        ),
        (
            lambda d: cv2.imwrite(str(d / "image_3" / "000001.png"), np.zeros((21, 32), np.uint8)),
            "image_3/000001.png: image size 32x21 differs from .*image_2/000000.png \\(32x20\\)",
        ),
        (
            lambda d: (d / "image_2" / "000001.png").write_bytes(b"GIF89a" + bytes(30)),
            r"image_2/000001.png: left image is not a PNG file \(bad or truncated header\)",
        ),
        (lambda d: [p.unlink() for p in (d / "image_2").glob("*.png")], r"image_2: no files matching \'\*.png\'"),
    ],
)
def test_broken_sequences_are_reported_on_opening(tmp_path, damage, message):
    damage(_written(tmp_path))
    with pytest.raises(PrismapInputError, match=message):
        read_sequence(tmp_path)


def test_broken_images_are_reported_on_access(tmp_path):
    directory = _written(tmp_path)
    data = (directory / "image_2" / "000001.png").read_bytes()
    (directory / "image_2" / "000001.png").write_bytes(data[:40])
    cv2.imwrite(str(directory / "disp" / "000000.png"), np.zeros((20, 32), np.uint8))
    seq = read_sequence(directory)
    with pytest.raises(
        PrismapInputError, match=r"image_2/000001.png: left image cannot be decoded \(truncated or corrupt PNG\)"
    ):
        seq[1]
    with pytest.raises(
        PrismapInputError,
        match="disp/000000.png: ground-truth disparity must be a single-channel uint16 PNG; got 1-channel uint8",
    ):
        seq[0]
    with pytest.raises(PrismapInputError, match="sequence directory not found"):
        read_sequence(directory / "nowhere")


def test_write_rejects_inconsistent_frames(tmp_path):
    frames = _frames(2)
    other = StereoCamera(100.0, 15.25, 9.75, 0.25, width=32, height=20)
    mixed = [
        frames[0],
        StereoFrame(frames[1].left, frames[1].right, other, frames[1].disparity_gt, frames[1].T_world_cam),
    ]
    with pytest.raises(PrismapInputError, match="`frames\\[1\\]` has another camera"):
        write_sequence(mixed, tmp_path / "a")
    no_pose = [frames[0], StereoFrame(frames[1].left, frames[1].right, CAMERA, frames[1].disparity_gt)]
    with pytest.raises(PrismapInputError, match="`frames\\[1\\]`: poses and ground-truth disparities"):
        write_sequence(no_pose, tmp_path / "b")
    with pytest.raises(PrismapInputError, match="`frames` is empty"):
        write_sequence([], tmp_path / "c")
    with pytest.raises(PrismapInputError, match="`frames\\[0\\]` must be a StereoFrame"):
        write_sequence([np.zeros((2, 2))], tmp_path / "d")
    big = StereoFrame(
        frames[0].left, frames[0].right, CAMERA, np.full((20, 32), 300.0, np.float32), frames[0].T_world_cam
    )
    with pytest.raises(PrismapInputError, match="reaches 300.00 px; the uint16 x 256 format stores at most 255.99"):
        write_sequence([big], tmp_path / "e")


def _tree(directory):
    """{relative path: bytes} of every file below ``directory``."""
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def _streamed(frames, bad_index, bad):
    """Frames one by one (as a simulator streams them), frame ``bad_index`` replaced by ``bad(frame)``."""
    for index, frame in enumerate(frames):
        yield bad(frame) if index == bad_index else frame


BAD_LATER_FRAMES = {
    "4-channel image": lambda f: StereoFrame(
        np.dstack([f.left, f.left[:, :, :1]]), f.right, CAMERA, f.disparity_gt, f.T_world_cam
    ),
    "disparity too large": lambda f: StereoFrame(
        f.left, f.right, CAMERA, np.full((20, 32), 300.0, np.float32), f.T_world_cam
    ),
    "other camera": lambda f: StereoFrame(
        f.left, f.right, StereoCamera(99.0, 15.25, 9.75, 0.25), f.disparity_gt, f.T_world_cam
    ),
}


@pytest.mark.parametrize("bad", BAD_LATER_FRAMES.values(), ids=BAD_LATER_FRAMES.keys())
def test_a_bad_later_frame_leaves_no_partial_output(tmp_path, bad):
    """Issue 7: frames 0 and 1 are fine, frame 2 is not; nothing may appear, in a new or an existing directory."""
    with pytest.raises(PrismapInputError, match="frames\\[2\\]"):
        write_sequence(_streamed(_frames(3), 2, bad), tmp_path / "new", occupancy=_truth())
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # neither the sequence nor the staging directory
    existing = tmp_path / "existing"
    write_sequence(_frames(2, seed=5), existing)
    before = _tree(existing)
    with pytest.raises(PrismapInputError, match="frames\\[2\\]"):
        write_sequence(_streamed(_frames(3), 2, bad), existing, occupancy=_truth())
    assert _tree(existing) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing"]


def test_an_interrupted_write_leaves_no_partial_output(tmp_path):
    def interrupted():
        yield from _frames(2)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_sequence(interrupted(), tmp_path / "seq")
    assert list(tmp_path.iterdir()) == []


def test_writing_into_a_used_directory_replaces_same_names_and_keeps_others(tmp_path):
    write_sequence(_frames(3, seed=1), tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    frames = _frames(3, seed=2)
    write_sequence(frames, tmp_path)
    assert (tmp_path / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.parent.iterdir() if p.name.startswith(f".{tmp_path.name}.")) == []
    seq = read_sequence(tmp_path)
    for original, frame in zip(frames, seq):
        np.testing.assert_array_equal(frame.left, original.left)
        np.testing.assert_array_equal(frame.T_world_cam, original.T_world_cam)
    with pytest.raises(PrismapInputError, match="notes.txt: exists and is not a directory"):
        write_sequence(frames, tmp_path / "notes.txt")


def test_sequence_camera_is_the_kitti_reader_camera(tmp_path):
    """calib.txt goes through read_kitti_calib and from_kitti_projections: doffs = P3[0, 2] - P2[0, 2]."""
    from prismap.io import read_kitti_calib

    write_sequence(_frames(1), tmp_path)
    calib = read_kitti_calib(tmp_path / "calib.txt")
    expected = StereoCamera.from_kitti_projections(
        calib["P2"].reshape(3, 4), calib["P3"].reshape(3, 4), width=32, height=20
    )
    assert read_sequence(tmp_path).camera == expected == CAMERA
    assert calib["P3"][2] - calib["P2"][2] == CAMERA.doffs_px


def test_random_cameras_round_trip_through_calib_txt(tmp_path):
    rng = np.random.default_rng(11)
    image = np.zeros((4, 6), np.uint8)
    for trial in range(20):
        camera = StereoCamera(
            rng.uniform(100, 2000),
            rng.uniform(0, 600),
            rng.uniform(0, 400),
            rng.uniform(0.01, 1.0),
            doffs_px=rng.uniform(-5, 50),
            width=6,
            height=4,
        )
        write_sequence([StereoFrame(image, image, camera)], tmp_path / str(trial))
        back = read_sequence(tmp_path / str(trial)).camera
        for field in ("focal_px", "cx_px", "cy_px", "baseline_m", "doffs_px"):
            # %.17g is exact; b = (f b) / f and doffs = (cx + doffs) - cx cost at most a few ulps
            assert getattr(back, field) == pytest.approx(getattr(camera, field), rel=1e-13, abs=1e-12), field
