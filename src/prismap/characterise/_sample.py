"""A bounded, seeded sample of characterised pixels (features and errors) over any number of frames.

The class search (:func:`prismap.characterise.choose_classes`) needs the features and the error of
single pixels, which cannot all be kept for 100 frames. Each characterised pixel of the frame at
position ``p`` of the selection draws a priority from ``numpy.random.default_rng((seed, p))``; a sample
keeps the ``capacity`` pixels of lowest priority (ties broken by frame, then pixel index). That is a
uniform sample without replacement of every pixel seen (bottom-k sampling), and the lowest ``capacity``
of a union is the lowest ``capacity`` of the parts' lowest, so samples of chunks of frames merge
(``a + b``) into exactly the sample of all of them, in any order and on any worker.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from prismap._validate import check_integer
from prismap.characterise._features import PixelFeatures
from prismap.errors import PrismapInputError

DEFAULT_MAX_SAMPLES = 4_000_000
"""Pixels the class search keeps (about 50 bytes each with four features: 200 MB)."""


def characterised_pixels(features, disparity_gt):
    """(H, W) bool: pixels with a computed disparity, finite ground truth and no NaN feature (the class fits' pixels)."""
    keep = features.valid & np.isfinite(disparity_gt)
    for array in features.values.values():
        keep &= ~np.isnan(array)
    return keep


@dataclass(frozen=True, eq=False)
class PixelSample:
    """At most ``capacity`` characterised pixels drawn uniformly from the frames added so far.

    Attributes
    ----------
    capacity : int
        Most pixels kept.
    n_seen : int
        Characterised pixels (finite computed disparity, finite ground truth, no NaN feature) seen.
    priority : (n,) float64
        Each kept pixel's random priority in [0, 1).
    frame : (n,) int64
        Position in the frame selection of each kept pixel.
    pixel : (n,) int64
        Its flat index in the image.
    right_half : (n,) bool
        Whether its column lies in the right half of the image.
    values : dict of str -> (n,) float32, units of each feature
    errors : (n,) float64, pixels
        ``e = d_true - d_computed``.
    """

    capacity: int
    n_seen: int
    priority: np.ndarray
    frame: np.ndarray
    pixel: np.ndarray
    right_half: np.ndarray
    values: dict
    errors: np.ndarray

    @classmethod
    def from_frame(
        cls,
        features: PixelFeatures,
        disparity_gt: npt.ArrayLike,
        position: int,
        *,
        capacity: int = DEFAULT_MAX_SAMPLES,
        seed: int = 0,
        name: str = "frame",
    ) -> PixelSample:
        """The sample of one frame's characterised pixels.

        Parameters
        ----------
        features : PixelFeatures
            Of the frame's computed disparity (its ``disparity_px`` is the computed disparity).
        disparity_gt : (H, W) float, pixels, NaN or infinity = unknown
        position : int, >= 0
            The frame's position in the selection: seeds its priorities and picks its held-out fold.
        capacity : int, >= 1
        seed : int
        name : str
            Names the frame in error messages.
        """
        check_integer(capacity, "max_samples", expected="an integer >= 1", condition=lambda n: n >= 1)
        computed = features.values["disparity_px"]
        truth = np.asarray(disparity_gt, dtype=np.float64)
        if truth.shape != computed.shape:
            raise PrismapInputError(
                f"{name}: disparity and ground truth differ in shape: {computed.shape} vs {truth.shape}"
            )
        keep = characterised_pixels(features, truth)
        pixel = np.flatnonzero(keep)
        priority = np.random.default_rng((int(seed), int(position))).random(pixel.size)
        chosen = np.arange(pixel.size)
        if pixel.size > capacity:
            chosen = np.sort(np.lexsort((pixel, priority))[: int(capacity)])
        pixel = pixel[chosen]
        width = keep.shape[1]
        return cls(
            capacity=int(capacity),
            n_seen=int(keep.sum()),
            priority=priority[chosen],
            frame=np.full(pixel.size, int(position), dtype=np.int64),
            pixel=pixel,
            right_half=pixel % width >= width / 2,
            values={feature: array.ravel()[pixel].astype(np.float32) for feature, array in features.values.items()},
            errors=(truth.ravel() - computed.ravel().astype(np.float64))[pixel],
        )

    def __add__(self, other):
        if not isinstance(other, PixelSample):
            return NotImplemented
        if self.capacity != other.capacity:
            raise PrismapInputError(f"only samples of one capacity merge; got {self.capacity} and {other.capacity}")
        if set(self.values) != set(other.values):
            raise PrismapInputError(
                f"frames have features {sorted(other.values)}; earlier frames had {sorted(self.values)}"
            )
        priority = np.concatenate((self.priority, other.priority))
        frame = np.concatenate((self.frame, other.frame))
        pixel = np.concatenate((self.pixel, other.pixel))
        order = np.lexsort((pixel, frame, priority))[: self.capacity]
        order = order[np.lexsort((pixel[order], frame[order]))]  # canonical order: by frame, then pixel
        return PixelSample(
            capacity=self.capacity,
            n_seen=self.n_seen + other.n_seen,
            priority=priority[order],
            frame=frame[order],
            pixel=pixel[order],
            right_half=np.concatenate((self.right_half, other.right_half))[order],
            values={name: np.concatenate((array, other.values[name]))[order] for name, array in self.values.items()},
            errors=np.concatenate((self.errors, other.errors))[order],
        )

    @property
    def n_samples(self) -> int:
        """Pixels kept."""
        return int(self.errors.size)

    @property
    def exhaustive(self) -> bool:
        """Whether every characterised pixel seen is kept."""
        return self.n_samples == self.n_seen

    def arrays(self) -> tuple[dict[str, npt.NDArray[np.float64]], np.ndarray, npt.NDArray[np.int64], str]:
        """What the class search takes: float64 features, errors, the held-out fold of each pixel, its description.

        The folds are frames of even and odd position when the sample holds two frames or more, else the
        left and right image halves.
        """
        values = {name: array.astype(np.float64) for name, array in self.values.items()}
        if np.unique(self.frame).size >= 2:
            return values, self.errors, self.frame % 2, "two folds: frames of even / odd index"
        return values, self.errors, self.right_half.astype(np.int64), "two folds: left / right image halves (one frame)"
