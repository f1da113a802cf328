"""OpenCV's block matcher and semiglobal matcher behind :class:`prismap.stereo.StereoMatcher`."""

from abc import abstractmethod

import cv2
import numpy as np

from prismap._memory import check_memory
from prismap._validate import check_integer, check_real
from prismap.errors import PrismapInputError
from prismap.stereo._base import StereoMatcher, check_stereo_pair, left_right_disagreement, to_grey

MATCH_BYTES_PER_PIXEL = 24
"""Memory one OpenCV match takes per pixel of the pair (bytes): OpenCV's buffers, its int16 disparity and the
float32 copies (20 measured for SGBM on a 3000x1500 colour pair); twice that with the left-right check."""


class _OpenCVMatcher(StereoMatcher):
    """Shared part: argument checks, fixed-point -> float conversion, the optional left-right check.

    OpenCV returns int16 disparities scaled by 16 and marks invalid pixels with
    ``(min_disparity - 1) * 16``; those become NaN. The right image's disparity for the
    left-right check comes from matching the horizontally flipped pair (right as reference).
    """

    def __init__(self, *, min_disparity, num_disparities, block_size, left_right_check, lr_max_difference_px):
        lr_max = check_real(lr_max_difference_px, "lr_max_difference_px", minimum=0.0)
        self.min_disparity = check_integer(min_disparity, "min_disparity")
        self.num_disparities = check_integer(
            num_disparities,
            "num_disparities",
            expected="a positive multiple of 16",
            condition=lambda n: n > 0 and n % 16 == 0,
        )
        self.block_size = check_integer(
            block_size, "block_size", expected="an odd positive integer", condition=lambda n: n > 0 and n % 2
        )
        self.left_right_check = bool(left_right_check)
        self.lr_max_difference_px = lr_max

    def compute(self, left, right):
        """Disparity of ``left`` against ``right``.

        Parameters
        ----------
        left, right : (H, W) or (H, W, 3) uint8
            Rectified pair, grey or RGB, of one shape.

        Returns
        -------
        disparity : (H, W) float32, pixels, NaN = invalid
            With ``left_right_check=True``, pixels whose match does not map back within
            ``lr_max_difference_px`` are NaN too.
        """
        return self.compute_with_confidence(left, right)[0]

    def compute_with_confidence(self, left, right):
        """:meth:`compute` and, with ``left_right_check=True``, the left-right disagreement (pixels).

        Returns
        -------
        disparity : (H, W) float32, pixels, NaN = invalid
        lr_disagreement : (H, W) float32, pixels, NaN where not measurable; or None without the check
            (:func:`prismap.stereo.left_right_disagreement`, before pixels beyond the tolerance are dropped).
        """
        left, right = self._prepare(check_stereo_pair(left, right))
        reach = self.min_disparity + self.num_disparities
        if reach >= left.shape[1]:
            raise PrismapInputError(
                f"{self.name}: min_disparity + num_disparities = {reach} px must be below the image width "
                f"{left.shape[1]} px (no pixel could be matched)"
            )
        height, width = left.shape[:2]
        check_memory(
            height * width * MATCH_BYTES_PER_PIXEL * (2 if self.left_right_check else 1),
            f"{self.name}: matching a {width}x{height} pair",
            fix="use smaller images (MAX_IMAGE_PIXELS bounds decoding; matching needs the memory budget too)",
        )
        matcher = self._create(channels=1 if left.ndim == 2 else left.shape[2])
        disparity = self._to_float(matcher.compute(left, right))
        if not self.left_right_check:
            return disparity, None
        disagreement = left_right_disagreement(disparity, self._right_disparity(matcher, left, right))
        keep = disagreement <= self.lr_max_difference_px
        return np.where(keep, disparity, np.float32(np.nan)).astype(np.float32), disagreement

    def _right_disparity(self, matcher, left, right):
        """Disparity of the right image against the left (positive), from the flipped pair.

        OpenCV leaves the first ``min_disparity + num_disparities`` columns of its reference image
        unmatched; flipped, those would be the right image's last columns, which the check needs
        for the left image's last columns. The flipped pair is therefore padded by that many
        edge-replicated columns, which are cropped off again.
        """
        pad = max(self.min_disparity + self.num_disparities, 0)
        flipped = [cv2.copyMakeBorder(image[:, ::-1], 0, 0, pad, 0, cv2.BORDER_REPLICATE) for image in (right, left)]
        return self._to_float(matcher.compute(*flipped))[:, pad:][:, ::-1]

    def params(self):
        """Every parameter, as a JSON-serialisable dict (``name`` included)."""
        return {"name": self.name, **vars(self)}

    def __repr__(self):
        args = ", ".join(f"{key}={value!r}" for key, value in vars(self).items())
        return f"{type(self).__name__}({args})"

    def _to_float(self, fixed_point):
        disparity = fixed_point.astype(np.float32) / np.float32(16.0)
        return np.where(fixed_point >= self.min_disparity * 16, disparity, np.float32(np.nan))

    def _prepare(self, pair):
        return pair

    @abstractmethod
    def _create(self, *, channels):
        """The configured OpenCV matcher for images of ``channels`` channels."""


