"""Voxel keys: pure conversions between world points and integer voxel indices (DESIGN.md conventions).

The key of a world point is ``floor(p / voxel_size)`` on each axis and a voxel's centre is
``(key + 0.5) * voxel_size``, as OctoMap's ``coordToKey`` / ``keyToCoord`` without its offset. These
functions know nothing of storage; the map checks that keys stay inside :data:`KEY_LIMIT`.
"""

import numpy as np

from prismap._validate import as_float_array, check_positive
from prismap.errors import PrismapInputError

KEY_LIMIT = 1 << 23
"""Keys must satisfy ``-KEY_LIMIT <= key < KEY_LIMIT`` on every axis (8.4 M voxels each way: 84 km at 1 cm)."""


def point_to_key(points_w, voxel_size_m):
    """Integer key of the voxel containing each point.

    Parameters
    ----------
    points_w : (..., D) float, metres, world frame
        Points with D = 2 or 3 coordinates; must be finite.
    voxel_size_m : float, metres, > 0

    Returns
    -------
    keys : (..., D) int64
        ``floor(points_w / voxel_size_m)``.
    """
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    points = as_float_array(points_w, "points_w", allow_nan=False)
    return np.floor(points / voxel).astype(np.int64)


def key_to_center(keys, voxel_size_m):
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


def check_keys(keys, name="keys"):
    """Return ``keys`` as a contiguous (N, 3) int32 array inside :data:`KEY_LIMIT`, or raise naming ``name``."""
    array = np.asarray(keys)
    if not np.issubdtype(array.dtype, np.integer) or array.ndim != 2 or array.shape[1] != 3:
        raise PrismapInputError(f"`{name}` must be an (N, 3) integer array; got shape {array.shape}, dtype {array.dtype}")
    if array.size and (array.min() < -KEY_LIMIT or array.max() >= KEY_LIMIT):
        raise PrismapInputError(
            f"`{name}` must lie in [-{KEY_LIMIT}, {KEY_LIMIT}); got values in [{array.min()}, {array.max()}]"
        )
    return np.ascontiguousarray(array, dtype=np.int32)
