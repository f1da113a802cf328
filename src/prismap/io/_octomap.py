"""Export to OctoMap (``.ot`` full log-odds, ``.bt`` free/occupied) through the optional ``octomap`` module."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from prismap._files import atomic_path
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap, key_to_center

OCTOMAP_KEY_RANGE = 1 << 15
"""OctoMap's 16-bit keys: voxel keys must lie in [-2**15, 2**15)."""


def _octomap():
    try:
        import octomap
    except ImportError:
        raise PrismapInputError(
            "OctoMap export needs the optional `octomap` module: pip install -e '.[octomap]' (octomap-python)"
        ) from None
    return octomap


def to_octree(grid: OccupancyMap) -> Any:
    """An ``octomap.OcTree`` holding every known voxel of ``grid`` with its log-odds.

    The tree's clamping is widened to +-20 log-odds so the values arrive unchanged, and its occupancy
    threshold is the map's ``occupied_threshold``. Unknown voxels stay unknown (absent).
    """
    octomap = _octomap()
    if not isinstance(grid, OccupancyMap):
        raise PrismapInputError(f"`grid` must be an OccupancyMap; got {type(grid).__name__}")
    keys, log, _ = grid.known_voxels()
    if keys.size and (keys.min() < -OCTOMAP_KEY_RANGE or keys.max() >= OCTOMAP_KEY_RANGE):
        raise PrismapInputError(
            f"the map spans keys [{keys.min()}, {keys.max()}]; OctoMap holds [-{OCTOMAP_KEY_RANGE}, {OCTOMAP_KEY_RANGE})"
        )
    tree = octomap.OcTree(grid.voxel_size_m)
    tree.setClampingThresMin(1.0 / (1.0 + np.exp(20.0)))
    tree.setClampingThresMax(1.0 / (1.0 + np.exp(-20.0)))
    tree.setOccupancyThres(grid.occupied_threshold)
    centers = key_to_center(keys, grid.voxel_size_m)
    for center, value in zip(centers, log.astype(np.float64)):
        tree.updateNode(center, float(value), True)
    tree.updateInnerOccupancy()
    return tree


def write_octomap(grid: OccupancyMap, path: str | os.PathLike[str]) -> None:
    """Write ``grid`` as an OctoMap file, atomically: ``.ot`` (full log-odds) or ``.bt`` (free/occupied)."""
    path = Path(path)
    if path.suffix not in (".ot", ".bt"):
        raise PrismapInputError(f"{path}: OctoMap files end in .ot (full) or .bt (binary); got {path.suffix!r}")
    tree = to_octree(grid)
    with atomic_path(path) as tmp:
        ok = tree.write(str(tmp).encode()) if path.suffix == ".ot" else tree.writeBinary(str(tmp).encode())
        if not ok:
            raise PrismapInputError(f"{path}: OctoMap could not write the file")
