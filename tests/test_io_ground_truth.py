"""open_ground_truth on every dataset kind, written small in its exact layout: frames, ground truth, selection,
the Velodyne projection against a hand-computed point, and one clear error per kind of bad input."""

import cv2
import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.io import (
    GroundTruthFrames,
    load_middlebury_motorcycle,
    open_ground_truth,
    points_to_disparity,
    write_disparity_png,
    write_pfm,
    write_sequence,
)
from prismap.io._frame import StereoFrame
from support import kitti_line, kitti_projection, shifted_pair, write_kitti_stereo

H, W = 6, 10
F_PX, CX, CY, BASELINE = 20.0, 4.2, 2.3, 0.54
T2 = np.array([0.06, 0.0, 0.0])  # colour camera 2 in rectified camera-0 coordinates: x2 = x0 + T2
# Velodyne -> camera 0: x0 = -y_v, y0 = -z_v - 0.08, z0 = x_v - 0.27 (KITTI's axes, a hand-checkable offset)
TR = np.array([[0, -1, 0, 0.0], [0, 0, -1, -0.08], [1, 0, 0, -0.27]])
# By hand: (10.27, -0.94, 0.42) -> camera 0 (0.94, -0.5, 10) -> camera 2 (1, -0.5, 10): u = 20 * 1 / 10 + 4.2 = 6.2,
# v = 20 * -0.5 / 10 + 2.3 = 1.3, so pixel (row 1, column 6), disparity f b / z = 20 * 0.54 / 10 = 1.08 px.
# The second point lies on the same ray twice as far (0.54 px, hidden); the third is behind the camera; the
# fourth projects to u = 24.2, outside the 10-px-wide image.
SCAN = np.array(
    [[10.27, -0.94, 0.42, 0.3], [20.27, -1.94, 0.92, 0.1], [-5.0, 0.0, 0.0, 0.5], [10.27, -10.06, -0.08, 0.2]],
    np.float32,
)
HAND_PIXEL, HAND_DISPARITY = (1, 6), 1.08


def _images(folder, names, rng, *, size=(H, W)):
    folder.mkdir(parents=True, exist_ok=True)
    images = []
    for name in names:
        image = rng.integers(0, 256, (*size, 3), dtype=np.uint8)
        cv2.imwrite(str(folder / name), image)
        images.append(image[..., ::-1])  # RGB, as read
    return images


def _expected_velodyne_truth():
    truth = np.full((H, W), np.nan, np.float32)
    truth[HAND_PIXEL] = HAND_DISPARITY
    return truth


# ----------------------------------------------------------------------------- the projection itself


def test_points_to_disparity_keeps_the_nearest_point_per_pixel():
    camera = StereoCamera(F_PX, CX, CY, BASELINE, width=W, height=H)
    points = np.array([[1.0, -0.5, 10.0], [2.0, -1.0, 20.0], [-1.0, 0.0, -3.0], [10.0, 0.0, 10.0]])
    np.testing.assert_allclose(points_to_disparity(points, camera), _expected_velodyne_truth(), rtol=1e-6)
    # nearest pixel centre: u = 9.49 rounds into the last column, u = 9.5 falls outside; v = -0.5 is row 0
    edge = np.array(
        [[(9.49 - CX) / F_PX, (0.0 - CY) / F_PX, 1.0], [(9.5 - CX) / F_PX, 0.0, 1.0], [0.0, (-0.5 - CY) / F_PX, 1.0]]
    )
    disparity = points_to_disparity(edge, camera)
    assert disparity[0, 9] == pytest.approx(F_PX * BASELINE) and disparity[0, 4] == pytest.approx(F_PX * BASELINE)
    assert np.isfinite(disparity).sum() == 2
    with pytest.raises(PrismapInputError, match="image size"):
        points_to_disparity(points, StereoCamera(F_PX, CX, CY, BASELINE))
    with pytest.raises(PrismapInputError, match=r"`points_cam` must have shape \(N, 3\)"):
        points_to_disparity(np.zeros((2, 4)), camera)


# ----------------------------------------------------------------------------- KITTI odometry and raw