class BlockMatcher(_OpenCVMatcher):
    """Block matching (``cv2.StereoBM``): sum of absolute differences over a square window.

    Fast and sparse: low-texture and ambiguous pixels are left invalid. Colour input is
    converted to grey (StereoBM matches one channel).

    Parameters
    ----------
    min_disparity : int, pixels
        Smallest disparity searched.
    num_disparities : int, pixels, positive multiple of 16
        Size of the search range ``[min_disparity, min_disparity + num_disparities)``.
    block_size : int, pixels, odd, 5..255
        Side of the matching window.
    pre_filter_type : {"xsobel", "normalized_response"}
        Pre-filter applied before matching.
    pre_filter_size : int, pixels, odd, 5..255
        Window of the normalised-response pre-filter.
    pre_filter_cap : int, 1..63
        Clip of the pre-filtered values.
    texture_threshold : int
        Minimum summed texture in the window; weaker windows are invalid.
    uniqueness_ratio : int, percent
        Margin by which the best cost must beat the second best.
    speckle_window_size : int, pixels
        Largest connected region treated as speckle and removed (0 = off).
    speckle_range : int, pixels
        Disparity variation allowed inside one connected region.
    left_right_check : bool
        Apply :func:`prismap.stereo.left_right_check` (matches the pair twice).
    lr_max_difference_px : float, pixels
        Tolerance of the left-right check.
    """

    name = "bm"
    _PRE_FILTERS = {
        "xsobel": cv2.StereoBM_PREFILTER_XSOBEL,
        "normalized_response": cv2.StereoBM_PREFILTER_NORMALIZED_RESPONSE,
    }

    def __init__(
        self,
        *,
        min_disparity=0,
        num_disparities=64,
        block_size=15,
        pre_filter_type="xsobel",
        pre_filter_size=9,
        pre_filter_cap=31,
        texture_threshold=10,
        uniqueness_ratio=15,
        speckle_window_size=0,
        speckle_range=0,
        left_right_check=False,
        lr_max_difference_px=1.0,
    ):
        super().__init__(
            min_disparity=min_disparity,
            num_disparities=num_disparities,
            block_size=block_size,
            left_right_check=left_right_check,
            lr_max_difference_px=lr_max_difference_px,
        )
        check_integer(
            block_size, "block_size", expected="odd in 5..255 for block matching", condition=lambda n: 5 <= n <= 255
        )
        if pre_filter_type not in self._PRE_FILTERS:
            raise PrismapInputError(
                f"`pre_filter_type` must be one of {list(self._PRE_FILTERS)}; got {pre_filter_type!r}"
            )
        self.pre_filter_type = pre_filter_type
        self.pre_filter_size = check_integer(
            pre_filter_size, "pre_filter_size", expected="odd in 5..255", condition=lambda n: 5 <= n <= 255 and n % 2
        )
        self.pre_filter_cap = check_integer(
            pre_filter_cap, "pre_filter_cap", expected="an integer in 1..63", condition=lambda n: 1 <= n <= 63
        )
        self.texture_threshold = _non_negative(texture_threshold, "texture_threshold")
        self.uniqueness_ratio = _non_negative(uniqueness_ratio, "uniqueness_ratio")
        self.speckle_window_size = _non_negative(speckle_window_size, "speckle_window_size")
        self.speckle_range = _non_negative(speckle_range, "speckle_range")

    def _prepare(self, pair):
        return tuple(to_grey(image) for image in pair)

    def _create(self, *, channels):
        matcher = cv2.StereoBM_create(numDisparities=self.num_disparities, blockSize=self.block_size)
        matcher.setMinDisparity(self.min_disparity)
        matcher.setPreFilterType(self._PRE_FILTERS[self.pre_filter_type])
        matcher.setPreFilterSize(self.pre_filter_size)
        matcher.setPreFilterCap(self.pre_filter_cap)
        matcher.setTextureThreshold(self.texture_threshold)
        matcher.setUniquenessRatio(self.uniqueness_ratio)
        matcher.setSpeckleWindowSize(self.speckle_window_size)
        matcher.setSpeckleRange(self.speckle_range)
        return matcher


