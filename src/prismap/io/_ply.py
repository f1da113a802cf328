"""Occupied voxels as a binary PLY point cloud (vertex x, y, z float32 and probability float32)."""

from __future__ import annotations

import os

import numpy as np
import numpy.typing as npt

from prismap._files import atomic_path
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap


def write_ply(grid: OccupancyMap, path: str | os.PathLike[str]) -> int:
    """Write the occupied voxels' centres (metres, world frame) and probabilities to a binary PLY.

    Parameters
    ----------
    grid : OccupancyMap
    path : str or Path
        Destination (``.ply``), written atomically.

    Returns
    -------
    int
        Number of vertices written.
    """
    if not isinstance(grid, OccupancyMap):
        raise PrismapInputError(f"`grid` must be an OccupancyMap; got {type(grid).__name__}")
    _, centers, prob = grid.occupied_voxels()
    vertices = np.empty(len(prob), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("probability", "<f4")])
    vertices["x"], vertices["y"], vertices["z"] = centers.T
    vertices["probability"] = prob
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment prismap occupied voxels, voxel size {grid.voxel_size_m} m\n"
        f"element vertex {len(prob)}\n"
        "property float x\nproperty float y\nproperty float z\nproperty float probability\nend_header\n"
    )
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(vertices.tobytes())
    return len(prob)


def read_ply(path: str | os.PathLike[str]) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Read a PLY written by :func:`write_ply`: ``(centers_w (N, 3) float32, probability (N,) float32)``."""
    data = open(path, "rb").read()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise PrismapInputError(f"{path}: not a PLY file")
    header = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise PrismapInputError(f"{path}: expected a binary little-endian PLY")
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    vertices = np.frombuffer(data, dtype="<f4", offset=end + len(b"end_header\n"))
    if vertices.size != 4 * count:
        raise PrismapInputError(f"{path}: expected {count} vertices of 4 floats; got {vertices.size} floats")
    vertices = vertices.reshape(count, 4)
    return vertices[:, :3], vertices[:, 3]