@pytest.fixture
def odometry(tmp_path):
    seq = tmp_path / "sequences" / "07"
    seq.mkdir(parents=True)
    (seq / "calib.txt").write_text(
        kitti_line("P0", kitti_projection(F_PX, CX, CY, [0, 0, 0]))
        + kitti_line("P1", kitti_projection(F_PX, CX, CY, [-BASELINE, 0, 0]))
        + kitti_line("P2", kitti_projection(F_PX, CX, CY, T2))
        + kitti_line("P3", kitti_projection(F_PX, CX, CY, T2 - [BASELINE, 0, 0]))
        + kitti_line("Tr", TR)
    )
    names = [f"{i:06d}.png" for i in range(3)]
    rng = np.random.default_rng(7)
    lefts = _images(seq / "image_2", names, rng)
    _images(seq / "image_3", names, rng)
    (seq / "velodyne").mkdir()
    for i in range(3):
        SCAN.tofile(seq / "velodyne" / f"{i:06d}.bin")
    return seq, lefts


def test_kitti_odometry_ground_truth_is_the_projected_velodyne_scan(odometry):
    seq, lefts = odometry
    frames = open_ground_truth(seq)
    assert frames.kind == "kitti-odometry" and len(frames) == 3 and frames.indices == (0, 1, 2)
    frame = frames[1]
    np.testing.assert_array_equal(frame.left, lefts[1])
    np.testing.assert_allclose(frame.disparity_gt, _expected_velodyne_truth(), rtol=1e-5)
    np.testing.assert_allclose(frames.disparity_gt(2), _expected_velodyne_truth(), rtol=1e-5)
    assert frame.camera.baseline_m == pytest.approx(BASELINE)
    assert frames.max_disparity_px(progress=False) == pytest.approx(HAND_DISPARITY, rel=1e-5)


def test_kitti_odometry_missing_scan_or_transform_fails_on_opening(odometry):
    seq, _ = odometry
    (seq / "velodyne" / "000002.bin").unlink()
    assert len(open_ground_truth(seq, frames="0:2")) == 2
    with pytest.raises(
        PrismapInputError,
        match=r"1 of the 3 selected frames have no ground truth; first frame 2: .*000002.bin not found",
    ):
        open_ground_truth(seq)
    text = (seq / "calib.txt").read_text()
    (seq / "calib.txt").write_text(text[: text.index("Tr:")])
    with pytest.raises(PrismapInputError, match=r"has no Velodyne transform \(Tr\)"):
        open_ground_truth(seq, frames="0:2")


def test_kitti_raw_ground_truth_is_the_projected_velodyne_scan(tmp_path):
    date = tmp_path / "2011_09_26"
    drive = date / "2011_09_26_drive_0005_sync"
    date.mkdir()
    (date / "calib_cam_to_cam.txt").write_text(
        "calib_time: 09-Jan-2012 13:57:47\n"
        + kitti_line("R_rect_00", np.eye(3))
        + kitti_line("P_rect_02", kitti_projection(F_PX, CX, CY, T2))
        + kitti_line("P_rect_03", kitti_projection(F_PX, CX, CY, T2 - [BASELINE, 0, 0]))
    )
    (date / "calib_velo_to_cam.txt").write_text(kitti_line("R", TR[:, :3]) + kitti_line("T", TR[:, 3]))
    names = ["0000000000.png", "0000000001.png"]
    rng = np.random.default_rng(3)
    lefts = _images(drive / "image_02" / "data", names, rng)
    _images(drive / "image_03" / "data", names, rng)
    (drive / "velodyne_points" / "data").mkdir(parents=True)
    for name in names:
        SCAN.tofile(drive / "velodyne_points" / "data" / name.replace(".png", ".bin"))
    frames = open_ground_truth(drive, frames="1:")
    assert frames.kind == "kitti-raw" and frames.indices == (1,)
    np.testing.assert_array_equal(frames[0].left, lefts[1])
    np.testing.assert_allclose(frames[0].disparity_gt, _expected_velodyne_truth(), rtol=1e-5)


# ----------------------------------------------------------------------------- KITTI stereo 2012 / 2015


