"""PFM files, Middlebury calib.txt and folders (written here in exactly that format), Motorcycle."""

import struct

import cv2
import numpy as np
import pytest

from prismap import PrismapInputError
from prismap.camera import StereoCamera
from prismap.io import load_middlebury_folder, load_middlebury_motorcycle, read_middlebury_calib, read_pfm, write_pfm
from prismap.stereo import make_matcher

# Middlebury 2014 Motorcycle's calib.txt, verbatim.
MOTORCYCLE_CALIB = """cam0=[3979.911 0 1244.772; 0 3979.911 1019.507; 0 0 1]
cam1=[3979.911 0 1369.115; 0 3979.911 1019.507; 0 0 1]
doffs=124.343
baseline=193.001
width=2964
height=1988
ndisp=270
isint=0
vmin=23
vmax=245
dyavg=0
dymax=0
"""


def _small_calib(width, height):
    return (
        f"cam0=[100.5 0 {width / 2}; 0 100.5 {height / 2}; 0 0 1]\n"
        f"cam1=[100.5 0 {width / 2 + 3}; 0 100.5 {height / 2}; 0 0 1]\n"
        f"doffs=3\nbaseline=120.5\nwidth={width}\nheight={height}\nndisp=32\nvmin=2\nvmax=20\n"
    )


def _write_folder(folder, *, height=12, width=20, seed=0, gt=True):
    rng = np.random.default_rng(seed)
    folder.mkdir()
    left = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    right = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    cv2.imwrite(str(folder / "im0.png"), cv2.cvtColor(left, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "im1.png"), cv2.cvtColor(right, cv2.COLOR_RGB2BGR))
    (folder / "calib.txt").write_text(_small_calib(width, height))
    disparity = rng.uniform(2, 20, (height, width)).astype(np.float32)
    disparity[0, :3] = np.inf
    if gt:
        write_pfm(folder / "disp0.pfm", disparity)
    return left, right, disparity


def _pfm_bytes(magic, rows_top_to_bottom, scale):
    """A PFM file built by hand: header, then rows bottom to top in the byte order of the scale's sign."""
    height, width = rows_top_to_bottom.shape[:2]
    order = "<" if scale < 0 else ">"
    values = np.flipud(rows_top_to_bottom).ravel()
    return f"{magic}\n{width} {height}\n{scale}\n".encode() + struct.pack(f"{order}{values.size}f", *values)


@pytest.mark.parametrize("scale", [-1.0, 1.0])
def test_read_pfm_rows_bottom_to_top_and_byte_order_from_scale(tmp_path, scale):
    expected = np.array([[1.0, 2.0, np.inf], [4.5, -5.0, 6.25]], dtype=np.float32)
    (tmp_path / "d.pfm").write_bytes(_pfm_bytes("Pf", expected, scale))
    got = read_pfm(tmp_path / "d.pfm")
    assert got.dtype == np.float32 and got.shape == (2, 3)
    np.testing.assert_array_equal(got, expected)


def test_read_pfm_colour_and_odd_header_whitespace(tmp_path):
    expected = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)
    data = _pfm_bytes("PF", expected, -1.0).replace(b"\n3 2\n", b"\n3   2 \n")
    (tmp_path / "c.pfm").write_bytes(data)
    np.testing.assert_array_equal(read_pfm(tmp_path / "c.pfm"), expected)


def test_write_pfm_round_trip_and_nan_becomes_inf(tmp_path):
    rng = np.random.default_rng(1)
    grey = rng.normal(size=(7, 5)).astype(np.float32)
    grey[3, 2] = np.nan
    write_pfm(tmp_path / "g.pfm", grey)
    raw = (tmp_path / "g.pfm").read_bytes()
    assert raw.startswith(b"Pf\n5 7\n-1\n") and len(raw) == len(b"Pf\n5 7\n-1\n") + 7 * 5 * 4
    back = read_pfm(tmp_path / "g.pfm")
    assert back[3, 2] == np.inf
    grey[3, 2] = np.inf
    np.testing.assert_array_equal(back, grey)
    colour = rng.normal(size=(4, 6, 3))
    write_pfm(tmp_path / "c.pfm", colour)
    np.testing.assert_array_equal(read_pfm(tmp_path / "c.pfm"), colour.astype(np.float32))


def test_pfm_errors_name_the_file(tmp_path):
    with pytest.raises(PrismapInputError, match=r"missing.pfm: PFM file not found"):
        read_pfm(tmp_path / "missing.pfm")
    (tmp_path / "bad.pfm").write_bytes(b"P6\n3 2\n255\n" + bytes(18))
    with pytest.raises(PrismapInputError, match=r"bad.pfm: not a PFM file"):
        read_pfm(tmp_path / "bad.pfm")
    (tmp_path / "short.pfm").write_bytes(_pfm_bytes("Pf", np.zeros((2, 3), np.float32), -1.0)[:-4])
    with pytest.raises(PrismapInputError, match=r"short.pfm: PFM data truncated: 3x2x1 float32 needs 24 bytes; got 20"):
        read_pfm(tmp_path / "short.pfm")
    (tmp_path / "scale.pfm").write_bytes(b"Pf\n3 2\nabc\n" + bytes(24))
    with pytest.raises(PrismapInputError, match=r"scale.pfm: PFM header must hold width, height and scale"):
        read_pfm(tmp_path / "scale.pfm")
    message = r"`array` must be a non-empty \(H, W\) or \(H, W, 3\) map; got shape \(2, 2, 2\)"
    with pytest.raises(PrismapInputError, match=message):
        write_pfm(tmp_path / "x.pfm", np.zeros((2, 2, 2)))


