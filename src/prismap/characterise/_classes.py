"""Error classes: boxes in the space of confidence features that split pixels into classes of one error mixture.

Class ``k`` holds the pixels whose features satisfy ``lower[k, f] <= x_f < upper[k, f]`` for every feature
``f`` (``upper = +inf`` includes ``+inf``). The boxes must tile the feature space exactly: no gap, no
overlap, so every pixel with a valid disparity falls in exactly one class. With no feature there is one
class holding every valid pixel (a plain, unconditioned error model).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from prismap.characterise._features import FEATURE_UNITS
from prismap.errors import PrismapInputError

NO_CLASS = -1
"""Class of a pixel without a valid disparity (or with NaN in a feature the classes use)."""


@dataclass(frozen=True, eq=False)
class ErrorClasses:
    """Boxes over the features ``features`` that tile their space.

    Attributes
    ----------
    features : tuple of str
        Names of :data:`prismap.characterise.FEATURE_UNITS` the classes split on (0, 1 or 2 of them).
    lower, upper : (K, F) float64, units of each feature
        Bounds of class ``k`` on feature ``f``; ``-inf`` and ``+inf`` allowed.
    """

    features: tuple
    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        features = tuple(self.features)
        unknown = [name for name in features if name not in FEATURE_UNITS]
        if unknown or len(set(features)) != len(features):
            raise PrismapInputError(
                f"error classes: features must be distinct names of {list(FEATURE_UNITS)}; got {list(features)}"
            )
        try:
            lower = np.array(self.lower, dtype=np.float64)
            upper = np.array(self.upper, dtype=np.float64)
        except (TypeError, ValueError):
            raise PrismapInputError("error classes: `lower` and `upper` must be arrays of numbers") from None
        if lower.ndim != 2 or lower.shape[0] == 0 or lower.shape[1] != len(features) or upper.shape != lower.shape:
            raise PrismapInputError(
                f"error classes: `lower` and `upper` must both be (K >= 1, {len(features)}); "
                f"got {lower.shape} and {upper.shape}"
            )
        if np.isnan(lower).any() or np.isnan(upper).any() or not (lower < upper).all():
            bad = int(np.flatnonzero(~(lower < upper).all(axis=1))[0]) if not (lower < upper).all() else None
            raise PrismapInputError(
                "error classes: every bound must be a number with lower < upper"
                + (
                    f"; class {bad} has lower {lower[bad].tolist()} and upper {upper[bad].tolist()}"
                    if bad is not None
                    else ""
                )
            )
        _check_tiling(features, lower, upper)
        for array in (lower, upper):
            array.setflags(write=False)
        object.__setattr__(self, "features", features)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @classmethod
    def single(cls) -> ErrorClasses:
        """One class holding every valid pixel (no feature)."""
        return cls((), np.zeros((1, 0)), np.zeros((1, 0)))

    @classmethod
    def from_edges(cls, features: Sequence[str], edges: Sequence[npt.ArrayLike]) -> ErrorClasses:
        """The grid of bins ``edges[f]`` (interior edges, increasing) on each feature; class index row-major."""
        features = tuple(features)
        if len(edges) != len(features):
            raise PrismapInputError(
                f"error classes: {len(features)} feature(s) need as many edge lists; got {len(edges)}"
            )
        bins = []
        for interior in edges:
            bounds = np.concatenate(([-np.inf], np.asarray(interior, dtype=np.float64).ravel(), [np.inf]))
            bins.append(list(itertools.pairwise(bounds)))
        cells = list(itertools.product(*bins))  # row-major: the last feature varies fastest
        lower = np.array([[low for low, _ in cell] for cell in cells]).reshape(len(cells), len(features))
        upper = np.array([[high for _, high in cell] for cell in cells]).reshape(len(cells), len(features))
        return cls(features, lower, upper)

    @property
    def n_classes(self) -> int:
        """Number of classes K."""
        return self.lower.shape[0]

    def bounds(self, k: int) -> dict[str, tuple[float, float]]:
        """``{feature: (lower, upper)}`` of class ``k``."""
        return {name: (float(self.lower[k, f]), float(self.upper[k, f])) for f, name in enumerate(self.features)}

    def assign(self, values: Mapping[str, np.ndarray], valid: np.ndarray | None = None) -> npt.NDArray[np.int32]:
        """Class of each sample: int32 of the samples' shape, :data:`NO_CLASS` where invalid or NaN.

        Parameters
        ----------
        values : dict of str -> array, units of each feature
            At least the arrays of :attr:`features`, all of one shape.
        valid : bool array of that shape or None
            Samples to classify (default: all).
        """
        missing = [name for name in self.features if name not in values]
        if missing:
            raise PrismapInputError(f"error classes need feature(s) {missing}; got only {sorted(values)}")
        arrays = [np.asarray(values[name], dtype=np.float64) for name in self.features]
        shape = np.shape(valid) if valid is not None else (arrays[0].shape if arrays else None)
        if shape is None:
            raise PrismapInputError("error classes without features need the `valid` mask to know the shape")
        keep = np.ones(shape, bool) if valid is None else np.asarray(valid, dtype=bool).copy()
        for name, array in zip(self.features, arrays):
            if array.shape != shape:
                raise PrismapInputError(f"feature {name!r} has shape {array.shape}; expected {shape}")
            keep &= ~np.isnan(array)
        label = np.full(shape, NO_CLASS, dtype=np.int32)
        if not self.features:
            label[keep] = 0
            return label
        # Each feature's bounds split its axis into intervals; a class is a box of such intervals.
        index = np.zeros(shape, dtype=np.int64)
        for f, array in enumerate(arrays):
            cuts = np.unique(np.concatenate((self.lower[:, f], self.upper[:, f])))
            interval = np.searchsorted(cuts, array, side="right") - 1
            interval = np.minimum(interval, cuts.size - 2)  # +inf lies in the last interval
            index = index * (cuts.size - 1) + np.where(keep, interval, 0)
        lookup = self._interval_lookup()
        label[keep] = lookup[index[keep]]
        return label

    def _interval_lookup(self):
        """(prod of interval counts,) int32: the class of every box of the feature-wise interval grid."""
        cut_lists = [np.unique(np.concatenate((self.lower[:, f], self.upper[:, f]))) for f in range(len(self.features))]
        sizes = [c.size - 1 for c in cut_lists]
        lookup = np.full(int(np.prod(sizes)), NO_CLASS, dtype=np.int32)
        for k in range(self.n_classes):
            ranges = [
                np.flatnonzero((c[:-1] >= self.lower[k, f]) & (c[1:] <= self.upper[k, f]))
                for f, c in enumerate(cut_lists)
            ]
            for cell in np.array(np.meshgrid(*ranges, indexing="ij")).reshape(len(sizes), -1).T:
                lookup[np.ravel_multi_index(tuple(cell), sizes)] = k
        return lookup

    def to_list(self) -> list[dict[str, list[float | None]]]:
        """JSON form: one ``{feature: [lower or null, upper or null]}`` per class (null = infinite)."""
        return [
            {
                name: [None if np.isinf(lo) else lo, None if np.isinf(hi) else hi]
                for name, (lo, hi) in self.bounds(k).items()
            }
            for k in range(self.n_classes)
        ]


def _check_tiling(features, lower, upper):
    """Raise unless the boxes cover the whole feature space exactly once (no gap, no overlap)."""
    if not features:
        if lower.shape[0] != 1:
            raise PrismapInputError(f"error classes: without features there is exactly one class; got {lower.shape[0]}")
        return
    cuts = []
    for f, name in enumerate(features):
        c = np.unique(np.concatenate((lower[:, f], upper[:, f])))
        if c[0] != -np.inf or c[-1] != np.inf:
            raise PrismapInputError(
                f"error classes leave a gap: feature {name!r} is covered only from {c[0]} to {c[-1]}, "
                "not from -inf to +inf"
            )
        cuts.append(c)
    for cell in np.ndindex(*[c.size - 1 for c in cuts]):
        low = np.array([cuts[f][i] for f, i in enumerate(cell)])
        high = np.array([cuts[f][i + 1] for f, i in enumerate(cell)])
        holders = np.flatnonzero(((lower <= low) & (upper >= high)).all(axis=1))
        where = ", ".join(f"{name} in [{a:g}, {b:g})" for name, a, b in zip(features, low, high))
        if holders.size == 0:
            raise PrismapInputError(f"error classes leave a gap: no class holds {where}")
        if holders.size > 1:
            raise PrismapInputError(f"error classes overlap: classes {holders.tolist()} all hold {where}")
