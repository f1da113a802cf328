"""Per-pixel confidence features of a computed disparity: what a run knows about where its matcher fails.

Every feature is computed from the rectified images and the computed disparity alone (no ground truth),
so a mapping run can compute it for each frame and pick the error mixture of each pixel's class.

- ``edge_distance_px`` (pixels): Euclidean distance to the nearest discontinuity of the computed
  disparity. A pixel is a discontinuity when the disparity jumps by more than ``edge_threshold_px``
  to one of its 4-neighbours (both pixels of the pair are marked) or when it is invalid itself
  (NaN): invalid pixels are where matching failed (occlusions, no texture) and border the depth edges,
  so they count as edges. A frame with no edge at all has ``+inf`` everywhere.
- ``texture`` (grey levels per pixel): ``sqrt`` of the mean squared Sobel gradient magnitude of the
  left grey image over a ``texture_window_px`` square window (Sobel normalised by 1/8 so it estimates
  the derivative; borders reflected as OpenCV's ``BORDER_REFLECT_101``).
- ``disparity_gradient`` (pixels per pixel): the mean magnitude of the computed disparity's gradient
  (Sobel normalised by 1/8) over the same ``texture_window_px`` window, averaged over the pixels whose
  3x3 neighbourhood is wholly valid (``+inf`` where the window holds none). It is large where the
  computed disparity is rough or slanted; matchers err more where it is large (on the room's SGBM
  frames, not explained by the true surface slant), which neither the distance to a discontinuity nor
  the image texture sees.
- ``lr_disagreement_px`` (pixels): the left-right disagreement of the matcher's check
  (:func:`prismap.stereo.left_right_disagreement`); only when the check runs.
- ``disparity_px`` (pixels): the computed disparity itself.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt
from scipy import ndimage

from prismap._validate import as_float_array, check_positive
from prismap.errors import PrismapInputError

FEATURE_UNITS = {
    "edge_distance_px": "px",
    "texture": "grey levels / px",
    "disparity_gradient": "px / px",
    "lr_disagreement_px": "px",
    "disparity_px": "px",
}
"""Every feature name and its unit, in the order they are tried as class splits."""

LR_FEATURE = "lr_disagreement_px"
DEFAULT_EDGE_THRESHOLD_PX = 1.0
DEFAULT_TEXTURE_WINDOW_PX = 7


@dataclass(frozen=True, eq=False)
class PixelFeatures:
    """The confidence features of one frame.

    Attributes
    ----------
    values : dict of str -> (H, W) float64
        One array per feature name of :data:`FEATURE_UNITS` that could be computed (units there).
    valid : (H, W) bool
        Pixels with a finite computed disparity.
    settings : dict
        ``edge_threshold_px`` and ``texture_window_px``: a model fitted on features made with other
        settings refuses these (see :meth:`prismap.characterise.ErrorModel.classify`).
    """

    values: dict
    valid: np.ndarray
    settings: dict = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the features present."""
        return tuple(self.values)

    @property
    def shape(self) -> tuple[int, ...]:
        """``(H, W)`` of the frame."""
        return self.valid.shape


def discontinuity_mask(
    disparity: npt.ArrayLike, *, edge_threshold_px: float = DEFAULT_EDGE_THRESHOLD_PX
) -> npt.NDArray[np.bool_]:
    """(H, W) bool: pixels on a disparity discontinuity (a 4-neighbour jump above the threshold, or invalid)."""
    d = as_float_array(disparity, "disparity", ndim=2)
    threshold = check_positive(edge_threshold_px, "edge_threshold_px")
    edges = ~np.isfinite(d)
    with np.errstate(invalid="ignore"):
        jump_x = np.abs(np.diff(d, axis=1)) > threshold
        jump_y = np.abs(np.diff(d, axis=0)) > threshold
    edges[:, 1:] |= jump_x
    edges[:, :-1] |= jump_x
    edges[1:, :] |= jump_y
    edges[:-1, :] |= jump_y
    return edges


def edge_distance(disparity, *, edge_threshold_px=DEFAULT_EDGE_THRESHOLD_PX):
    """(H, W) float64, pixels: Euclidean distance to the nearest pixel of :func:`discontinuity_mask` (scipy's exact
    transform: OpenCV's ``DIST_MASK_PRECISE`` is 3x faster but its last float32 bit follows its thread count, and
    a Dask run must classify every pixel as the sequential one does)."""
    edges = discontinuity_mask(disparity, edge_threshold_px=edge_threshold_px)
    if not edges.any():
        return np.full(edges.shape, np.inf)
    return ndimage.distance_transform_edt(~edges)


def texture_strength(grey, *, window_px=DEFAULT_TEXTURE_WINDOW_PX):
    """(H, W) float64, grey levels per pixel: RMS Sobel gradient magnitude over a square window.

    Parameters
    ----------
    grey : (H, W) uint8 or float, grey levels
    window_px : int, odd, >= 1
    """
    image = as_float_array(grey, "left_grey", ndim=2, allow_nan=False)
    window = _odd_window(window_px)
    gx = cv2.Sobel(image, cv2.CV_64F, 1, 0, ksize=3, scale=0.125, borderType=cv2.BORDER_REFLECT_101)
    gy = cv2.Sobel(image, cv2.CV_64F, 0, 1, ksize=3, scale=0.125, borderType=cv2.BORDER_REFLECT_101)
    energy = cv2.boxFilter(
        gx * gx + gy * gy, cv2.CV_64F, (window, window), normalize=True, borderType=cv2.BORDER_REFLECT_101
    )
    return np.sqrt(np.maximum(energy, 0.0))


