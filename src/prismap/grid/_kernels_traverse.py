"""numba kernels of ray traversal (Amanatides & Woo): the voxels each ray crosses and their depth intervals.

Called only by the grid's wrappers, which check and convert first. The hot loops inline everything on
their common path (an out-of-line call with array arguments per block change costs more than the step itself). The fused
kernels register the crossed voxels in the frame accumulator as they go (``_kernels_accumulate``).
Every kernel releases the GIL (``nogil=True``) so that a caller may run them beside Python code.

References: J. Amanatides, A. Woo, "A fast voxel traversal algorithm for ray tracing", Eurographics 1987.
"""

import numba
import numpy as np

from prismap.grid._kernels_accumulate import face, link_block, register_run
from prismap.grid._kernels_hash import EMPTY
from prismap.grid._keys import split_key


@numba.njit(cache=True, nogil=True)
def cell_limits(origin, rays, t_start, t_stop, voxel_size):
    """Per ray, a bound on the voxels it visits from depth ``t_start`` to ``t_stop`` (0 when it casts nothing); the
    traversal's length guard."""
    limits = np.zeros(rays.shape[0], dtype=np.int64)
    for i in range(rays.shape[0]):
        if t_stop[i] > 0.0:
            limits[i] = span(origin, rays[i], t_start[i], t_stop[i], voxel_size, (0, 0, 0))
    return limits


@numba.njit(cache=True, nogil=True, inline="always")
def span(origin, ray, start, stop, voxel_size, bits):
    """A bound on the voxels (``bits = (0, 0, 0)``) or blocks a ray visits from depth ``start`` to ``stop``."""
    inv = 1.0 / voxel_size
    limit = 3
    for ax in range(3):
        first = np.int64(np.floor((origin[ax] + ray[ax] * start) * inv)) >> bits[ax]
        last = np.int64(np.floor((origin[ax] + ray[ax] * stop) * inv)) >> bits[ax]
        limit += abs(last - first)
    return limit


@numba.njit(cache=True, nogil=True, inline="always")
def _skip_to(start, k, t, d, s):
    """One axis's traversal state ``(key, depth of its next border)`` after crossing every border at or before depth
    ``start``, and the depth of the last border crossed (0 when none)."""
    if start <= 0.0 or not t <= start:
        return k, t, 0.0
    n = np.floor((start - t) / d) + 1.0
    return k + s * np.int64(n), t + n * d, t + (n - 1.0) * d


@numba.njit(cache=True, nogil=True, inline="always")
def _axis_setup(o, r, voxel_size):
    """Setup phase on one axis: (first key, key step, depth of the first border, depth per voxel)."""
    k = np.floor(o / voxel_size)
    if r > 0.0:
        return np.int64(k), 1, ((k + 1) * voxel_size - o) / r, voxel_size / r
    if r < 0.0:
        return np.int64(k), -1, (k * voxel_size - o) / r, -voxel_size / r
    return np.int64(k), 0, np.inf, np.inf


@numba.njit(cache=True, nogil=True)
def _walk(origin, ray, start, stop, exclusive, voxel_size, limit, keys, t_in_out, t_out_out, m):
    """Amanatides-Woo traversal of one ray, writing its voxels from row ``m`` on; returns the next free row.

    The rule of :func:`cast_rays`, from the voxel that holds depth ``start`` on (its borders before it crossed at
    once; only voxels ending past ``start`` are kept); ``limit`` (from :func:`cell_limits`) bounds the steps. The
    state is kept in scalars (one per axis) so that it stays in registers.

    Parameters
    ----------
    origin : (3,) float64, metres, world frame
        Where the ray starts.
    ray : (3,) float64, world frame
        Its direction, scaled to unit depth.
    start : float, metres of depth
        Where its cast starts (0: at the origin).
    stop : float, metres of depth
        Its stop depth.
    exclusive : bool
        Exclude the voxel that holds the stop point (else include it).
    voxel_size : float, metres
        Voxel edge.
    limit : int
        Most steps.
    keys : (M, 3) int32, t_in_out, t_out_out : (M,) float64, metres of depth
        Written from row ``m``: each kept voxel's key and depth interval.
    m : int
        First row to write.
    """
    kx, sx, tx, dx = _axis_setup(origin[0], ray[0], voxel_size)
    ky, sy, ty, dy = _axis_setup(origin[1], ray[1], voxel_size)
    kz, sz, tz, dz = _axis_setup(origin[2], ray[2], voxel_size)
    kx, tx, bx = _skip_to(start, kx, tx, dx, sx)
    ky, ty, by = _skip_to(start, ky, ty, dy, sy)
    kz, tz, bz = _skip_to(start, kz, tz, dz, sz)
    min_length = 1e-9 * voxel_size / np.sqrt(ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2])
    t_in = max(bx, max(by, bz))
    # Step phase; the loop bound is the length guard against floating-point drift.
    for _ in range(limit):
        t_out = min(tx, min(ty, tz))
        if _past_stop(t_in, t_out, stop, exclusive):
            break
        if t_out - t_in > min_length and t_out > start:
            m = write_cell(keys, t_in_out, t_out_out, m, kx, ky, kz, t_in, t_out)
        kx, ky, kz, tx, ty, tz = _step(kx, ky, kz, tx, ty, tz, sx, sy, sz, dx, dy, dz)
        t_in = t_out
    return m


