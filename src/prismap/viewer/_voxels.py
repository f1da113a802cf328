"""What the viewer draws, as plain arrays: a level-of-detail pyramid of voxels, the selection a viewer's
controls ask for, and the colours of probabilities. No server or browser here, so it is tested alone."""

from __future__ import annotations

import functools
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from prismap.errors import PrismapInputError
from prismap.grid import key_to_center
from prismap.io import GroundTruthOccupancy

COLORMAP = "viridis"
"""Matplotlib colormap of P(occupied): 0 = dark violet (free), 0.5 = teal, 1 = yellow (occupied)."""

UNKNOWN_COLOR = (150, 150, 150)
"""Grey of the unobserved cells inside the map's box."""

CLASSES = ("free", "unknown", "occupied")
"""Voxel classes by the map's thresholds: free ``P < free_threshold``, occupied ``P >= occupied_threshold``,
unknown between them (observed but undecided; unobserved space is drawn as its own grey layer)."""


def probability_colors(probability: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """(N, 3) uint8 RGB of :data:`COLORMAP` at each probability (256 levels, clipped to [0, 1])."""
    p = np.clip(np.nan_to_num(np.asarray(probability, dtype=np.float32), nan=0.5), 0.0, 1.0)
    return _colormap_table()[np.round(p * 255).astype(np.intp)]


@functools.cache
def _colormap_table():
    from matplotlib import colormaps

    return np.round(colormaps[COLORMAP](np.linspace(0.0, 1.0, 256))[:, :3] * 255).astype(np.uint8)


@dataclass(frozen=True)
class VoxelLevel:
    """Voxels aggregated to ``2**level`` times the map's voxel edge.

    Attributes
    ----------
    level : int
    size_m : float, metres
        Edge of one voxel of this level.
    keys : (N, 3) int64
        ``floor(x / size_m)``, unique (sorted lexicographically above level 0).
    probability : (N,) float32
        Largest P(occupied) of the map's voxels inside (an occupied voxel is never hidden by coarsening).
    """

    level: int
    size_m: float
    keys: np.ndarray
    probability: np.ndarray

    @property
    def centers_w(self) -> npt.NDArray[np.float32]:
        """(N, 3) float32 voxel centres, metres, world frame."""
        return key_to_center(self.keys, self.size_m).astype(np.float32)


def coarsen(level: VoxelLevel) -> VoxelLevel:
    """The next level: keys halved (floor), each parent holding the largest probability of its children."""
    keys, probability = _group_max(level.keys >> 1, level.probability)
    return VoxelLevel(level.level + 1, 2.0 * level.size_m, keys, probability)


def _group_max(keys, probability):
    """Unique ``keys`` (sorted) and the largest ``probability`` of each."""
    if len(keys) == 0:
        return keys, probability
    lo = keys.min(axis=0)
    flat = np.ravel_multi_index((keys - lo).T, keys.max(axis=0) - lo + 1)
    order = np.argsort(flat)
    flat = flat[order]
    starts = np.flatnonzero(np.r_[True, flat[1:] != flat[:-1]])
    return keys[order][starts], np.maximum.reduceat(probability[order], starts)


def voxel_pyramid(
    keys: npt.ArrayLike, probability: npt.ArrayLike, voxel_size_m: float, *, min_voxels: int = 4096
) -> VoxelPyramid:
    """Levels 0, 1, ... of a voxel set, each coarser level half the resolution, until one has at most
    ``min_voxels`` voxels or stops shrinking.

    Parameters
    ----------
    keys : (N, 3) int, voxel keys of the map, unique (as a map's are)
    probability : (N,) float, P(occupied)
    voxel_size_m : float, metres

    Returns
    -------
    VoxelPyramid
        Coarser levels are computed when first asked for (a view that fits the budget never pays for them).
    """
    keys = np.asarray(keys)
    probability = np.asarray(probability)
    if keys.ndim != 2 or keys.shape[1] != 3 or probability.shape != (keys.shape[0],):
        raise PrismapInputError(
            f"`keys` must be (N, 3) with (N,) `probability`; got {keys.shape} and {probability.shape}"
        )
    if not voxel_size_m > 0:
        raise PrismapInputError(f"`voxel_size_m` must be > 0; got {voxel_size_m!r}")
    return VoxelPyramid(
        VoxelLevel(0, float(voxel_size_m), keys.astype(np.int64), probability.astype(np.float32)), min_voxels
    )


class VoxelPyramid:
    """The levels of :func:`voxel_pyramid`, computed lazily; iterate (finest first) or index them."""

    def __init__(self, base: VoxelLevel, min_voxels: int) -> None:
        self._levels = [base]
        self._min_voxels = min_voxels
        self._complete = False

    def _grow(self):
        """Add the next level; False when the last one is already coarse enough or stopped shrinking."""
        last = self._levels[-1]
        if self._complete or len(last.keys) <= self._min_voxels:
            self._complete = True
            return False
        nxt = coarsen(last)
        if len(nxt.keys) == len(last.keys):
            self._complete = True
            return False
        self._levels.append(nxt)
        return True

    def __iter__(self):
        index = 0
        while index < len(self._levels) or self._grow():
            yield self._levels[index]
            index += 1

    def __getitem__(self, index):
        if index < 0:
            while self._grow():
                pass
        while index >= len(self._levels) and self._grow():
            pass
        return self._levels[index]

    def __len__(self):
        while self._grow():
            pass
        return len(self._levels)


def voxel_classes(probability: npt.ArrayLike, free_threshold: float, occupied_threshold: float) -> npt.NDArray[np.int8]:
    """(N,) int8 index into :data:`CLASSES` of each probability by the map's thresholds."""
    p = np.asarray(probability)
    out = np.ones(p.shape, dtype=np.int8)
    out[p < free_threshold] = 0
    out[p >= occupied_threshold] = 2
    return out


def select(
    levels: Iterable[VoxelLevel],
    *,
    threshold: float = 0.0,
    classes: Iterable[str] = ("occupied",),
    z_range_m: tuple[float, float] = (-np.inf, np.inf),
    free_threshold: float = 0.5,
    occupied_threshold: float = 0.5,
    budget: int = 2_000_000,
) -> tuple[VoxelLevel, npt.NDArray[np.bool_]]:
    """The voxels a viewer shows: P >= ``threshold``, class in ``classes``, centre height within
    ``z_range_m``, at the finest level of ``levels`` that shows at most ``budget`` of them.

    Returns
    -------
    level : VoxelLevel
    mask : (N,) bool over ``level``'s voxels
    """
    unknown = [c for c in classes if c not in CLASSES]
    if unknown:
        raise PrismapInputError(f"`classes` must be among {CLASSES}; got {unknown}")
    wanted = np.array([c in classes for c in CLASSES])
    for level in levels:
        z = key_to_center(level.keys[:, 2], level.size_m)
        mask = (level.probability >= threshold) & (z >= z_range_m[0]) & (z <= z_range_m[1])
        mask &= wanted[voxel_classes(level.probability, free_threshold, occupied_threshold)]
        if np.count_nonzero(mask) <= budget:
            break
    return level, mask


def unobserved_cells(base: VoxelLevel, *, budget: int = 2_000_000) -> VoxelLevel:
    """Cells inside the box of ``base``'s voxels that hold none of them, at the finest ``2**k`` coarsening
    whose box has at most ``budget`` cells (unobserved space is dense: it is drawn coarse).

    Parameters
    ----------
    base : VoxelLevel
        Level 0 of :func:`voxel_pyramid`.

    Returns
    -------
    VoxelLevel
        Probability NaN (no measurement); no voxels when ``base`` has none.
    """
    if len(base.keys) == 0:
        return base
    k = 0
    while True:
        keys = base.keys >> k
        lo, hi = keys.min(axis=0), keys.max(axis=0) + 1
        if np.prod(hi - lo) <= budget:
            break
        k += 1
    seen = np.zeros(tuple(hi - lo), dtype=bool)
    seen[tuple((keys - lo).T)] = True
    empty = np.argwhere(~seen) + lo
    return VoxelLevel(base.level + k, base.size_m * 2**k, empty, np.full(len(empty), np.nan, dtype=np.float32))


AGREEMENT = (
    "undecided or not in the truth",
    "correct free",
    "correct occupied",
    "free called occupied",
    "occupied called free (danger)",
)
"""A map voxel's agreement with the ground truth, by code (the index): the higher the code, the more a coarse
voxel of the pyramid shows it (a danger voxel is never hidden by coarsening)."""

AGREEMENT_COLORS = np.array(
    [(150, 150, 150), (85, 172, 238), (120, 177, 89), (244, 144, 12), (221, 46, 68)], dtype=np.uint8
)
"""RGB of each :data:`AGREEMENT` code: grey, blue, green, orange, red."""


def agreement_codes(
    keys: npt.ArrayLike,
    probability: npt.ArrayLike,
    truth: GroundTruthOccupancy,
    *,
    free_threshold: float = 0.5,
    occupied_threshold: float = 0.5,
) -> npt.NDArray[np.int8]:
    """(N,) int8 :data:`AGREEMENT` code of each map voxel against ``truth``.

    Parameters
    ----------
    keys : (N, 3) int, voxel keys of the map
    probability : (N,) float, P(occupied) of each
    truth : GroundTruthOccupancy
        On the map's grid (same voxel size); only its observed voxels are judged.
    free_threshold, occupied_threshold : float
        The map's thresholds (:func:`voxel_classes`): a voxel between them is undecided.
    """
    from prismap.grid import pack_keys

    packed = pack_keys(np.asarray(keys, dtype=np.int64))
    observed = np.isin(packed, pack_keys(truth.observed_keys))
    occupied = np.isin(packed, pack_keys(truth.occupied_keys))
    state = voxel_classes(probability, free_threshold, occupied_threshold)
    code = np.zeros(len(packed), dtype=np.int8)
    code[observed & ~occupied & (state == 0)] = 1
    code[observed & occupied & (state == 2)] = 2
    code[observed & ~occupied & (state == 2)] = 3
    code[observed & occupied & (state == 0)] = 4
    return code


def select_codes(
    levels: Iterable[VoxelLevel],
    *,
    shown: Iterable[int],
    z_range_m: tuple[float, float] = (-np.inf, np.inf),
    budget: int = 2_000_000,
) -> tuple[VoxelLevel, npt.NDArray[np.bool_]]:
    """The voxels of a code pyramid (``probability`` holding :data:`AGREEMENT` codes) whose code is in
    ``shown`` (codes) and whose centre height is within ``z_range_m``, at the finest level within ``budget``.

    Returns
    -------
    level : VoxelLevel
    mask : (N,) bool over ``level``'s voxels
    """
    wanted = np.zeros(len(AGREEMENT), dtype=bool)
    wanted[list(shown)] = True
    for level in levels:
        z = (level.keys[:, 2] + 0.5) * level.size_m
        mask = wanted[level.probability.astype(np.intp)] & (z >= z_range_m[0]) & (z <= z_range_m[1])
        if np.count_nonzero(mask) <= budget:
            break
    return level, mask
