"""OpenCV block and semiglobal matchers: known shifts, the left-right check, params, bad input."""

import cv2
import numpy as np
import pytest
import scipy.ndimage as ndi

from prismap import PrismapInputError
from prismap.stereo import left_right_disagreement, make_matcher
from prismap.stereo._opencv import BlockMatcher, SemiGlobalMatcher

MATCHERS = {"bm": {"block_size": 9}, "sgbm": {"block_size": 5}}


def _texture(height, width, seed):
    """Smooth random texture, float64 in [0, 255]: band-limited, so sub-pixel shifts are well defined."""
    texture = ndi.gaussian_filter(np.random.default_rng(seed).uniform(0, 255, (height, width)), 1.0)
    return (texture - texture.min()) / np.ptp(texture) * 255


def _to_uint8(image):
    return np.rint(image).clip(0, 255).astype(np.uint8)


def _shifted_pair(disparity_px, *, height=96, width=192, seed=0):
    """Left = texture, right(u) = texture(u + d) (cubic interpolation): constant disparity d."""
    texture = _texture(height, width + 64, seed)
    rows, cols = np.mgrid[0:height, 0:width].astype(np.float64)
    right = ndi.map_coordinates(texture, [rows, cols + disparity_px], order=3, mode="nearest")
    return _to_uint8(texture[:, :width]), _to_uint8(right)


@pytest.mark.parametrize("name", MATCHERS)
@pytest.mark.parametrize("disparity_px", [12.0, 12.25, 12.5])
def test_constant_disparity_recovered_on_the_interior(name, disparity_px):
    left, right = _shifted_pair(disparity_px)
    disparity = make_matcher(name, num_disparities=32, **MATCHERS[name]).compute(left, right)
    assert disparity.shape == left.shape and disparity.dtype == np.float32
    # The first min_disparity + num_disparities columns cannot be matched: OpenCV leaves them invalid.
    assert np.isnan(disparity[:, :20]).all()
    interior = disparity[10:-10, 50:-10]
    assert np.mean(np.isfinite(interior)) > 0.99
    assert np.mean(np.abs(interior - disparity_px) <= 0.25) > 0.9


@pytest.mark.parametrize("name", MATCHERS)
def test_rgb_and_grey_inputs_agree_on_a_grey_pair(name):
    left, right = _shifted_pair(12.0, seed=1)
    matcher = make_matcher(name, num_disparities=32, **MATCHERS[name])
    grey = matcher.compute(left, right)
    rgb = matcher.compute(np.dstack([left] * 3), np.dstack([right] * 3))
    valid = np.isfinite(grey) & np.isfinite(rgb)
    assert valid[10:-10, 50:-10].mean() > 0.99
    assert np.median(np.abs(grey[valid] - rgb[valid])) == 0.0


def test_min_disparity_shifts_the_search_range():
    left, right = _shifted_pair(40.0, seed=2)
    disparity = SemiGlobalMatcher(min_disparity=32, num_disparities=16).compute(left, right)
    interior = disparity[10:-10, 70:-10]
    assert np.mean(np.abs(interior - 40.0) <= 0.25) > 0.9
    assert np.nanmin(disparity) >= 32


def _occluding_strip(*, height=96, width=192, seed=3, background_px=8, foreground_px=24, strip=(100, 140)):
    """A fronto-parallel strip at disparity 24 in front of a background at disparity 8.

    The background just left of the strip in the left image, columns [strip[0] - 16, strip[0]),
    is hidden from the right camera: the band the left-right check must remove.
    """
    background = _texture(height, width + 64, seed)
    foreground = _texture(height, width + 64, seed + 100)
    u = np.arange(width)
    a, b = strip
    in_left = (u >= a) & (u < b)
    left = np.where(in_left, foreground[:, u], background[:, u])
    in_right = (u >= a - foreground_px) & (u < b - foreground_px)
    right = np.where(in_right, foreground[:, np.clip(u + foreground_px, 0, None)], background[:, u + background_px])
    band = (a - (foreground_px - background_px), a)
    return _to_uint8(left), _to_uint8(right), band