@pytest.mark.parametrize("year", [2012, 2015])
def test_kitti_stereo_frames_and_noc_or_occ_ground_truth(tmp_path, year):
    rng = np.random.default_rng(year)
    pairs = [shifted_pair(rng, 8, 12, d) for d in (2, 3, 4)]
    root = write_kitti_stereo(tmp_path / "training", pairs, year=year, disparities=("noc",))
    occ = [p[2].copy() for p in pairs]
    for index, truth in enumerate(occ):  # occ: also the occluded first columns
        truth[:, :2] = 1.5
        folder = "disp_occ" if year == 2012 else "disp_occ_0"
        write_disparity_png(root / folder / f"{index:06d}_10.png", truth, "disparity")
    frames = open_ground_truth(root)
    assert frames.kind == f"kitti-stereo-{year}" and len(frames) == 3  # the _11 images have no ground truth
    frame = frames[2]
    left, right, truth = pairs[2]
    if year == 2012:
        np.testing.assert_array_equal(frame.left[..., 0], left.mean(axis=2).astype(np.uint8))  # grey, repeated
    else:
        np.testing.assert_array_equal(frame.left, left)
        np.testing.assert_array_equal(frame.right, right)
    np.testing.assert_array_equal(frame.disparity_gt, truth)
    assert frame.camera.focal_px == 20.0 and frame.camera.baseline_m == pytest.approx(0.54)
    assert (frame.camera.width, frame.camera.height) == (12, 8) and frame.camera.cx_px == 5.5
    assert frame.name == f"kitti-stereo-{year}/000002_10"
    np.testing.assert_array_equal(open_ground_truth(root, kitti_disparity="occ")[2].disparity_gt, occ[2])
    assert frames.max_disparity_px(progress=False) == 4.0


def test_kitti_stereo_without_disparities_or_calibration_or_with_other_sizes(tmp_path):
    rng = np.random.default_rng(0)
    root = write_kitti_stereo(tmp_path / "testing", [shifted_pair(rng, 8, 12, 2)], year=2012, disparities=())
    with pytest.raises(
        PrismapInputError,
        match=r"testing: KITTI stereo 2012 folder without ground-truth disparities: "
        r"no disp_noc/ \(the testing split has none\)",
    ):
        open_ground_truth(root)
    root = write_kitti_stereo(tmp_path / "training", [shifted_pair(rng, 8, 12, 2)], year=2015)
    with pytest.raises(PrismapInputError, match="no disp_occ_0/"):
        open_ground_truth(root, kitti_disparity="occ")
    with pytest.raises(PrismapInputError, match="`kitti_disparity` must be one of"):
        open_ground_truth(root, kitti_disparity="all")
    write_disparity_png(root / "disp_noc_0" / "000000_10.png", np.ones((8, 13)), "disparity")
    frames = open_ground_truth(root)
    message = r"000000_10.png: disparity size \(8, 13\) differs from the left image's \(8, 12\)"
    with pytest.raises(PrismapInputError, match=message):
        frames.max_disparity_px(progress=False)
    with pytest.raises(PrismapInputError, match=message):
        frames[0]
    (root / "calib_cam_to_cam" / "000000.txt").unlink()
    with pytest.raises(PrismapInputError, match="calib_cam_to_cam: missing 1 calibration file"):
        open_ground_truth(root)


# ----------------------------------------------------------------------------- Middlebury, sequences, Tsukuba


def _middlebury_scene(folder, rng, *, disparity=None, height=H, width=W):
    folder.mkdir(parents=True)
    left = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    right = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    cv2.imwrite(str(folder / "im0.png"), left[..., ::-1])
    cv2.imwrite(str(folder / "im1.png"), right[..., ::-1])
    (folder / "calib.txt").write_text(
        f"cam0=[50 0 4; 0 50 3; 0 0 1]\ncam1=[50 0 6; 0 50 3; 0 0 1]\ndoffs=2\nbaseline=100\n"
        f"width={width}\nheight={height}\nndisp=8\n"
    )
    if disparity is None:
        disparity = rng.uniform(1, 8, (height, width)).astype(np.float32)
        disparity[0, 0] = np.inf
    write_pfm(folder / "disp0.pfm", disparity)
    return left, disparity


