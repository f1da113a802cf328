"""The shared reading helpers of prismap.io (_images, _text): values against hand-made files, and messages."""

import cv2
import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.io._images import (
    paired_names,
    png_size,
    read_disparity_png,
    read_gray_png,
    read_image,
    read_pair,
    read_png,
    with_image_size,
)
from prismap.io._text import homogeneous, parse_numbers, read_bytes, read_number_rows, read_text

RNG = np.random.default_rng(7)
RGB = RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)
GREY = RNG.integers(0, 256, (5, 7), dtype=np.uint8)


def _png(path, image):
    assert cv2.imwrite(str(path), image)
    return path


def test_read_image_turns_bgr_into_rgb_and_keeps_grey(tmp_path):
    path = _png(tmp_path / "c.png", cv2.cvtColor(RGB, cv2.COLOR_RGB2BGR))
    np.testing.assert_array_equal(read_image(path, "image", colour=False), RGB)
    np.testing.assert_array_equal(read_image(path, "image", colour=True), RGB)
    grey = _png(tmp_path / "g.png", GREY)
    np.testing.assert_array_equal(read_image(grey, "image", colour=False), GREY)
    np.testing.assert_array_equal(read_image(grey, "image", colour=True), np.repeat(GREY[:, :, None], 3, axis=2))
    bgra = np.dstack([cv2.cvtColor(RGB, cv2.COLOR_RGB2BGR), np.full((5, 7), 9, np.uint8)])
    np.testing.assert_array_equal(read_image(_png(tmp_path / "a.png", bgra), "image", colour=False), RGB)


def test_read_image_of_16_bit_files(tmp_path):
    path = _png(tmp_path / "d.png", np.full((2, 3), 300, np.uint16))
    with pytest.raises(PrismapInputError, match="d.png: left image must be an 8-bit PNG; got uint16"):
        read_image(path, "left image", colour=False)
    assert read_image(path, "left image", colour=True).dtype == np.uint8  # OpenCV scales to 8 bits


def test_read_png_errors_name_file_and_role(tmp_path):
    with pytest.raises(PrismapInputError, match="none.png: right image not found"):
        read_png(tmp_path / "none.png", "right image")
    (tmp_path / "gif.png").write_bytes(b"GIF89a" + bytes(40))
    with pytest.raises(PrismapInputError, match=r"gif.png: right image is not a PNG file \(wrong signature\)"):
        read_png(tmp_path / "gif.png", "right image")
    data = _png(tmp_path / "ok.png", RGB).read_bytes()
    (tmp_path / "cut.png").write_bytes(data[:30])
    with pytest.raises(PrismapInputError, match=r"cut.png: right image cannot be decoded \(truncated or corrupt PNG\)"):
        read_png(tmp_path / "cut.png", "right image")


def test_disparity_png_scale_and_unknown_pixels(tmp_path):
    raw = np.array([[0, 1, 256], [512, 65535, 3]], np.uint16)
    disparity = read_disparity_png(_png(tmp_path / "d16.png", raw), "disparity", dtype=np.uint16, scale=256.0)
    expected = np.array([[np.nan, 1 / 256, 1.0], [2.0, 65535 / 256, 3 / 256]], np.float32)
    assert disparity.dtype == np.float32
    np.testing.assert_array_equal(disparity, expected)
    raw8 = np.array([[0, 5, 255]], np.uint8)
    disparity = read_disparity_png(_png(tmp_path / "d8.png", raw8), "disparity", dtype=np.uint8, scale=1.0)
    np.testing.assert_array_equal(disparity, [[np.nan, 5.0, 255.0]])
    with pytest.raises(
        PrismapInputError, match="d8.png: disparity must be a single-channel uint16 PNG; got 1-channel uint8"
    ):
        read_disparity_png(tmp_path / "d8.png", "disparity", dtype=np.uint16, scale=256.0)
    _png(tmp_path / "c16.png", np.zeros((2, 2, 3), np.uint16))
    with pytest.raises(
        PrismapInputError, match="c16.png: raw must be a single-channel uint16 PNG; got 3-channel uint16"
    ):
        read_gray_png(tmp_path / "c16.png", "raw", np.uint16)


def test_png_size_reads_the_header_only(tmp_path):
    path = _png(tmp_path / "s.png", np.zeros((11, 4, 3), np.uint8))
    assert png_size(path, "image") == (11, 4)
    (tmp_path / "short.png").write_bytes(path.read_bytes()[:20])
    with pytest.raises(PrismapInputError, match=r"short.png: image is not a PNG file \(bad or truncated header\)"):
        png_size(tmp_path / "short.png", "image")
    with pytest.raises(PrismapInputError, match="none.png: image not found"):
        png_size(tmp_path / "none.png", "image")