@pytest.mark.parametrize("name", MATCHERS)
def test_left_right_check_removes_the_occluded_band(name):
    left, right, (band_start, band_end) = _occluding_strip()
    lenient = {"uniqueness_ratio": 0, "speckle_window_size": 0}
    plain = make_matcher(name, num_disparities=32, **lenient, **MATCHERS[name]).compute(left, right)[10:-10]
    checked = make_matcher(
        name, num_disparities=32, left_right_check=True, lr_max_difference_px=1.0, **lenient, **MATCHERS[name]
    ).compute(left, right)[10:-10]
    band = slice(band_start + 3, band_end - 3)
    assert np.isfinite(checked[:, band]).mean() < 0.05
    if name == "bm":  # without uniqueness, block matching reports a value at every band pixel
        assert np.isfinite(plain[:, band]).mean() > 0.95
    # Away from the band the check keeps what was right, and never invents values.
    for columns, truth in ((slice(50, band_start - 6), 8.0), (slice(105, 135), 24.0), (slice(150, 186), 8.0)):
        kept = checked[:, columns]
        assert np.isfinite(kept).mean() > 0.9
        assert np.nanmax(np.abs(kept - truth)) <= 1.0
    assert not (np.isfinite(checked) & np.isnan(plain)).any()


@pytest.mark.parametrize("name", MATCHERS)
def test_left_right_check_keeps_the_last_columns(name):
    # OpenCV cannot match the first num_disparities columns of its reference image; the right
    # image's last columns must still be matched, or the check would empty the left image's last ones.
    left, right = _shifted_pair(12.0, seed=6)
    checked = make_matcher(name, num_disparities=32, left_right_check=True, **MATCHERS[name]).compute(left, right)
    last = checked[10:-10, -40:-6]
    assert np.isfinite(last).mean() > 0.99
    assert np.nanmax(np.abs(last - 12.0)) <= 0.5


@pytest.mark.parametrize("name", MATCHERS)
def test_compute_with_confidence_returns_compute_and_the_disagreement_behind_the_check(name):
    left, right, (band_start, band_end) = _occluding_strip()
    lenient = {"uniqueness_ratio": 0, "speckle_window_size": 0}
    checking = make_matcher(
        name, num_disparities=32, left_right_check=True, lr_max_difference_px=1.0, **lenient, **MATCHERS[name]
    )
    disparity, disagreement = checking.compute_with_confidence(left, right)
    np.testing.assert_array_equal(disparity, checking.compute(left, right))
    assert disagreement.shape == left.shape and disagreement.dtype == np.float32
    # Kept pixels are exactly those that agree within the tolerance; the occluded band disagrees.
    np.testing.assert_array_equal(np.isfinite(disparity), disagreement <= 1.0)
    assert np.nanmedian(disagreement[10:-10, band_start + 3 : band_end - 3]) > 1.0
    plain, none = make_matcher(name, num_disparities=32, **MATCHERS[name]).compute_with_confidence(left, right)
    assert none is None and plain.shape == left.shape


def test_left_right_disagreement_against_a_loop_reference():
    rng = np.random.default_rng(3)
    left = rng.uniform(0, 6, (5, 9)).astype(np.float32)
    right = rng.uniform(0, 6, (5, 9)).astype(np.float32)
    left[1, 2] = np.nan
    right[2, 3] = np.nan
    ours = left_right_disagreement(left, right)
    for v in range(5):
        for u in range(9):
            target = int(np.rint(u - left[v, u])) if np.isfinite(left[v, u]) else -1
            expected = abs(right[v, target] - left[v, u]) if 0 <= target < 9 else np.nan
            np.testing.assert_equal(ours[v, u], np.float32(expected))
    with pytest.raises(PrismapInputError, match="one shape"):
        left_right_disagreement(left, right[:, :4])


