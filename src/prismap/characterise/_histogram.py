"""Disparity errors of a matcher against ground truth, accumulated in a fixed-bin histogram."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_positive
from prismap.errors import PrismapInputError

DEFAULT_BIN_WIDTH = 1.0 / 32.0
DEFAULT_LIMIT_PX = 256.0
SUM_RESOLUTION_PX = 2.0**-16
"""Resolution of ``sum_abs_error_px`` (pixels): float64 sums of its multiples are exact up to 2^37 px."""
MAX_BINS = 1 << 22
"""Most bins a histogram may have (32 MiB of counts; the EM fit's cost grows with the bins)."""


@dataclass(frozen=True, eq=False)
class ErrorHistogram:
    """Errors ``e = d_true - d_computed`` (pixels) of one matcher, over any number of frames.

    Bins have fixed edges ``-limit_px + k * bin_width``, so histograms of different frames add up
    (``merged = h1 + h2``) and 100 frames never hold all their errors in memory. Errors beyond
    ``[-limit_px, limit_px)`` are not binned: they are counted in ``n_below`` / ``n_above``, enter the
    bad-pixel rates and the mean absolute error, and are left out of the mixture fit (which sees
    ``counts`` only). ``sum_abs_error_px`` is a multiple of :data:`SUM_RESOLUTION_PX` (each
    :meth:`from_errors` rounds to it), so sums of histograms are exact, the same in any order or
    chunking, while they stay below 2^37 px.

    Attributes
    ----------
    counts : (B,) int64
        Errors per bin, ``B = 2 * limit_px / bin_width``.
    bin_width : float, pixels
    limit_px : float, pixels
        Half-width of the binned range; a multiple of ``bin_width``.
    n_below, n_above : int
        Errors ``< -limit_px`` and ``>= limit_px``.
    n_gt_valid : int
        Pixels with finite ground truth (computed or not): the denominator of coverage.
    n_bad_1px, n_bad_2px : int
        Errors with ``|e| > 1`` px and ``|e| > 2`` px.
    sum_abs_error_px : float, pixels
    n_frames : int
    """

    counts: np.ndarray
    bin_width: float
    limit_px: float
    n_below: int = 0
    n_above: int = 0
    n_gt_valid: int = 0
    n_bad_1px: int = 0
    n_bad_2px: int = 0
    sum_abs_error_px: float = 0.0
    n_frames: int = 0

    def __post_init__(self):
        width = check_positive(self.bin_width, "bin_width")
        limit = check_positive(self.limit_px, "limit_px")
        n_bins = 2.0 * limit / width
        if abs(n_bins - round(n_bins)) > 1e-9 * n_bins:
            raise PrismapInputError(f"`limit_px` ({limit}) must be a multiple of `bin_width` ({width})")
        counts = np.asarray(self.counts, dtype=np.int64).copy()
        if counts.shape != (round(n_bins),):
            raise PrismapInputError(f"`counts` must have shape ({round(n_bins)},); got {counts.shape}")
        counts.setflags(write=False)
        object.__setattr__(self, "counts", counts)
        object.__setattr__(self, "bin_width", width)
        object.__setattr__(self, "limit_px", limit)

    @classmethod
    def empty(cls, *, bin_width: float = DEFAULT_BIN_WIDTH, limit_px: float = DEFAULT_LIMIT_PX) -> ErrorHistogram:
        """A histogram with no errors, to add frames to."""
        n_bins = int(round(2.0 * check_positive(limit_px, "limit_px") / check_positive(bin_width, "bin_width")))
        if n_bins > MAX_BINS:
            raise PrismapInputError(
                f"`bin_width` {bin_width:g} px over +-{limit_px:g} px gives {n_bins} bins, more "
                f"than MAX_BINS = {MAX_BINS}; bin_width must be >= {2 * limit_px / MAX_BINS:.3g} px"
            )
        return cls(np.zeros(n_bins, dtype=np.int64), bin_width, limit_px)

    @classmethod
    def from_disparities(
        cls,
        disparity: npt.ArrayLike,
        disparity_gt: npt.ArrayLike,
        *,
        bin_width: float = DEFAULT_BIN_WIDTH,
        limit_px: float = DEFAULT_LIMIT_PX,
        name: str = "frame",
    ) -> ErrorHistogram:
        """The errors of one frame.

        Parameters
        ----------
        disparity : (H, W) float, pixels, NaN = invalid
            Computed disparity of the left image.
        disparity_gt : (H, W) float, pixels, NaN or infinity = unknown
            Ground truth of the left image.
        bin_width, limit_px : float, pixels
        name : str
            Names the frame in error messages.

        Raises
        ------
        PrismapInputError
            For different shapes, no known ground truth, or no computed value where it is known.
        """
        computed = as_float_array(disparity, f"{name}: disparity", ndim=2)
        truth = as_float_array(disparity_gt, f"{name}: disparity_gt", ndim=2)
        if computed.shape != truth.shape:
            raise PrismapInputError(
                f"{name}: disparity and ground truth differ in shape: {computed.shape} vs {truth.shape}"
            )
        known = np.isfinite(truth)
        n_known = int(known.sum())
        if n_known == 0:
            raise PrismapInputError(f"{name}: the ground-truth disparity has no valid (finite) pixel")
        both = known & np.isfinite(computed)
        if not both.any():
            raise PrismapInputError(
                f"{name}: the computed disparity has no valid pixel where the ground truth is known "
                f"({n_known} ground-truth pixels, {int(np.isfinite(computed).sum())} computed pixels)"
            )
        errors = truth[both] - computed[both]
        return cls.from_errors(errors, n_gt_valid=n_known, bin_width=bin_width, limit_px=limit_px)

    @classmethod
    def from_errors(
        cls,
        errors: npt.ArrayLike,
        *,
        n_gt_valid: int | None = None,
        bin_width: float = DEFAULT_BIN_WIDTH,
        limit_px: float = DEFAULT_LIMIT_PX,
    ) -> ErrorHistogram:
        """One frame's errors ``e = d_true - d_computed`` (pixels, finite, any shape).

        ``n_gt_valid`` (default: the number of errors, i.e. full coverage) is the frame's count of
        pixels with known ground truth.
        """
        e = as_float_array(errors, "errors", allow_nan=False).ravel()
        n_gt = e.size if n_gt_valid is None else int(n_gt_valid)
        if n_gt < e.size:
            raise PrismapInputError(f"`n_gt_valid` ({n_gt}) is smaller than the number of errors ({e.size})")
        empty = cls.empty(bin_width=bin_width, limit_px=limit_px)
        index = np.floor((e + empty.limit_px) / empty.bin_width).astype(np.int64)
        inside = (index >= 0) & (index < empty.counts.size)
        magnitude = np.abs(e)
        return cls(
            np.bincount(index[inside], minlength=empty.counts.size),
            empty.bin_width,
            empty.limit_px,
            n_below=int((index < 0).sum()),
            n_above=int((index >= empty.counts.size).sum()),
            n_gt_valid=n_gt,
            n_bad_1px=int((magnitude > 1.0).sum()),
            n_bad_2px=int((magnitude > 2.0).sum()),
            sum_abs_error_px=round(float(magnitude.sum()) / SUM_RESOLUTION_PX) * SUM_RESOLUTION_PX,
            n_frames=1,
        )

    def __add__(self, other):
        if not isinstance(other, ErrorHistogram):
            return NotImplemented
        if self.counts.size != other.counts.size or self.bin_width != other.bin_width:
            raise PrismapInputError(
                "only histograms with the same bins add up; got bin width "
                f"{self.bin_width} / limit {self.limit_px} and {other.bin_width} / {other.limit_px}"
            )
        return ErrorHistogram(
            self.counts + other.counts,
            self.bin_width,
            self.limit_px,
            **{name: getattr(self, name) + getattr(other, name) for name in _SUMMED},
        )

    @property
    def edges(self) -> npt.NDArray[np.float64]:
        """(B + 1,) float64, pixels: bin edges."""
        return -self.limit_px + self.bin_width * np.arange(self.counts.size + 1)

    @property
    def centres(self) -> npt.NDArray[np.float64]:
        """(B,) float64, pixels: bin centres."""
        return -self.limit_px + self.bin_width * (np.arange(self.counts.size) + 0.5)

    @property
    def n_errors(self) -> int:
        """Pixels with both a computed value and ground truth, binned or not."""
        return int(self.counts.sum()) + self.n_below + self.n_above

    @property
    def coverage(self) -> float:
        """Share of ground-truth pixels with a computed value."""
        return self.n_errors / self.n_gt_valid if self.n_gt_valid else float("nan")

    @property
    def bad_1px(self) -> float:
        """Share of computed pixels with ``|e| > 1`` px."""
        return self.n_bad_1px / self.n_errors if self.n_errors else float("nan")

    @property
    def bad_2px(self) -> float:
        """Share of computed pixels with ``|e| > 2`` px."""
        return self.n_bad_2px / self.n_errors if self.n_errors else float("nan")

    @property
    def mean_abs_error_px(self) -> float:
        """Mean ``|e|`` (pixels) over computed pixels."""
        return self.sum_abs_error_px / self.n_errors if self.n_errors else float("nan")

    def density(self) -> npt.NDArray[np.float64]:
        """(B,) float64, 1/pixel: the binned errors as a probability density (integrates to 1)."""
        total = self.counts.sum()
        if total == 0:
            raise PrismapInputError("the error histogram is empty: no error to show as a density")
        return self.counts / (total * self.bin_width)

    def statistics(self) -> dict[str, int | float]:
        """The summary numbers as a JSON-ready dict."""
        return {
            "n_frames": self.n_frames,
            "n_errors": self.n_errors,
            "n_gt_valid": self.n_gt_valid,
            "n_outside_bins": self.n_below + self.n_above,
            "coverage": self.coverage,
            "bad_1px": self.bad_1px,
            "bad_2px": self.bad_2px,
            "mean_abs_error_px": self.mean_abs_error_px,
        }


_SUMMED = ("n_below", "n_above", "n_gt_valid", "n_bad_1px", "n_bad_2px", "sum_abs_error_px", "n_frames")