@numba.njit(cache=True, nogil=True, inline="always")
def write_cell(keys, t_in_out, t_out_out, m, kx, ky, kz, t_in, t_out):
    """Write voxel ``(kx, ky, kz)`` and its depth interval as cell row ``m``; returns the next free row."""
    keys[m, 0] = kx
    keys[m, 1] = ky
    keys[m, 2] = kz
    t_in_out[m] = t_in
    t_out_out[m] = t_out
    return m + 1


@numba.njit(cache=True, nogil=True, inline="always")
def _past_stop(t_in, t_out, stop, exclusive):
    """Whether the voxel ``[t_in, t_out]`` lies past the ray's stop (the rule of :func:`cast_rays`)."""
    if exclusive:
        return t_out > stop
    return t_in > stop


@numba.njit(cache=True, nogil=True, inline="always")
def _step(kx, ky, kz, tx, ty, tz, sx, sy, sz, dx, dy, dz):
    """One traversal step along the axis of the nearest border (x first on ties, then y)."""
    if tx <= ty and tx <= tz:
        return kx + sx, ky, kz, tx + dx, ty, tz
    if ty <= tz:
        return kx, ky + sy, kz, tx, ty + dy, tz
    return kx, ky, kz + sz, tx, ty, tz + dz


@numba.njit(cache=True, nogil=True)
def cast_rays(origin, rays, t_stop, exclusive, voxel_size):
    """Voxels crossed by each ray and their depth intervals (Amanatides & Woo traversal).

    The point at depth ``t`` of ray ``i`` is ``origin + t * rays[i]``. A ray visits the voxels from its
    origin's voxel on; it keeps a voxel of interval ``[t_in, t_out]`` while ``t_in <= t_stop[i]``
    (the voxel containing the stop point is included), or, when ``exclusive[i]``, while
    ``t_out <= t_stop[i]`` (that voxel is excluded, as OctoMap excludes the end cell of a ray cut at
    its max range). Voxels the ray only touches (length below 1e-9 voxel) are skipped, so a camera on
    a voxel boundary does not update the voxel behind it. ``t_stop[i] <= 0`` or NaN casts nothing.

    Returns ``ray_of_cell (C,) int64, keys (C, 3) int32, t_in (C,) float64, t_out (C,) float64``.

    References: J. Amanatides, A. Woo, "A fast voxel traversal algorithm for ray tracing",
    Eurographics 1987.
    """
    t_start = np.zeros(rays.shape[0])
    limits = cell_limits(origin, rays, t_start, t_stop, voxel_size)
    total = limits.sum()
    ray_of_cell = np.empty(total, dtype=np.int64)
    keys = np.empty((total, 3), dtype=np.int32)
    t_in = np.empty(total, dtype=np.float64)
    t_out = np.empty(total, dtype=np.float64)
    m = 0
    for i in range(rays.shape[0]):
        if limits[i] > 0:
            end = _walk(origin, rays[i], 0.0, t_stop[i], exclusive[i], voxel_size, limits[i], keys, t_in, t_out, m)
            ray_of_cell[m:end] = i
            m = end
    return ray_of_cell[:m], keys[:m], t_in[:m], t_out[:m]


@numba.njit(cache=True, nogil=True)
def cast_rays_into(accumulator, origin, rays, t_start, t_stop, exclusive, voxel_size):
    """:func:`cast_rays` fused with ``register_run``: each crossed voxel's accumulator row, no keys. Parameters
    as :func:`cast_rays`'s, ``t_start`` ((R,) metres of depth) where each ray's cast starts (:func:`_walk`), and
    ``accumulator`` (:class:`~prismap.grid._kernel_args.AccumulatorArrays`, changed in place).

    Returns ``ray_of_cell (C,) int64, cell_index (C,) int64, t_in (C,), t_out (C,) float64`` and the
    number of rays done: fewer than ``len(rays)`` when a new block found the accumulator full (that
    ray's cells are left out; grow the accumulator and cast the remaining rays).
    """
    limits = cell_limits(origin, rays, t_start, t_stop, voxel_size)
    total = limits.sum()
    ray_of_cell = np.empty(total, dtype=np.int64)
    cell_index = np.empty(total, dtype=np.int64)
    t_in = np.empty(total, dtype=np.float64)
    t_out = np.empty(total, dtype=np.float64)
    scratch = np.empty((limits.max() if limits.size else 0, 3), dtype=np.int32)
    last_block, last_slot = EMPTY, np.int64(-1)
    m = 0
    for i in range(rays.shape[0]):
        if limits[i] == 0:
            continue
        n = _walk(
            origin, rays[i], t_start[i], t_stop[i], exclusive[i], voxel_size, limits[i], scratch, t_in[m:], t_out[m:], 0
        )
        done, last_block, last_slot = register_run(accumulator, scratch, 0, n, cell_index[m:], last_block, last_slot)
        if done < n:
            return ray_of_cell[:m], cell_index[:m], t_in[:m], t_out[:m], i
        ray_of_cell[m : m + n] = i
        m += n
    return ray_of_cell[:m], cell_index[:m], t_in[:m], t_out[:m], rays.shape[0]


