"""Voxel keys, as OctoMap's ``OcTreeKey``: the key limit, the block/voxel split, packing, points <-> keys.

The key of a world point is ``floor(p / voxel_size)`` on each axis and a voxel's centre is
``(key + 0.5) * voxel_size`` (DESIGN.md conventions; OctoMap's ``coordToKey`` / ``keyToCoord`` without
its offset). The map stores voxels in blocks of ``2**bits`` voxels per axis (:data:`BLOCK_BITS`): voxel
key ``k`` lies in block ``k >> bits`` at local offset ``k & (2**bits - 1)``. A block coordinate triple is
packed into one int64 of :data:`AXIS_BITS` bits per axis (offset :data:`PACK_OFFSET`), so block
coordinates must lie in ``[-PACK_OFFSET, PACK_OFFSET)``; the voxel key limit follows from the block bits:
``KEY_LIMIT = PACK_OFFSET << min(block bits)``. Keys outside it are refused, never wrapped.

Everything here is pure arithmetic, apart from storage; numba versions of the packing are what the
grid's kernels inline, numpy versions are for whole arrays (ground-truth files, evaluation).
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_positive
from prismap.errors import PrismapInputError

AXIS_BITS = 21
"""Bits per axis of a packed coordinate triple (3 x 21 = 63 bits of an int64)."""

PACK_OFFSET = 1 << (AXIS_BITS - 1)
"""Packed coordinates lie in ``[-PACK_OFFSET, PACK_OFFSET)`` on every axis."""

_AXIS_MASK = (1 << AXIS_BITS) - 1

BLOCK_BITS = {3: (2, 2, 2), 2: (3, 3, 0)}
"""log2 block sizes: 4x4x4 voxels for 3-D maps, 8x8x1 for 2-D maps (small blocks: less unobserved space
stored; 4^3 blocks cost fewer bytes per known voxel than 8^3 on a 640x480 frame, at some more CPU)."""

KEY_LIMIT = PACK_OFFSET << min(BLOCK_BITS[3])
"""Voxel keys must satisfy ``-KEY_LIMIT <= key < KEY_LIMIT`` on every axis: 2**22 (419 km at 0.1 m voxels).
The 2-D blocks are at least as wide on x and y, and a 2-D map's z key is 0."""


MAX_VOXEL_SIZE_M = 1e6
"""Largest voxel edge (metres) a map takes: its key range then spans +-4.2e12 m, finite in float32 (PLY and
PointCloud2 coordinates) with room to spare."""


def check_voxel_size(voxel_size_m, name="voxel_size_m"):
    """``float(voxel_size_m)`` if it is a finite number in (0, :data:`MAX_VOXEL_SIZE_M`], else raise naming ``name``."""
    size = check_positive(voxel_size_m, name)
    if size > MAX_VOXEL_SIZE_M:
        raise PrismapInputError(
            f"`{name}` must be at most {MAX_VOXEL_SIZE_M:g} m (MAX_VOXEL_SIZE_M: voxel centres "
            f"must stay finite in float32); got {size:g}"
        )
    return size


def key_limit_m(voxel_size_m: float) -> float:
    """Distance from the world origin (metres, per axis) that the key range covers at this voxel size."""
    return KEY_LIMIT * float(voxel_size_m)


def key_range_text(voxel_size_m: float) -> str:
    """``[-L, L)`` keys as text with the limit in metres, for error messages."""
    return f"[-{KEY_LIMIT}, {KEY_LIMIT}) (+-{key_limit_m(voxel_size_m):.6g} m at {voxel_size_m:g} m voxels)"


@numba.njit(cache=True, nogil=True, inline="always")
def pack_block(bx, by, bz):
    """Packed int64 of a block coordinate triple (each in ``[-PACK_OFFSET, PACK_OFFSET)``)."""
    return (
        ((np.int64(bx) + PACK_OFFSET) << (2 * AXIS_BITS))
        | ((np.int64(by) + PACK_OFFSET) << AXIS_BITS)
        | (np.int64(bz) + PACK_OFFSET)
    )


@numba.njit(cache=True, nogil=True, inline="always")
def split_key(kx, ky, kz, bits):
    """(packed block key, local voxel index ``x | y << bx | z << (bx + by)``) of one voxel key."""
    bx, by, bz = bits
    local = (kx & ((1 << bx) - 1)) | ((ky & ((1 << by) - 1)) << bx) | ((kz & ((1 << bz) - 1)) << (bx + by))
    return pack_block(kx >> bx, ky >> by, kz >> bz), local


PACKED_STEPS = (1 << (2 * AXIS_BITS), 1 << AXIS_BITS, 1)
"""Difference of two packed keys one apart on x, y, z (the accumulator's face links use it)."""