class SemiGlobalMatcher(_OpenCVMatcher):
    """Semiglobal block matching (``cv2.StereoSGBM``, after Hirschmuller 2008).

    Dense: path-wise smoothness costs ``P1`` (disparity change of 1) and ``P2`` (larger changes)
    aggregated along several directions. Grey or RGB input (costs summed over channels).

    Parameters
    ----------
    min_disparity : int, pixels
    num_disparities : int, pixels, positive multiple of 16
    block_size : int, pixels, odd
        Side of the matching window (3..11 is typical; 1 matches single pixels).
    p1, p2 : int or None
        Smoothness penalties; ``None`` = ``8 cn block_size^2`` and ``32 cn block_size^2`` with
        ``cn`` the number of image channels (OpenCV's recommended values). ``p2 > p1``.
    mode : {"sgbm", "sgbm_3way", "hh", "hh4"}
        5-direction SGBM, its faster 3-way variant, or the full 8-direction (``hh``) and
        4-direction (``hh4``) algorithm.
    pre_filter_cap : int
        Clip of the x-derivative pre-filter.
    uniqueness_ratio : int, percent
        Margin by which the best cost must beat the second best.
    speckle_window_size : int, pixels
        Largest connected region treated as speckle and removed (0 = off).
    speckle_range : int, pixels
        Disparity variation allowed inside one connected region.
    left_right_check : bool
        Apply :func:`prismap.stereo.left_right_check` (matches the pair twice).
    lr_max_difference_px : float, pixels
        Tolerance of the left-right check.

    References
    ----------
    .. [1] H. Hirschmuller, "Stereo processing by semiglobal matching and mutual information",
       IEEE TPAMI 30(2), 2008. :DOI:`10.1109/TPAMI.2007.1166`
    """

    name = "sgbm"
    _MODES = {
        "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
        "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
        "hh": cv2.STEREO_SGBM_MODE_HH,
        "hh4": cv2.STEREO_SGBM_MODE_HH4,
    }

    def __init__(
        self,
        *,
        min_disparity=0,
        num_disparities=64,
        block_size=5,
        p1=None,
        p2=None,
        mode="sgbm",
        pre_filter_cap=63,
        uniqueness_ratio=10,
        speckle_window_size=100,
        speckle_range=2,
        left_right_check=False,
        lr_max_difference_px=1.0,
    ):
        super().__init__(
            min_disparity=min_disparity,
            num_disparities=num_disparities,
            block_size=block_size,
            left_right_check=left_right_check,
            lr_max_difference_px=lr_max_difference_px,
        )
        if mode not in self._MODES:
            raise PrismapInputError(f"`mode` must be one of {list(self._MODES)}; got {mode!r}")
        self.p1 = None if p1 is None else _non_negative(p1, "p1")
        self.p2 = None if p2 is None else _non_negative(p2, "p2")
        if self.p1 is not None and self.p2 is not None and self.p2 <= self.p1:
            raise PrismapInputError(f"`p2` must exceed `p1`; got p1={p1!r}, p2={p2!r}")
        self.mode = mode
        self.pre_filter_cap = _non_negative(pre_filter_cap, "pre_filter_cap")
        self.uniqueness_ratio = _non_negative(uniqueness_ratio, "uniqueness_ratio")
        self.speckle_window_size = _non_negative(speckle_window_size, "speckle_window_size")
        self.speckle_range = _non_negative(speckle_range, "speckle_range")

    def _create(self, *, channels):
        area = channels * self.block_size**2
        p1 = 8 * area if self.p1 is None else self.p1
        p2 = 32 * area if self.p2 is None else self.p2
        if p2 <= p1:
            raise PrismapInputError(f"`p2` must exceed `p1`; got p1={p1}, p2={p2} for {channels}-channel images")
        return cv2.StereoSGBM_create(
            minDisparity=self.min_disparity,
            numDisparities=self.num_disparities,
            blockSize=self.block_size,
            P1=p1,
            P2=p2,
            disp12MaxDiff=-1,
            preFilterCap=self.pre_filter_cap,
            uniquenessRatio=self.uniqueness_ratio,
            speckleWindowSize=self.speckle_window_size,
            speckleRange=self.speckle_range,
            mode=self._MODES[self.mode],
        )


def _non_negative(value, name):
    return check_integer(value, name, expected="a non-negative integer", condition=lambda n: n >= 0)
