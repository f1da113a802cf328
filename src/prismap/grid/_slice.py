"""A horizontal slice of an :class:`~prismap.grid.OccupancyMap` as an image (``OccupancyMap.slice_image``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array
from prismap.errors import PrismapInputError
from prismap.grid._keys import point_to_key

if TYPE_CHECKING:  # the map's module imports this one
    from prismap.grid._map import OccupancyMap


def horizontal_slice(
    grid: OccupancyMap, layer: int | None, z_range_m: tuple[float, float] | None
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The image and extent of :meth:`~prismap.grid.OccupancyMap.slice_image` (which documents them)."""
    if (layer is None) == (z_range_m is None):
        if grid.ndim == 2 and layer is None and z_range_m is None:
            layer = 0
        else:
            raise PrismapInputError("give exactly one of `layer` or `z_range_m`")
    if layer is not None:
        if int(layer) != layer:
            raise PrismapInputError(f"`layer` must be an integer z key; got {layer!r}")
        z_lo = z_hi = int(layer)
    else:
        z_min, z_max = as_float_array(z_range_m, "z_range_m", shape=(2,), allow_nan=False)
        if not z_max > z_min:
            raise PrismapInputError(f"`z_range_m` must be (z_min, z_max) with z_max > z_min; got {tuple(z_range_m)}")
        z_lo = int(point_to_key([z_min], grid.voxel_size_m)[0])
        z_hi = int(np.ceil(z_max / grid.voxel_size_m)) - 1
    keys, log, count = grid.known_voxels()
    inside = (keys[:, 2] >= z_lo) & (keys[:, 2] <= z_hi)
    keys, prob = keys[inside], grid._read(log[inside], count[inside])
    if keys.shape[0] == 0:
        return np.full((0, 0), np.nan), np.zeros(4)
    x0, y0 = keys[:, 0].min(), keys[:, 1].min()
    width, height = keys[:, 0].max() - x0 + 1, keys[:, 1].max() - y0 + 1
    image = np.full((height, width), -np.inf)
    np.maximum.at(image, (keys[:, 1] - y0, keys[:, 0] - x0), prob)
    image[np.isneginf(image)] = np.nan
    v = grid.voxel_size_m
    return image, np.array([x0 * v, (x0 + width) * v, y0 * v, (y0 + height) * v])