def test_invalid_marker_becomes_nan_and_fixed_point_is_divided_by_16():
    left, right = _shifted_pair(12.0, seed=5)
    matcher = BlockMatcher(num_disparities=32, block_size=9)
    raw = cv2.StereoBM_create(numDisparities=32, blockSize=9).compute(left, right)
    ours = matcher.compute(left, right)
    assert (raw == -16).any()
    np.testing.assert_array_equal(np.isnan(ours), raw == -16)
    np.testing.assert_array_equal(ours[raw != -16], raw[raw != -16] / 16.0)


def test_params_and_defaults():
    sgbm = make_matcher("sgbm")
    params = sgbm.params()
    assert params["name"] == "sgbm" and params["num_disparities"] == 64 and params["block_size"] == 5
    assert params["p1"] is None and params["mode"] == "sgbm" and params["left_right_check"] is False
    assert make_matcher("sgbm", **{k: v for k, v in params.items() if k != "name"}).params() == params
    bm = BlockMatcher(block_size=21, left_right_check=True)
    assert bm.params()["block_size"] == 21 and bm.params()["name"] == "bm"
    assert "block_size=21" in repr(bm)
    # OpenCV's recommended penalties scale with the number of channels.
    assert sgbm._create(channels=3).getP1() == 8 * 3 * 25 and sgbm._create(channels=1).getP2() == 32 * 25


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"num_disparities": 40}, "`num_disparities` must be a positive multiple of 16; got 40"),
        ({"num_disparities": 0}, "positive multiple of 16"),
        ({"block_size": 6}, "`block_size` must be an odd positive integer; got 6"),
        ({"block_size": 5.5}, "`block_size` must be an odd"),
        ({"min_disparity": "0"}, "`min_disparity` must be an integer"),
        ({"lr_max_difference_px": -1}, "`lr_max_difference_px` must be a finite number >= 0"),
        ({"mode": "fast"}, "`mode` must be one of"),
        ({"p1": 100, "p2": 50}, "`p2` must exceed `p1`"),
    ],
)
def test_bad_sgbm_parameters(kwargs, message):
    with pytest.raises(PrismapInputError, match=message):
        SemiGlobalMatcher(**kwargs)


def test_bad_bm_parameters():
    with pytest.raises(PrismapInputError, match="5..255"):
        BlockMatcher(block_size=3)
    with pytest.raises(PrismapInputError, match="`pre_filter_cap` must be an integer in 1..63"):
        BlockMatcher(pre_filter_cap=64)
    with pytest.raises(PrismapInputError, match="`pre_filter_type` must be one of"):
        BlockMatcher(pre_filter_type="sobel")
    with pytest.raises(PrismapInputError, match="`p2` must exceed `p1`"):
        SemiGlobalMatcher(p2=100).compute(*_shifted_pair(12.0))


def test_bad_images_are_named():
    matcher = SemiGlobalMatcher(num_disparities=16)
    grey = np.zeros((40, 60), dtype=np.uint8)
    with pytest.raises(PrismapInputError, match=r"one shape; got \(40, 60\) and \(40, 50\)"):
        matcher.compute(grey, grey[:, :50])
    with pytest.raises(
        PrismapInputError,
        match=r"`right` must be an \(H, W\) grey or \(H, W, 3\) RGB uint8 image; got shape \(\d+, \d+\), dtype float32",
    ):
        matcher.compute(grey, grey.astype(np.float32))
    with pytest.raises(
        PrismapInputError, match=r"`left` must be an \(H, W\) grey or \(H, W, 3\) RGB uint8 image; got shape"
    ):
        matcher.compute(grey[0], grey[0])
    with pytest.raises(PrismapInputError, match=r"got shape \(40, 60, 4\)"):
        matcher.compute(np.zeros((40, 60, 4), np.uint8), np.zeros((40, 60, 4), np.uint8))