def pack_keys(coords: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """One int64 per (x, y, z) coordinate triple, ordered like the triples lexicographically.

    Parameters
    ----------
    coords : (N, 3) int, each in ``[-PACK_OFFSET, PACK_OFFSET)`` (block coordinates, or voxel keys
        within that range as in ground-truth files)

    Returns
    -------
    packed : (N,) int64, the packing :func:`pack_block` computes
    """
    k = np.asarray(coords, dtype=np.int64)
    if k.size and (k.min() < -PACK_OFFSET or k.max() >= PACK_OFFSET):
        raise PrismapInputError(f"keys must lie in [-{PACK_OFFSET}, {PACK_OFFSET}) to pack; got [{k.min()}, {k.max()}]")
    k = k + PACK_OFFSET
    return (k[:, 0] << (2 * AXIS_BITS)) | (k[:, 1] << AXIS_BITS) | k[:, 2]


def pack_key_sets(*key_arrays: npt.ArrayLike) -> tuple[npt.NDArray[np.int64], ...]:
    """One int64 per key of several (N_i, D) key arrays (D <= 3), equal codes for equal keys across them.

    Keys are taken relative to the smallest key of all arrays on each axis, so they may lie anywhere as
    long as each axis spans fewer than ``2**AXIS_BITS`` keys; the codes keep the lexicographic order.
    """
    stacked = np.concatenate([np.asarray(a, dtype=np.int64) for a in key_arrays], axis=0)
    if stacked.shape[0] == 0:
        return tuple(np.zeros(0, np.int64) for _ in key_arrays)
    dims = stacked.shape[1]
    low = stacked.min(axis=0)
    span = [int(hi) - int(lo) + 1 for lo, hi in zip(low, stacked.max(axis=0))]  # Python ints: no overflow
    if dims > 3 or max(span) > 2 * PACK_OFFSET:
        raise PrismapInputError(
            f"keys span {span} voxels per axis: too far apart to pack into int64 "
            f"(at most 3 axes of {2 * PACK_OFFSET} keys)"
        )
    pad = np.full(3 - dims, -PACK_OFFSET, dtype=np.int64)
    return tuple(
        pack_keys(
            np.column_stack(
                [np.asarray(a, dtype=np.int64) - low - PACK_OFFSET, np.broadcast_to(pad, (len(a), 3 - dims))]
            )
        )
        for a in key_arrays
    )


def unpack_keys(packed: npt.ArrayLike) -> npt.NDArray[np.int64]:
    """(N, 3) int64 coordinates of packed keys: the inverse of :func:`pack_keys`."""
    shifts = np.array([2 * AXIS_BITS, AXIS_BITS, 0], dtype=np.int64)
    return ((np.asarray(packed, dtype=np.int64)[:, None] >> shifts) & _AXIS_MASK) - PACK_OFFSET


def block_voxel_keys(block_coords, bits):
    """(B, V, 3) int64 voxel keys of every voxel of each block (V = ``2**sum(bits)``, local index order)."""
    bx, by, bz = bits
    local = np.arange(1 << sum(bits), dtype=np.int64)
    offsets = np.stack(
        [local & ((1 << bx) - 1), (local >> bx) & ((1 << by) - 1), (local >> (bx + by)) & ((1 << bz) - 1)], axis=1
    )
    return (np.asarray(block_coords, dtype=np.int64)[:, None, :] << np.array(bits, dtype=np.int64)) + offsets[None]


def point_to_key(points_w: npt.ArrayLike, voxel_size_m: float) -> npt.NDArray[np.int64]:
    """Integer key of the voxel containing each point.

    Parameters
    ----------
    points_w : (..., D) float, metres, world frame
        Points with D = 2 or 3 coordinates; must be finite.
    voxel_size_m : float, metres, > 0

    Returns
    -------
    keys : (..., D) int64
        ``floor(points_w / voxel_size_m)``; the caller checks them against :data:`KEY_LIMIT`
        (:func:`check_keys`). Points beyond 2**62 voxels are refused here (they would overflow int64).
    """
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    points = as_float_array(points_w, "points_w", allow_nan=False)
    scaled = np.floor(points / voxel)
    if scaled.size and np.abs(scaled).max() >= 2.0**62:
        raise PrismapInputError(
            f"`points_w` must lie within the key range {key_range_text(voxel)}; got "
            f"coordinates up to {np.abs(points).max():.6g} m"
        )
    return scaled.astype(np.int64)


def key_to_center(keys: npt.ArrayLike, voxel_size_m: float) -> npt.NDArray[np.float64]:
    """World coordinates of the centre of each voxel key.

    Parameters
    ----------
    keys : (..., D) int
        Voxel keys.
    voxel_size_m : float, metres, > 0

    Returns
    -------
    centers_w : (..., D) float64, metres, world frame
        ``(keys + 0.5) * voxel_size_m``.
    """
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    array = np.asarray(keys)
    if not np.issubdtype(array.dtype, np.integer):
        raise PrismapInputError(f"`keys` must be an integer array; got dtype {array.dtype}")
    return (array.astype(np.float64) + 0.5) * voxel


def check_keys(keys, voxel_size_m, name="keys"):
    """Return ``keys`` as a contiguous (N, 3) int32 array inside :data:`KEY_LIMIT`, or raise naming ``name``
    and the limit in metres at ``voxel_size_m``."""
    array = np.asarray(keys)
    if not np.issubdtype(array.dtype, np.integer) or array.ndim != 2 or array.shape[1] != 3:
        raise PrismapInputError(
            f"`{name}` must be an (N, 3) integer array; got shape {array.shape}, dtype {array.dtype}"
        )
    if array.size and (array.min() < -KEY_LIMIT or array.max() >= KEY_LIMIT):
        raise PrismapInputError(
            f"`{name}` must lie in the key range {key_range_text(voxel_size_m)}; got values in [{array.min()}, {array.max()}]"
        )
    return np.ascontiguousarray(array, dtype=np.int32)