@numba.njit(cache=True, nogil=True)
def cast_hit_miss(accumulator, origin, rays, t_stop, exclusive, z_hit, l_hit, l_miss, voxel_size):
    """Cast rays and add hit/miss increments straight into the accumulator (no per-cell arrays).

    Voxels as :func:`cast_rays` keeps them; one of interval ``[t_in, t_out)`` on ray ``i`` gets ``l_hit``
    if it holds ``z_hit[i]``, ``l_miss`` if it ends at or before it, 0 beyond (the rule of
    ``sensor_models._kernels.hitmiss_cells``), added as :func:`scatter` adds. Returns the number of rays
    done and the blocks the next ray may need: a ray starts only when the accumulator has room for every
    block it may cross, so when it stops short, grow the accumulator and cast the remaining rays.

    ``links[slot]`` caches the slots of a block's six face neighbours (order of :func:`face`; -1 = not
    yet known): a ray entering the next block reads it instead of hashing (:func:`link_block`).

    Parameters
    ----------
    accumulator : AccumulatorArrays
        The frame accumulator (:class:`~prismap.grid._kernel_args.AccumulatorArrays`), changed in place.
    origin, rays, t_stop, exclusive, voxel_size
        As :func:`cast_rays`'s.
    z_hit : (R,) float64, metres of depth
        Each ray's hit depth, inf = none (cut at max range).
    l_hit, l_miss : float, log-odds
        The model's increments.
    """
    n_blocks, acc, links, bits = accumulator.n_blocks, accumulator.acc, accumulator.links, accumulator.bits
    limits = cell_limits(origin, rays, np.zeros(rays.shape[0]), t_stop, voxel_size)
    capacity = min(accumulator.block_keys.size, accumulator.table.size // 2)
    hit = np.float32(l_hit)
    miss = np.float32(l_miss)
    zero = np.float32(0.0)
    last_block, last_slot = EMPTY, np.int64(-1)
    for i in range(rays.shape[0]):
        if limits[i] == 0:
            continue
        blocks = span(origin, rays[i], 0.0, t_stop[i], voxel_size, bits)
        if n_blocks[0] + blocks > capacity:
            return i, blocks
        ray = rays[i]
        stop = t_stop[i]
        excl = exclusive[i]
        z = z_hit[i]
        kx, sx, tx, dx = _axis_setup(origin[0], ray[0], voxel_size)
        ky, sy, ty, dy = _axis_setup(origin[1], ray[1], voxel_size)
        kz, sz, tz, dz = _axis_setup(origin[2], ray[2], voxel_size)
        min_length = 1e-9 * voxel_size / np.sqrt(ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2])
        t_in = 0.0
        for _ in range(limits[i]):
            t_out = min(tx, min(ty, tz))
            if _past_stop(t_in, t_out, stop, excl):
                break
            if t_out - t_in > min_length:
                block, local = split_key(kx, ky, kz, bits)
                if block != last_block:
                    side = face(block - last_block)
                    slot = np.int64(links[last_slot, side]) if side >= 0 else np.int64(-1)
                    if slot < 0:
                        slot = link_block(accumulator, block, side, last_slot, capacity)
                    last_block, last_slot = block, slot
                x = miss if t_out <= z else (hit if t_in <= z else zero)
                acc[last_slot, local, 0] += x
                acc[last_slot, local, 1] += 1.0
                if x > acc[last_slot, local, 2]:  # a comparison, as in _kernels_accumulate.scatter
                    acc[last_slot, local, 2] = x
                if x < acc[last_slot, local, 3]:
                    acc[last_slot, local, 3] = x
            kx, ky, kz, tx, ty, tz = _step(kx, ky, kz, tx, ty, tz, sx, sy, sz, dx, dy, dz)
            t_in = t_out
    return rays.shape[0], 0