def test_read_middlebury_calib_of_motorcycle(tmp_path):
    (tmp_path / "calib.txt").write_text(MOTORCYCLE_CALIB)
    camera = read_middlebury_calib(tmp_path / "calib.txt")
    assert camera == StereoCamera(3979.911, 1244.772, 1019.507, 0.193001, doffs_px=124.343, width=2964, height=1988)


def test_calib_errors_name_file_and_field(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(MOTORCYCLE_CALIB.replace("baseline=193.001\n", ""))
    with pytest.raises(PrismapInputError, match=r"calib.txt: missing field\(s\) \['baseline'\]"):
        read_middlebury_calib(path)
    path.write_text(MOTORCYCLE_CALIB.replace("doffs=124.343", "doffs=12,4"))
    with pytest.raises(PrismapInputError, match=r"calib.txt line 3, field doffs: expected numbers; got '12,4'"):
        read_middlebury_calib(path)
    path.write_text(MOTORCYCLE_CALIB.replace("[3979.911 0 1244.772; ", "[3979.911 0 1244.772 0; "))
    with pytest.raises(
        PrismapInputError, match=r"calib.txt line 1, field cam0: expected a 3x3 matrix \[a b c; d e f; g h i\]"
    ):
        read_middlebury_calib(path)
    path.write_text("cam0 [1 0 0; 0 1 0; 0 0 1]\n")
    with pytest.raises(PrismapInputError, match="calib.txt line 1: expected 'key=value'"):
        read_middlebury_calib(path)
    with pytest.raises(PrismapInputError, match=r"nowhere.txt: Middlebury calibration file not found"):
        read_middlebury_calib(tmp_path / "nowhere.txt")


def test_load_middlebury_folder_round_trip(tmp_path):
    left, right, disparity = _write_folder(tmp_path / "Toy-perfect")
    frame = load_middlebury_folder(tmp_path / "Toy-perfect")
    np.testing.assert_array_equal(frame.left, left)
    np.testing.assert_array_equal(frame.right, right)
    assert frame.name == "Toy-perfect"
    assert frame.camera == StereoCamera(100.5, 10.0, 6.0, 0.1205, doffs_px=3.0, width=20, height=12)
    assert frame.disparity_gt.dtype == np.float32
    assert np.isnan(frame.disparity_gt[0, :3]).all()
    np.testing.assert_array_equal(frame.disparity_gt[1:], disparity[1:])
    assert frame.extras["calib"]["ndisp"] == 32 and "cam0" not in frame.extras["calib"]
    assert frame.T_world_cam is None


def test_folder_without_ground_truth(tmp_path):
    _write_folder(tmp_path / "Test", gt=False)
    assert load_middlebury_folder(tmp_path / "Test").disparity_gt is None


def test_folder_errors_name_files_and_shapes(tmp_path):
    with pytest.raises(PrismapInputError, match=r"nothing: not a Middlebury folder"):
        load_middlebury_folder(tmp_path / "nothing")
    folder = tmp_path / "A"
    _write_folder(folder)
    cv2.imwrite(str(folder / "im1.png"), np.zeros((12, 19, 3), np.uint8))
    message = r"im1.png: right image shape \(12, 19, 3\) != left \(12, 20, 3\)"
    with pytest.raises(PrismapInputError, match=message):
        load_middlebury_folder(folder)
    folder = tmp_path / "B"
    _write_folder(folder)
    write_pfm(folder / "disp0.pfm", np.zeros((12, 21), np.float32))
    message = r"disp0.pfm must be one-channel of the images' size \(12, 20\); got shape \(12, 21\)"
    with pytest.raises(PrismapInputError, match=message):
        load_middlebury_folder(folder)
    folder = tmp_path / "C"
    _write_folder(folder)
    (folder / "im0.png").unlink()
    with pytest.raises(PrismapInputError, match=r"im0.png: left image not found"):
        load_middlebury_folder(folder)
    folder = tmp_path / "D"
    _write_folder(folder)
    (folder / "calib.txt").write_text(_small_calib(40, 12))
    with pytest.raises(PrismapInputError, match=r"calib.txt says width=40, height=12; im0.png is 20x12"):
        load_middlebury_folder(folder)


def test_motorcycle_frame_and_sgbm_accuracy():
    frame = load_middlebury_motorcycle()
    assert frame.left.shape == frame.right.shape == (500, 741, 3) and frame.left.dtype == np.uint8
    assert frame.camera.focal_px == 994.978 and frame.camera.doffs_px == 31.086
    assert frame.disparity_gt.shape == (500, 741) and not np.isinf(frame.disparity_gt).any()
    assert 0.05 < np.isnan(frame.disparity_gt).mean() < 0.1
    disparity = make_matcher("sgbm", num_disparities=64).compute(frame.left, frame.right)
    valid = np.isfinite(disparity) & np.isfinite(frame.disparity_gt)
    assert valid.sum() > 0.8 * np.isfinite(frame.disparity_gt).sum()
    assert np.median(np.abs(frame.disparity_gt[valid] - disparity[valid])) < 1.0
