"""Line a map's voxels up with a ground truth, by integer key, in 2-D or 3-D."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_probability
from prismap.errors import PrismapInputError
from prismap.grid import pack_key_sets


def align_to_ground_truth(
    keys: npt.ArrayLike,
    probability: npt.ArrayLike,
    occupied_keys: npt.ArrayLike,
    region_keys: npt.ArrayLike,
    *,
    p0: float,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Predicted ``P`` and true occupancy for every voxel of the evaluated region.

    Parameters
    ----------
    keys : (N, D) int
        Keys ``floor(p / voxel_size)`` of the voxels the map knows (D = 2 or 3).
    probability : (N,) float, in [0, 1]
        The map's ``P(occupied)`` of those voxels.
    occupied_keys : (M, D) int
        Keys of the truly occupied voxels. Those outside the region are not scored; repeats
        are harmless.
    region_keys : (K, D) int
        Keys of the evaluated voxels: those a perfect sensor on the same trajectory would have
        observed. Each key once.
    p0 : float, keyword-only, in (0, 1)
        Prior given to region voxels the map never observed ("unknown" scores as the prior).

    Returns
    -------
    probability : (K,) float64
        ``P`` of each region voxel, in the order of ``region_keys``.
    occupied : (K,) bool
        Whether each region voxel is truly occupied.

    Raises
    ------
    PrismapInputError
        Key arrays that are not integer (N, D) with the same D, lengths that differ, repeated keys
        in ``keys`` or ``region_keys``, ``P`` outside [0, 1], or keys too far apart to pack.

    Notes
    -----
    Keys are packed into one int64 per voxel by the grid's key module (``pack_key_sets``: offset by the
    smallest key on each axis, 21 bits per axis), then matched with ``np.searchsorted`` and ``np.isin``: O((N + M + K) log) and
    independent of the grid's storage.
    """
    aligned, occupied, _ = align_with_known(keys, probability, occupied_keys, region_keys, p0=p0)
    return aligned, occupied


def align_with_known(keys, probability, occupied_keys, region_keys, *, p0):
    """:func:`align_to_ground_truth` and, third, ``known`` ((K,) bool): whether the map holds each region voxel
    (the others took ``p0``)."""
    p0 = check_probability(p0, "p0")
    keys = _as_keys(keys, "keys")
    dims = keys.shape[1]
    occupied_keys = _as_keys(occupied_keys, "occupied_keys", dims)
    region_keys = _as_keys(region_keys, "region_keys", dims)
    p = as_float_array(probability, "probability", ndim=1, allow_nan=False)
    if p.shape[0] != keys.shape[0]:
        raise PrismapInputError(f"`probability` must have one value per key ({keys.shape[0]}); got {p.shape[0]}")
    if p.size and (p.min() < 0.0 or p.max() > 1.0):
        raise PrismapInputError(f"`probability` must lie in [0, 1]; got values in [{p.min()}, {p.max()}]")

    packed, packed_occupied, packed_region = pack_key_sets(keys, occupied_keys, region_keys)
    order = np.argsort(packed)
    sorted_keys = packed[order]
    _check_unique(sorted_keys, "keys")
    _check_unique(np.sort(packed_region), "region_keys")

    aligned = np.full(packed_region.size, p0)
    found = np.zeros(packed_region.size, dtype=bool)
    if packed.size:
        slot = np.minimum(np.searchsorted(sorted_keys, packed_region), packed.size - 1)
        found = sorted_keys[slot] == packed_region
        aligned[found] = p[order[slot[found]]]
    return aligned, np.isin(packed_region, packed_occupied), found


def _as_keys(value, name, dims=None):
    array = np.asarray(value)
    if array.ndim != 2 or (array.size and not np.issubdtype(array.dtype, np.integer)):
        raise PrismapInputError(
            f"`{name}` must be an (N, D) integer array; got shape {array.shape}, dtype {array.dtype}"
        )
    if dims is not None and array.shape[1] != dims:
        raise PrismapInputError(f"`{name}` must have {dims} columns like `keys`; got {array.shape[1]}")
    return array.astype(np.int64, copy=False)


def _check_unique(sorted_codes, name):
    repeats = int(np.count_nonzero(sorted_codes[1:] == sorted_codes[:-1]))
    if repeats:
        raise PrismapInputError(f"`{name}` must not repeat a key; got {repeats} repeats")