def test_middlebury_scene_and_folder_of_scenes(tmp_path):
    rng = np.random.default_rng(1)
    written = {name: _middlebury_scene(tmp_path / "2014" / name, rng) for name in ("Bicycle1", "Adirondack", "Piano")}
    (tmp_path / "2014" / "README.txt").write_text("not a scene")
    one = open_ground_truth(tmp_path / "2014" / "Piano")
    assert one.kind == "middlebury" and len(one) == 1
    frames = open_ground_truth(tmp_path / "2014", frames="0:3", every=2)
    assert frames.kind == "middlebury" and [f.name for f in frames] == ["Adirondack", "Piano"]
    left, disparity = written["Piano"]
    np.testing.assert_array_equal(frames[1].left, left)
    expected = np.where(np.isinf(disparity), np.nan, disparity)
    np.testing.assert_array_equal(frames[1].disparity_gt, expected)
    np.testing.assert_array_equal(frames.disparity_gt(1), expected)
    assert frames[1].camera.doffs_px == 2.0 and frames[1].camera.baseline_m == 0.1
    top = max(np.nanmax(written[n][1][np.isfinite(written[n][1])]) for n in ("Adirondack", "Piano"))
    assert frames.max_disparity_px(progress=False) == top
    (tmp_path / "2014" / "Piano" / "disp0.pfm").unlink()
    with pytest.raises(PrismapInputError, match=r"first frame 2: .*Piano/disp0.pfm not found"):
        open_ground_truth(tmp_path / "2014")


def test_motorcycle_by_name():
    frames = open_ground_truth("middlebury-motorcycle")
    assert frames.kind == "middlebury-motorcycle" and len(frames) == 1
    reference = load_middlebury_motorcycle()
    np.testing.assert_array_equal(frames.disparity_gt(0), reference.disparity_gt)
    assert frames.max_disparity_px(progress=False) == np.nanmax(reference.disparity_gt)


def test_a_ground_truth_pixel_beyond_the_image_width_is_refused(tmp_path):
    disparity = np.full((H, W), 3.0, np.float32)
    disparity[2, 5] = 1e9
    _middlebury_scene(tmp_path / "scene", np.random.default_rng(0), disparity=disparity)
    frames = open_ground_truth(tmp_path / "scene")
    message = (
        r"scene/disp0.pfm: ground-truth disparity 1e\+09 px at \(row 2, column 5\) is not below the image "
        r"width 10 px"
    )
    with pytest.raises(PrismapInputError, match=message):
        frames.max_disparity_px(progress=False)
    with pytest.raises(PrismapInputError, match=message):
        frames[0]


def _sequence_frames(n, rng):
    camera = StereoCamera(30.0, 4.5, 2.5, 0.2)
    frames = []
    for index in range(n):
        left = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        right = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        truth = np.round(rng.uniform(1, 9, (H, W)) * 256) / 256
        truth[0, index] = np.nan
        frames.append(StereoFrame(left, right, camera, disparity_gt=truth.astype(np.float32), name=str(index)))
    return frames


def test_a_sequence_with_disp_and_frame_selection(tmp_path):
    written = _sequence_frames(7, np.random.default_rng(5))
    write_sequence(written, tmp_path / "seq")
    frames = open_ground_truth(tmp_path / "seq", frames="1:-1", every=2)
    assert isinstance(frames, GroundTruthFrames) and frames.kind == "sequence"
    assert frames.indices == (1, 3, 5) and len(frames) == 3
    for position, index in enumerate(frames.indices):
        np.testing.assert_array_equal(frames[position].left, written[index].left)
        np.testing.assert_array_equal(frames[position].disparity_gt, written[index].disparity_gt)
    assert [f.name for f in frames[1:]] == ["seq/000003.png", "seq/000005.png"]
    assert open_ground_truth(tmp_path / "seq", frames=(None, 2)).indices == (0, 1)
    assert open_ground_truth(tmp_path / "seq", frames="-2:").indices == (5, 6)
    assert open_ground_truth(tmp_path / "seq", every=3).indices == (0, 3, 6)
    assert open_ground_truth(tmp_path / "seq", frames="0:7").indices == tuple(range(7))


