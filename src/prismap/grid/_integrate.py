"""One frame into the map: rays -> (voxel key, increment) pairs -> one update per voxel by the policy.

The grid never knows which sensor model it runs: it hands the model flat arrays (per ray the measured
disparity and ``|r|``, per cell the ray index and the cell's depth interval on that ray) and gets back
per-cell log-odds increments, which a numba accumulator combines per voxel (SENSOR_MODELS.md section 3).
"""

import numpy as np

from prismap.errors import PrismapInputError
from prismap.grid import _kernels
from prismap.grid._storage import BlockTable

RAYS_PER_CHUNK = 4096
"""Rays cast per model call in ray mode: bounds the memory of one chunk's cell arrays."""

VOXELS_PER_SLAB = 1 << 21
"""Candidate voxels per projection call in projective mode."""

NOISE_BIN_RATIO = 1.25
"""Rays whose pose-induced disparity noise falls in one geometric bin share one widened model."""

MIN_NOISE_PX = 0.01
"""Pose-induced disparity noise below this (pixels) leaves the model unchanged."""


def new_accumulator(bits):
    """A frame accumulator: per touched voxel ``(sum, count, max, min)`` of its increments, float32."""
    return BlockTable(bits, {"acc": ((1 << sum(bits), 4), np.float32)})


def noise_groups(model, extra_noise_px):
    """Split rays by pose-induced noise: list of ``(model, ray indices)``.

    Rays below :data:`MIN_NOISE_PX` use ``model`` itself; the others are binned geometrically
    (ratio :data:`NOISE_BIN_RATIO`) and each bin uses ``model.with_extra_noise(bin value)``.
    """
    if extra_noise_px is None:
        return [(model, None)]
    sigma = np.asarray(extra_noise_px, dtype=np.float64)
    small = ~(sigma >= MIN_NOISE_PX)
    groups = [(model, np.flatnonzero(small))] if small.any() else []
    bins = np.round(np.log(np.where(small, MIN_NOISE_PX, sigma) / MIN_NOISE_PX) / np.log(NOISE_BIN_RATIO)).astype(np.int64)
    for b in np.unique(bins[~small]):
        members = np.flatnonzero(~small & (bins == b))
        groups.append((model.with_extra_noise(MIN_NOISE_PX * NOISE_BIN_RATIO**b), members))
    return groups


def stop_depths(model, disparity, ray_norm, ranges):
    """Depth at which each ray stops and whether that stop excludes its voxel (cut by max range).

    ``ranges = (max_range_m, reach_m)``: a ray is cut at ``max_range_m`` (distance along it); one that
    would still run further than ``reach_m`` (the edge of the key space) is an error.
    """
    max_range_m, reach_m = ranges
    influence = np.asarray(model.influence_depth(disparity, ray_norm), dtype=np.float64)
    if influence.shape != disparity.shape:
        raise PrismapInputError(
            f"sensor model {model.name!r}: influence_depth returned shape {influence.shape}; expected {disparity.shape}"
        )
    range_depth = max_range_m / ray_norm
    exclusive = range_depth < influence
    t_stop = np.where(exclusive, range_depth, influence)
    too_far = ~(t_stop * ray_norm <= reach_m) & ~(t_stop <= 0)
    if too_far.any():
        raise PrismapInputError(
            f"rays would run beyond the map's key range ({reach_m:.4g} m from the origin; influence depths up to "
            f"{np.nanmax(influence):.4g} m): pass a finite `max_range_m`"
        )
    return t_stop, exclusive


def accumulate_cells(accumulator, keys, increment):
    """Add (key, increment) pairs to the accumulator, growing it whenever the kernel runs out of room."""
    start = 0
    while start < keys.shape[0]:
        table = accumulator
        start = _kernels.accumulate(
            table.table_keys, table.table_slots, table.block_keys, table.n_blocks, table.payload["acc"],
            keys, increment, start, table.bits,
        )
        if start < keys.shape[0]:
            accumulator.reserve(max(64, len(accumulator)))


