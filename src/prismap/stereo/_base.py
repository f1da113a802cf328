"""The interface every stereo matcher implements, the left-right check, and the name -> matcher registry."""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from prismap.errors import PrismapInputError


class StereoMatcher(ABC):
    """A dense matcher on a rectified pair: ``compute(left, right)`` -> disparity of the left image.

    Output is ``(H, W) float32`` in pixels with NaN where the matcher gives no value. Subclasses take
    their parameters as keyword arguments with documented defaults and report them in :meth:`params`
    (saved with every error model, so a characterisation says what produced it).
    """

    name = "base"

    @abstractmethod
    def compute(self, left: np.ndarray, right: np.ndarray) -> npt.NDArray[np.float32]:
        """Disparity of ``left`` against ``right``: (H, W) float32, pixels, NaN = invalid."""

    def compute_with_confidence(
        self, left: np.ndarray, right: np.ndarray
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32] | None]:
        """Disparity of ``left`` and the left-right disagreement behind it, when the matcher checks it.

        Returns
        -------
        disparity : (H, W) float32, pixels, NaN = invalid
            Exactly what :meth:`compute` returns.
        lr_disagreement : (H, W) float32, pixels, or None
            See :func:`left_right_disagreement`; None for matchers that run no left-right check (the
            default here).
        """
        return self.compute(left, right), None

    @abstractmethod
    def params(self) -> dict[str, Any]:
        """The matcher's parameters as a JSON-serialisable dict."""

    def search_range_px(self) -> tuple[float, float] | None:
        """``(lo, hi)``, pixels: the disparity search interval (:func:`search_range` of :meth:`params`)."""
        return search_range(self.params())


def search_range(params: Mapping[str, Any]) -> tuple[float, float] | None:
    """The disparity search interval ``(lo, hi)`` (pixels) a matcher's parameters set, or None if they set none.

    OpenCV's matchers search ``[min_disparity, min_disparity + num_disparities)``; the variational matcher
    ``[min_disparity, max_disparity]``. A matcher that fails returns a disparity roughly uniform over it,
    which the error model's failure component describes (:class:`prismap.gmm.GaussianMixture`).
    """
    low = params.get("min_disparity", 0)
    if "num_disparities" in params:
        return (float(low), float(low) + float(params["num_disparities"]))
    if "max_disparity" in params:
        return (float(low), float(params["max_disparity"]))
    return None


_MATCHERS = {
    "bm": "prismap.stereo._opencv:BlockMatcher",
    "sgbm": "prismap.stereo._opencv:SemiGlobalMatcher",
    "variational": "prismap.stereo._variational:VariationalMatcher",
}


def matcher_names() -> tuple[str, ...]:
    """Names accepted by :func:`make_matcher`."""
    return tuple(_MATCHERS)


def make_matcher(name: str, **params: Any) -> StereoMatcher:
    """Build the matcher called ``name`` (``bm``, ``sgbm``, ``variational``) with keyword ``params``."""
    try:
        module_name, class_name = _MATCHERS[name].split(":")
    except KeyError:
        raise PrismapInputError(f"unknown matcher {name!r}; expected one of {list(_MATCHERS)}") from None
    return getattr(importlib.import_module(module_name), class_name)(**params)


def left_right_disagreement(disparity_left: npt.ArrayLike, disparity_right: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """How far each left pixel's match is from mapping back (dual matching, thesis sec. 3.2.2).

    A left pixel ``(v, u)`` with disparity ``d`` looks up the right image's disparity at
    ``(v, round(u - d))``; the disagreement is the absolute difference of the two.

    Parameters
    ----------
    disparity_left, disparity_right : (H, W) float32, pixels, NaN = invalid
        Disparity of the left image, and of the right image against the left (positive values).

    Returns
    -------
    (H, W) float32, pixels: ``|d_right(v, round(u - d)) - d|``; NaN where the left disparity is invalid,
    the match falls outside the image or the right disparity there is invalid.
    """
    left = np.asarray(disparity_left, dtype=np.float32)
    right = np.asarray(disparity_right, dtype=np.float32)
    if left.shape != right.shape or left.ndim != 2:
        raise PrismapInputError(
            f"left-right check needs two 2-D disparity maps of one shape; got {left.shape} and {right.shape}"
        )
    height, width = left.shape
    columns = np.arange(width)[None, :] - np.nan_to_num(left, nan=-1e9)
    target = np.rint(columns).astype(np.int64)
    inside = np.isfinite(left) & (target >= 0) & (target < width)
    rows = np.broadcast_to(np.arange(height)[:, None], left.shape)
    back = np.full(left.shape, np.nan, dtype=np.float32)
    back[inside] = right[rows[inside], target[inside]]
    return np.abs(back - left)


def left_right_check(
    disparity_left: npt.ArrayLike, disparity_right: npt.ArrayLike, *, max_difference_px: float = 1.0
) -> npt.NDArray[np.float32]:
    """Invalidate pixels whose match does not map back within ``max_difference_px`` (occlusions fail it).

    Parameters
    ----------
    disparity_left, disparity_right : (H, W) float32, pixels, NaN = invalid
        As in :func:`left_right_disagreement`.
    max_difference_px : float, pixels

    Returns
    -------
    (H, W) float32: ``disparity_left`` with failing pixels set to NaN.
    """
    disagreement = left_right_disagreement(disparity_left, disparity_right)
    keep = disagreement <= max_difference_px
    return np.where(keep, np.asarray(disparity_left, dtype=np.float32), np.float32(np.nan)).astype(np.float32)


def check_stereo_pair(left, right):
    """Both images as contiguous uint8 arrays of one (H, W) or (H, W, 3) shape, else raise naming the image."""
    pair = []
    for name, image in (("left", left), ("right", right)):
        image = np.asarray(image)
        if image.dtype != np.uint8 or not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
            raise PrismapInputError(
                f"`{name}` must be an (H, W) grey or (H, W, 3) RGB uint8 image; got shape {image.shape}, dtype {image.dtype}"
            )
        pair.append(np.ascontiguousarray(image))
    if pair[0].shape != pair[1].shape:
        raise PrismapInputError(f"`left` and `right` must have one shape; got {pair[0].shape} and {pair[1].shape}")
    return tuple(pair)


def to_grey(image):
    """(H, W) uint8 grey of a grey or RGB uint8 image (RGB through OpenCV's luma weights)."""
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
