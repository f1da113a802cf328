"""One frame into the map: rays -> (voxel key, increment) pairs -> one update per voxel by the policy.

The grid never knows which sensor model it runs: it hands the model flat arrays (per ray the measured
disparity and ``|r|``, per cell the ray index and the cell's depth interval on that ray) and gets back
per-cell log-odds increments, which a numba accumulator combines per voxel (SENSOR_MODELS.md section 3).
The one exception: a model that states hit/miss increments (``hit_miss_increments``) is applied while
casting, without cell arrays.
"""

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from prismap.errors import PrismapInputError
from prismap.grid import _kernels
from prismap.grid._storage import BlockTable

RAYS_PER_CHUNK = 4096
"""Rays cast per model call in ray mode: bounds the memory of one chunk's cell arrays."""

NOISE_BIN_RATIO = 1.25
"""Rays whose pose-induced disparity noise falls in one geometric bin share one widened model."""

MIN_NOISE_PX = 0.01
"""Pose-induced disparity noise below this (pixels) leaves the model unchanged."""


def new_accumulator(bits):
    """A frame accumulator: per touched voxel ``(sum, count, max, min)`` of its increments, float32, and per
    block the slots of its six face neighbours (``links``, see ``_kernels.cast_hit_miss``)."""
    return BlockTable(bits, {"acc": ((1 << sum(bits), 4), np.float32), "links": ((6,), np.int32)})


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


def register_cells(accumulator, keys):
    """(C,) int64 accumulator row of each voxel key, adding blocks and growing the accumulator as needed."""
    rows = np.empty(keys.shape[0], dtype=np.int64)
    start = 0
    while True:
        table = accumulator
        start = _kernels.register_keys(table.table, table.block_keys, table.n_blocks, table.payload["acc"],
                                       table.payload["links"], keys, start, table.bits, rows)
        if start == keys.shape[0]:
            return rows
        accumulator.reserve(max(64, len(accumulator)))


def cast_into(accumulator, origin, rays, t_stop, exclusive, voxel_size, *, grow=True):
    """Cast rays, registering the voxels they cross in the accumulator.

    Returns ``[ray_of_cell, cell_index (accumulator rows), t_in, t_out]`` as
    :func:`_kernels.cast_rays_into`, and how many rays are done. With ``grow=False`` it never reallocates
    the accumulator (safe beside a :func:`scatter` into it in another thread) and may stop short; call
    :func:`finish_cast` afterwards.
    """
    table = accumulator
    *cells, done = _kernels.cast_rays_into(table.table, table.block_keys, table.n_blocks, table.payload["acc"],
                                           table.payload["links"], origin, rays, t_stop, exclusive, voxel_size,
                                           table.bits)
    if grow:
        return finish_cast(accumulator, origin, rays, t_stop, exclusive, voxel_size, (cells, done))
    return cells, done


def finish_cast(accumulator, origin, rays, t_stop, exclusive, voxel_size, partial):
    """Complete a :func:`cast_into` that stopped short, growing the accumulator; returns the cells."""
    cells, done = partial
    parts = [cells]
    while done < rays.shape[0]:
        accumulator.reserve(max(64, len(accumulator)))
        more, n = cast_into(accumulator, origin, rays[done:], t_stop[done:], exclusive[done:], voxel_size, grow=False)
        more[0] += done
        parts.append(more)
        done += n
    if len(parts) == 1:
        return cells
    return [np.concatenate(column) for column in zip(*parts)]


def scatter(accumulator, cell_index, increment):
    """Add the cells' increments to their accumulator rows."""
    acc = accumulator.payload["acc"]
    _kernels.scatter(acc.reshape(-1, acc.shape[2]), cell_index, increment)


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
    """Cast every ray (Amanatides-Woo) and accumulate the model's increments of the voxels it crosses.

    Hit/miss models go through :func:`cast_hit_miss`. For the others, rays go in chunks of
    :data:`RAYS_PER_CHUNK` through a two-stage pipeline: this thread casts chunk k + 1 (the kernel
    releases the GIL) while a worker thread runs the model on chunk k and adds its increments. The cast
    beside the scatter never grows the accumulator (it is grown once the scatter is done), and it only
    creates blocks and fills their rows while the scatter writes rows of blocks created before, so the two never touch the same memory.
    """
    if all(model.hit_miss_increments() is not None for model, _ in groups):
        for model, members in groups:
            idx = np.arange(disparity.size) if members is None else members
            cast_hit_miss(accumulator, origin, np.ascontiguousarray(rays[idx]), disparity[idx], ray_norm[idx], model,
                          ranges, voxel_size)
        return
    chunks = []
    for model, members in groups:
        idx = np.arange(disparity.size) if members is None else members
        t_stop, exclusive = stop_depths(model, disparity[idx], ray_norm[idx], ranges)
        for begin in range(0, idx.size, RAYS_PER_CHUNK):
            part = slice(begin, begin + RAYS_PER_CHUNK)
            chunk = idx[part]
            chunks.append((model, disparity[chunk], ray_norm[chunk], np.ascontiguousarray(rays[chunk]),
                           np.ascontiguousarray(t_stop[part]), np.ascontiguousarray(exclusive[part])))
    if not chunks:
        return
    with ThreadPoolExecutor(max_workers=1) as worker:
        cells = cast_into(accumulator, origin, *chunks[0][3:], voxel_size)
        for k, (model, d, norm, *_) in enumerate(chunks):
            job = worker.submit(_model_and_scatter, accumulator, model, d, norm, cells)
            if k + 1 < len(chunks):
                # This thread enters the GIL-free cast at once; the worker's model call may hold the GIL.
                partial = cast_into(accumulator, origin, *chunks[k + 1][3:], voxel_size, grow=False)
            job.result()
            if k + 1 < len(chunks):
                cells = finish_cast(accumulator, origin, *chunks[k + 1][3:], voxel_size, partial)