def test_paired_names_and_pairs(tmp_path):
    left, right = tmp_path / "L", tmp_path / "R"
    left.mkdir()
    right.mkdir()
    with pytest.raises(PrismapInputError, match=r"L: no files matching '\*.png'"):
        paired_names(left, right, "*.png")
    for name in ("b.png", "a.png"):
        _png(left / name, RGB)
        _png(right / name, RGB)
    _png(right / "extra.png", RGB)  # a right image without a left one is ignored
    assert paired_names(left, right, "*.png") == ["a.png", "b.png"]
    l_img, r_img = read_pair(left / "a.png", right / "a.png", colour=False)
    np.testing.assert_array_equal(l_img, cv2.cvtColor(RGB, cv2.COLOR_BGR2RGB))
    np.testing.assert_array_equal(l_img, r_img)
    _png(right / "b.png", RGB[:4])
    with pytest.raises(PrismapInputError, match=r"R/b.png: right image shape \(4, 7, 3\) != left \(5, 7, 3\)"):
        read_pair(left / "b.png", right / "b.png", colour=True)
    _png(left / "c.png", RGB)
    with pytest.raises(PrismapInputError, match=r"R: missing 1 right image\(s\), first 'c.png'"):
        paired_names(left, right, "*.png")


def test_with_image_size():
    camera = with_image_size(StereoCamera(100.0, 3.0, 2.0, 0.1), GREY)
    assert (camera.width, camera.height) == (7, 5) and camera.focal_px == 100.0


def test_parse_numbers_values_and_messages():
    np.testing.assert_array_equal(parse_numbers(" 1 -2.5e3\t7 ", "f.txt", 3), [1.0, -2500.0, 7.0])
    assert parse_numbers("   ", "f.txt", 3).shape == (0,)
    with pytest.raises(PrismapInputError, match="f.txt line 3, field P2: expected numbers; got '1 x'"):
        parse_numbers("1 x", "f.txt", 3, "P2")
    with pytest.raises(PrismapInputError, match="f.txt line 4: numbers must be finite; got '1 inf'"):
        parse_numbers("1 inf", "f.txt", 4)


def test_read_number_rows(tmp_path):
    path = tmp_path / "rows.txt"
    path.write_text("1 2 3\n4,5, 6\n\n\n")
    with pytest.raises(PrismapInputError, match="rows.txt line 2: expected numbers; got '4,5, 6'"):
        read_number_rows(path, "row file", 3, layout="x y z")
    np.testing.assert_array_equal(
        read_number_rows(path, "row file", 3, layout="x y z", commas=True), [[1, 2, 3], [4, 5, 6]]
    )
    path.write_text("1 2 3\n\n4 5 6\n")
    with pytest.raises(PrismapInputError, match=r"rows.txt line 2: expected 3 numbers \(x y z\); got 0"):
        read_number_rows(path, "row file", 3, layout="x y z")
    path.write_text(" \n\n")
    with pytest.raises(PrismapInputError, match="rows.txt: row file is empty"):
        read_number_rows(path, "row file", 3, layout="x y z")


def test_read_bytes_and_text_errors(tmp_path):
    with pytest.raises(PrismapInputError, match="none.bin: scan not found"):
        read_bytes(tmp_path / "none.bin", "scan")
    (tmp_path / "sub").mkdir()
    with pytest.raises(PrismapInputError, match="sub: scan not found"):  # a directory is not a file
        read_bytes(tmp_path / "sub", "scan")
    (tmp_path / "b.txt").write_bytes(b"ok\n\xff\xfe")
    with pytest.raises(PrismapInputError, match=r"b.txt: pose file is not UTF-8 text \(byte 3\)"):
        read_text(tmp_path / "b.txt", "pose file")
    (tmp_path / "u.txt").write_text("P2: 1 2\n", encoding="utf-8")
    assert read_text(tmp_path / "u.txt", "calibration") == "P2: 1 2\n"


def test_homogeneous_single_and_stacked():
    top = np.arange(12.0).reshape(3, 4)
    T = homogeneous(top)
    np.testing.assert_array_equal(T[:3], top)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    stacked = homogeneous(np.stack([top, 2 * top]))
    assert stacked.shape == (2, 4, 4)
    np.testing.assert_array_equal(stacked[1], homogeneous(2 * top))


def test_write_disparity_png_round_trips_through_the_reader(tmp_path):
    from prismap.io import write_disparity_png
    from prismap.io._images import read_disparity_png

    disparity = np.array([[0.5, np.nan, 255.99], [-1.0, 0.001, 17.25]])
    path = tmp_path / "disp" / "000000.png"
    write_disparity_png(path, disparity, "test disparity")
    back = read_disparity_png(path, "test disparity", dtype=np.uint16, scale=256.0)
    np.testing.assert_array_equal(np.isnan(back), [[False, True, False], [True, False, False]])
    np.testing.assert_allclose(back[[0, 0, 1], [0, 2, 2]], [0.5, 255.98828125, 17.25])
    assert back[1, 1] == np.float32(1 / 256)  # a valid disparity never rounds to "invalid"


def test_write_disparity_png_refuses_values_beyond_the_format_and_keeps_the_old_file(tmp_path):
    from prismap.io import write_disparity_png

    path = tmp_path / "000000.png"
    write_disparity_png(path, np.full((2, 2), 3.0), "old")
    before = path.read_bytes()
    with pytest.raises(
        PrismapInputError, match=r"`new` reaches 300.00 px; the uint16 x 256 format stores at most 255.99"
    ):
        write_disparity_png(path, np.full((2, 2), 300.0), "new")
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["000000.png"]