def cell_increments(model, disparity, ray_norm, ray_of_cell, t_in, t_out):
    """The model's log-odds increments of the cells, checked for shape."""
    _, increment = model.cell_posteriors(disparity, ray_norm, ray_of_cell, t_in, t_out)
    increment = np.asarray(increment, dtype=np.float64)
    if increment.shape != t_in.shape:
        raise PrismapInputError(
            f"sensor model {model.name!r}: cell_posteriors returned {increment.shape} increments for {t_in.shape} cells"
        )
    return increment


def ray_mode(accumulator, origin, rays, disparity, ray_norm, groups, ranges, voxel_size):
    """Cast every ray (Amanatides-Woo) and accumulate the model's increments of the voxels it crosses."""
    for model, members in groups:
        idx = np.arange(disparity.size) if members is None else members
        for begin in range(0, idx.size, RAYS_PER_CHUNK):
            chunk = idx[begin : begin + RAYS_PER_CHUNK]
            d, norm, r = disparity[chunk], ray_norm[chunk], np.ascontiguousarray(rays[chunk])
            t_stop, exclusive = stop_depths(model, d, norm, ranges)
            ray_of_cell, keys, t_in, t_out = _kernels.cast_rays(origin, r, t_stop, exclusive, voxel_size)
            if keys.shape[0]:
                accumulate_cells(accumulator, keys, cell_increments(model, d, norm, ray_of_cell, t_in, t_out))


def projective_mode(accumulator, origin, rays, disparity, ray_norm, groups, ranges, voxel_size, projection):
    """Visit the voxels of the frustum, give each the ray of the pixel its centre projects to, one update each.

    ``projection`` holds ``R_cam_world (3, 3)``, ``focal``, ``cx``, ``cy``, ``subsample`` and
    ``ray_index`` ((rows, cols) int64 ray of each subsampled pixel, -1 = none).
    """
    n = disparity.size
    t_stop = np.empty(n)
    exclusive = np.empty(n, dtype=np.bool_)
    group_of_ray = np.zeros(n, dtype=np.int64)
    for g, (model, members) in enumerate(groups):
        idx = np.arange(n) if members is None else members
        t_stop[idx], exclusive[idx] = stop_depths(model, disparity[idx], ray_norm[idx], ranges)
        group_of_ray[idx] = g
    valid = t_stop > 0
    if not valid.any():
        return
    far = (rays[valid] * t_stop[valid, None]).reshape(-1, 3)
    lo = np.floor(np.minimum(origin, (origin + far).min(axis=0)) / voxel_size).astype(np.int64) - 1
    hi = np.floor(np.maximum(origin, (origin + far).max(axis=0)) / voxel_size).astype(np.int64) + 1
    shape = hi - lo + 1
    x_per_slab = max(1, VOXELS_PER_SLAB // int(shape[1] * shape[2]))
    for x0 in range(0, int(shape[0]), x_per_slab):
        slab_shape = np.array([min(x_per_slab, shape[0] - x0), shape[1], shape[2]], dtype=np.int64)
        ray_of_cell, keys, t_in, t_out = _kernels.project_voxels(
            lo + np.array([x0, 0, 0]), slab_shape, origin, projection["R_cam_world"], projection["focal"],
            projection["cx"], projection["cy"], projection["subsample"], projection["ray_index"], rays,
            t_stop, exclusive, voxel_size,
        )
        cell_group = group_of_ray[ray_of_cell]
        for g, (model, _) in enumerate(groups):
            mine = cell_group == g if len(groups) > 1 else slice(None)
            k = keys[mine]
            if k.shape[0]:
                inc = cell_increments(model, disparity, ray_norm, ray_of_cell[mine], t_in[mine], t_out[mine])
                accumulate_cells(accumulator, np.ascontiguousarray(k), inc)