def cast_hit_miss(accumulator, origin, rays, disparity, ray_norm, model, ranges, voxel_size):
    """Ray mode for a model with :meth:`~InverseSensorModel.hit_miss_increments`: the increments are added
    while casting, one kernel call per accumulator size (it stops when the accumulator needs to grow)."""
    l_hit, l_miss = model.hit_miss_increments()
    t_stop, exclusive = stop_depths(model, disparity, ray_norm, ranges)
    z_hit = np.where(exclusive, np.inf, t_stop)  # a ray cut at max range ends in misses
    done = 0
    while done < rays.shape[0]:
        table = accumulator
        n, blocks = _kernels.cast_hit_miss(table.table, table.block_keys, table.n_blocks, table.payload["acc"],
                                           table.payload["links"], origin,
                                           rays[done:], t_stop[done:], exclusive[done:], z_hit[done:], l_hit, l_miss,
                                           voxel_size, table.bits)
        done += n
        if done < rays.shape[0]:
            accumulator.reserve(max(64, len(accumulator), blocks))


def _model_and_scatter(accumulator, model, disparity, ray_norm, cells):
    ray_of_cell, cell_index, t_in, t_out = cells
    if cell_index.size:
        scatter(accumulator, cell_index, cell_increments(model, disparity, ray_norm, ray_of_cell, t_in, t_out))


def projective_mode(accumulator, origin, rays, disparity, ray_norm, groups, ranges, voxel_size, projection):
    """Visit the voxels of the frustum, give each the ray of the pixel its centre projects to, one update each.

    ``projection`` holds ``R_cam_world (3, 3)``, ``focal``, ``cx``, ``cy``, ``subsample`` and
    ``ray_index`` ((rows, cols) int32 ray of each subsampled pixel, -1 = none).
    """
    n = disparity.size
    t_stop = np.empty(n)
    exclusive = np.empty(n, dtype=np.bool_)
    group_of_ray = np.zeros(n, dtype=np.int64)
    for g, (model, members) in enumerate(groups):
        idx = slice(None) if members is None else members  # one group: views, no copies
        t_stop[idx], exclusive[idx] = stop_depths(model, disparity[idx], ray_norm[idx], ranges)
        group_of_ray[idx] = g
    key_min, shape, n_casting = _kernels.frustum_box(origin, rays, t_stop, voxel_size)
    if n_casting == 0:
        return
    capacity = min(int(np.prod(shape)), max(1 << 16, 2 * n))  # about one kept voxel per ray: rarely repeated
    while True:
        *cells, n_kept = _kernels.project_voxels(
            key_min, shape, origin, projection["R_cam_world"], projection["focal"], projection["cx"],
            projection["cy"], projection["subsample"], projection["ray_index"], rays, t_stop, exclusive, voxel_size,
            capacity,
        )
        if n_kept <= capacity:
            break
        capacity = n_kept
    ray_of_cell, keys, t_in, t_out = cells
    # Cells grouped by ray (models keep per-ray state from cell to cell); one model call per group and
    # frame, on the rays some voxel uses (models cost per ray too).
    rows = register_cells(accumulator, keys)  # in box order: runs of voxels in one block
    rows, t_in, t_out, used, local = _kernels.sort_by_ray(ray_of_cell, n, rows, t_in, t_out)
    if len(groups) == 1:  # no pose noise: the loop below with every used ray in the group, minus its copies
        scatter(accumulator, rows, cell_increments(groups[0][0], disparity[used], ray_norm[used], local, t_in, t_out))
        return
    group_of_used = group_of_ray[used]
    group_of_cell = group_of_used[local]
    for g, (model, _) in enumerate(groups):
        in_group = group_of_used == g
        mine = np.flatnonzero(group_of_cell == g)
        if in_group.any():
            rank = np.cumsum(in_group) - 1  # index of each used ray among the group's used rays
            rays_g = used[in_group]
            inc = cell_increments(model, disparity[rays_g], ray_norm[rays_g], rank[local[mine]], t_in[mine], t_out[mine])
            scatter(accumulator, rows[mine], inc)