def disparity_gradient(
    disparity: npt.ArrayLike, *, window_px: int = DEFAULT_TEXTURE_WINDOW_PX
) -> npt.NDArray[np.float64]:
    """(H, W) float64, pixels per pixel: mean Sobel gradient magnitude of the disparity over a square window.

    Only pixels whose 3x3 neighbourhood is wholly finite have a gradient; the window averages those
    (borders reflected as OpenCV's ``BORDER_REFLECT_101``) and is ``+inf`` where it holds none.

    Parameters
    ----------
    disparity : (H, W) float, pixels, NaN = invalid
    window_px : int, odd, >= 1
    """
    d = as_float_array(disparity, "disparity", ndim=2)
    window = _odd_window(window_px)
    finite = np.isfinite(d)
    filled = np.where(finite, d, 0.0)
    border = cv2.BORDER_REFLECT_101
    gx = cv2.Sobel(filled, cv2.CV_64F, 1, 0, ksize=3, scale=0.125, borderType=border)
    gy = cv2.Sobel(filled, cv2.CV_64F, 0, 1, ksize=3, scale=0.125, borderType=border)
    defined = cv2.erode(finite.astype(np.uint8), np.ones((3, 3), np.uint8), borderType=border).astype(bool)
    magnitude = np.multiply(gx, gx, out=gx)  # sqrt(gx^2 + gy^2) in place: np.hypot is 4x slower
    magnitude += np.multiply(gy, gy, out=gy)
    np.sqrt(magnitude, out=magnitude)
    magnitude[~defined] = 0.0
    total = cv2.boxFilter(magnitude, cv2.CV_64F, (window, window), normalize=False, borderType=border)
    count = cv2.boxFilter(defined.astype(np.float64), cv2.CV_64F, (window, window), normalize=False, borderType=border)
    mean = np.full(d.shape, np.inf)
    np.divide(np.maximum(total, 0.0), count, out=mean, where=count > 0.5)
    return mean


def _odd_window(window_px):
    window = int(window_px)
    if window != window_px or window < 1 or window % 2 == 0:
        raise PrismapInputError(f"`texture_window_px` must be an odd integer >= 1; got {window_px!r}")
    return window


def compute_features(
    left_grey: npt.ArrayLike,
    right_grey: npt.ArrayLike | None,
    disparity: npt.ArrayLike,
    lr_disagreement: npt.ArrayLike | None = None,
    *,
    edge_threshold_px: float = DEFAULT_EDGE_THRESHOLD_PX,
    texture_window_px: int = DEFAULT_TEXTURE_WINDOW_PX,
    names: Iterable[str] | None = None,
) -> PixelFeatures:
    """The confidence features of one frame (see the module docstring for each).

    Parameters
    ----------
    left_grey : (H, W) uint8 or float, grey levels
        Rectified left image (RGB: convert first, e.g. ``cv2.cvtColor``).
    right_grey : (H, W) uint8 or float or None, grey levels
        Rectified right image; checked for shape only (no feature uses it yet).
    disparity : (H, W) float, pixels, NaN = invalid
        Computed disparity of the left image.
    lr_disagreement : (H, W) float, pixels, NaN = not measurable, or None
        From :meth:`prismap.stereo.StereoMatcher.compute_with_confidence`; None when the matcher
        ran no left-right check (the feature is then absent).
    edge_threshold_px : float, pixels
    texture_window_px : int, pixels, odd
    names : iterable of str or None
        Only these features (of :data:`FEATURE_UNITS`; a mapping run's classes use two or three), besides
        ``disparity_px``; None: every feature the inputs allow.

    Returns
    -------
    PixelFeatures
    """
    d = as_float_array(disparity, "disparity", ndim=2)
    left = np.asarray(left_grey)
    if left.shape != d.shape:
        raise PrismapInputError(f"`left_grey` must be 2-D of the disparity's shape {d.shape}; got {left.shape}")
    if right_grey is not None and np.shape(right_grey) != d.shape:
        raise PrismapInputError(f"`right_grey` must have the disparity's shape {d.shape}; got {np.shape(right_grey)}")
    check_positive(edge_threshold_px, "edge_threshold_px")
    _odd_window(texture_window_px)
    wanted = set(FEATURE_UNITS) if names is None else set(names)
    unknown = sorted(wanted - set(FEATURE_UNITS))
    if unknown:
        raise PrismapInputError(f"unknown feature(s) {unknown}; the features are {list(FEATURE_UNITS)}")
    values = {}
    if "edge_distance_px" in wanted:
        values["edge_distance_px"] = edge_distance(d, edge_threshold_px=edge_threshold_px)
    if "texture" in wanted:
        values["texture"] = texture_strength(left, window_px=texture_window_px)
    if "disparity_gradient" in wanted:
        values["disparity_gradient"] = disparity_gradient(d, window_px=texture_window_px)
    if lr_disagreement is not None and LR_FEATURE in wanted:
        values[LR_FEATURE] = as_float_array(lr_disagreement, "lr_disagreement", shape=d.shape)
    values["disparity_px"] = d
    settings = {"edge_threshold_px": float(edge_threshold_px), "texture_window_px": int(texture_window_px)}
    return PixelFeatures(values, np.isfinite(d), settings)
