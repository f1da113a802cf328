"""Argument bundles of the grid's kernels: the map's storage, the frame accumulator's arrays, and what the
projective walk over a frame's key box needs of the voxels, the camera and the frame's rays. Each is built in one
place (the map's and the accumulator's by :meth:`prismap.grid._storage.BlockTable.arrays`, the walk's by the
projective integrator) and passed down unchanged; numba compiles a ``NamedTuple`` of scalars and arrays like
separate arguments.
"""

from typing import NamedTuple

import numpy as np


class MapStore(NamedTuple):
    """The map's storage (``OccupancyMap``'s block table), which the accumulation kernels read and change in place.

    Attributes
    ----------
    table : (T,) int32
        Open-addressing hash table of block slots, -1 = empty (``_kernels_hash``).
    block_keys : (B,) int64
        Packed key of the block in each slot.
    n_blocks : (1,) int64
        Blocks in use; the kernels add blocks up to the room the caller reserved.
    log : (B, V) int64, units of ``_logodds.LOG_ODDS_STEP``
        Fixed-point log-odds of each voxel of each block.
    count : (B, V) uint16
        Observations of each voxel of each block, saturating at 65535.
    bits : tuple of 3 int
        Key bits per axis inside a block (``V = 2**sum(bits)`` voxels, :mod:`prismap.grid._keys`).
    """

    table: np.ndarray
    block_keys: np.ndarray
    n_blocks: np.ndarray
    log: np.ndarray
    count: np.ndarray
    bits: tuple


class AccumulatorArrays(NamedTuple):
    """The frame accumulator's arrays (``_accumulator.new_accumulator``), which the kernels fill in place.

    Attributes
    ----------
    table, block_keys, n_blocks, bits
        The accumulator's block table, as :class:`MapStore`'s (the same types and meaning).
    acc : (B, V, 4) float32, log-odds
        Per voxel of each block: ``(sum, count, max, min)`` of the frame's increments.
    links : (B, 6) int32
        Slots of each block's six face neighbours (order of ``_kernels_accumulate.face``), -1 = not yet known.
    """

    table: np.ndarray
    block_keys: np.ndarray
    n_blocks: np.ndarray
    acc: np.ndarray
    links: np.ndarray
    bits: tuple


class Projection(NamedTuple):
    """One frame's projective walk (``_kernels_project.project_part``).

    Attributes
    ----------
    key_min : (3,) int64, voxel keys
        The key box's first key on each world axis (``_kernels_project.frustum_box``).
    shape : (3,) int64, voxels
        The key box's size on each world axis.
    origin : (3,) float64, metres, world frame
        The camera centre, where every ray starts.
    R_cam_world : (3, 3) float64
        Rotation world -> camera (OpenCV axes).
    focal : float, pixels
        Focal length of the full-resolution image.
    cx, cy : float, pixels
        Principal point of the full-resolution image.
    subsample : float, pixels
        Pixel step of the rays: ``ray_index`` is the image subsampled by it.
    ray_index : (rows, cols) int32
        The ray of each subsampled pixel, -1 = none.
    rays : (R, 3) float64, world frame
        Each ray's direction, scaled to unit depth (``t`` along it is depth in metres).
    exclusive : (R,) bool
        True: the ray is cut at max range and keeps only voxels that end at or before its stop depth; False: it
        also keeps the voxel that holds its stop depth (``_kernels_traverse.cast_rays``'s rule).
    stops : (rows, cols) float64, metres of depth
        Each subsampled pixel's stop depth, -inf = no ray (``_kernels_project.stop_image``).
    tile_stop : (rows / TILE, cols / TILE) float64, metres of depth
        The farthest stop depth of each image tile (``_kernels_project.tile_stops``).
    voxel_size : float, metres
        Voxel edge.
    """

    key_min: np.ndarray
    shape: np.ndarray
    origin: np.ndarray
    R_cam_world: np.ndarray
    focal: float
    cx: float
    cy: float
    subsample: float
    ray_index: np.ndarray
    rays: np.ndarray
    exclusive: np.ndarray
    stops: np.ndarray
    tile_stop: np.ndarray
    voxel_size: float