@pytest.mark.parametrize(
    ("frames", "every", "message"),
    [
        ("3:3", 1, "`frames` 3:3 selects no frame of the 7 frames of"),
        ("5:2", 1, "`frames` 5:2 selects no frame"),
        ("0:8", 1, "`frames` 0:8: 8 lies outside the 7 frames of .* \\(0..6\\)"),
        ((-9, None), 1, "`frames` -9:: -9 lies outside the 7 frames"),
        ("1-3", 1, "`frames` must look like A:B"),
        ("a:3", 1, "`frames` must look like A:B"),
        ((1, 2, 3), 1, "`frames` must be 'A:B', \\(start, stop\\) or None"),
        (None, 0, "`every` must be an integer >= 1; got 0"),
        (None, 1.5, "`every` must be an integer >= 1; got 1.5"),
    ],
)
def test_bad_selections_are_clear_errors(tmp_path, frames, every, message):
    write_sequence(_sequence_frames(7, np.random.default_rng(0)), tmp_path / "seq")
    with pytest.raises(PrismapInputError, match=message):
        open_ground_truth(tmp_path / "seq", frames=frames, every=every)


def test_a_sequence_without_ground_truth_and_an_unknown_layout(tmp_path):
    frames = [StereoFrame(f.left, f.right, f.camera) for f in _sequence_frames(2, np.random.default_rng(0))]
    write_sequence(frames, tmp_path / "seq")
    with pytest.raises(PrismapInputError, match="a KITTI-layout sequence without ground truth: neither disp/"):
        open_ground_truth(tmp_path / "seq")
    (tmp_path / "empty").mkdir()
    with pytest.raises(PrismapInputError, match="empty: no dataset layout recognised; looked for a Middlebury scene"):
        open_ground_truth(tmp_path / "empty")
    with pytest.raises(PrismapInputError, match="nowhere: no such file or directory"):
        open_ground_truth(tmp_path / "nowhere")
    with pytest.raises(PrismapInputError, match="calib.txt: not a folder"):
        open_ground_truth(tmp_path / "seq" / "calib.txt")
    with pytest.raises(PrismapInputError, match="`dataset` must be 'middlebury-motorcycle' or a folder path; got list"):
        open_ground_truth([tmp_path / "seq"])


def _write_xml(path, depth_cm):
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("depth", depth_cm)
    storage.release()


@pytest.mark.parametrize("with_depth", [True, False])
def test_new_tsukuba_prefers_the_sub_pixel_depth_maps(tmp_path, with_depth):
    root = tmp_path / "NewTsukubaStereoDataset"
    rng = np.random.default_rng(2)
    lefts = {}
    for side in ("left", "right"):
        names = [f"tsukuba_daylight_{side[0].upper()}_{n:05d}.png" for n in (1, 2)]
        lefts[side] = _images(root / "illumination" / "daylight" / side, names, rng, size=(4, 32))
    truth = root / "groundtruth"
    (truth / "disparity_maps" / "left").mkdir(parents=True)
    for number in (1, 2):
        cv2.imwrite(
            str(truth / "disparity_maps/left" / f"tsukuba_disparity_L_{number:05d}.png"),
            np.full((4, 32), 20 + number, np.uint8),
        )
        if with_depth:
            (truth / "depth_maps" / "left").mkdir(parents=True, exist_ok=True)
            _write_xml(
                truth / "depth_maps/left" / f"tsukuba_depth_L_{number:05d}.xml",
                np.full((4, 32), 300.0 * number, np.float32),
            )
    frames = open_ground_truth(root, frames="1:")
    assert frames.kind == "new-tsukuba" and len(frames) == 1
    np.testing.assert_array_equal(frames[0].left, lefts["left"][1])
    expected = 615 * 0.1 / 6.0 if with_depth else 22.0  # f b / z at 6 m, else the published integer
    np.testing.assert_allclose(frames[0].disparity_gt, np.full((4, 32), expected), rtol=1e-6)
    assert frames.max_disparity_px(progress=False) == pytest.approx(expected, rel=1e-6)
