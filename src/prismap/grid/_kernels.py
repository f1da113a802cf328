"""numba kernels of the grid: block hashing, Amanatides-Woo traversal, projection, per-frame aggregation.

Only the wrappers in ``_storage.py``, ``_integrate.py`` and ``_map.py`` call these; they validate and
convert their inputs first (contiguous arrays, right dtypes, keys inside the limit). Kernels assume.

Blocks: a voxel key ``(kx, ky, kz)`` lies in block ``(kx >> bx, ky >> by, kz >> bz)`` at local index
``(kx & mx) | (ky & my) << bx | (kz & mz) << (bx + by)``; ``bits = (bx, by, bz)``. A block key is packed
into one int64 (21 bits per axis, offset ``2**20``) and found through an open-addressing hash table
(linear probing, Fibonacci hashing) of int32 block slots: a table entry is a slot ``s`` (the block's
packed key is ``block_keys[s]``) or -1 when empty, so the table costs 4 bytes per entry. The frame
accumulator also links each block to its six face neighbours, so that a ray stepping into the next
block reads one int32 instead of hashing (~8.5 M block changes on a 640x480 frame at 0.1 m).

Speed notes (each measured): the hot loops inline everything on their common path; a call per block
change with array arguments (reference-counted) made a cast 3x slower. Kernels never grow arrays with
a generic helper (each dtype specialises it: seconds of first-call compile); they count and let the
caller retry with room.

Every kernel releases the GIL (``nogil=True``) so that a caller may run them beside Python code.
"""

import numba
import numpy as np

EMPTY = np.int64(-1)
"""Empty table entry; also 'no block' in the last-block caches."""
_OFFSET = 1 << 20
_MASK21 = (1 << 21) - 1

POLICY_CODES = {"mean": 0, "max-abs": 1, "occupied-wins": 2, "max": 3, "sum": 4}
"""Per-frame policy name -> code used by :func:`apply_frame`."""


@numba.njit(cache=True, nogil=True)
def pack_block(bx, by, bz):
    """Packed int64 of a block coordinate triple (each in [-2**20, 2**20))."""
    return ((np.int64(bx) + _OFFSET) << 42) | ((np.int64(by) + _OFFSET) << 21) | (np.int64(bz) + _OFFSET)


@numba.njit(cache=True, nogil=True)
def _hash_index(key, mask):
    """Table index of a packed block key: the axes folded together, then Fibonacci hashing (high bits)."""
    k = np.uint64(key)
    h = (k ^ (k >> np.uint64(21)) ^ (k >> np.uint64(42))) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64((h >> np.uint64(32)) & np.uint64(mask))


@numba.njit(cache=True, nogil=True)
def find_block(table, block_keys, key):
    """Slot of packed block ``key``, or -1 when absent."""
    mask = table.size - 1
    i = _hash_index(key, mask)
    while True:
        s = table[i]
        if s < 0:
            return np.int64(-1)
        if block_keys[s] == key:
            return np.int64(s)
        i = (i + 1) & mask


@numba.njit(cache=True, nogil=True)
def insert_block(table, block_keys, n_blocks, key):
    """Slot of ``key``, adding it as block ``n_blocks[0]`` when absent (returns (slot, is_new)).

    The caller guarantees room: ``n_blocks[0] < block_keys.size`` and the table at most half full.
    """
    mask = table.size - 1
    i = _hash_index(key, mask)
    while True:
        s = table[i]
        if s < 0:
            slot = n_blocks[0]
            table[i] = slot
            block_keys[slot] = key
            n_blocks[0] = slot + 1
            return np.int64(slot), True
        if block_keys[s] == key:
            return np.int64(s), False
        i = (i + 1) & mask


@numba.njit(cache=True, nogil=True)
def rehash(block_keys, n_blocks, table_size):
    """A new hash table of ``table_size`` (a power of two) holding blocks ``0 .. n_blocks-1``."""
    table = np.full(table_size, -1, dtype=np.int32)
    mask = table_size - 1
    for slot in range(n_blocks):
        i = _hash_index(block_keys[slot], mask)
        while table[i] >= 0:
            i = (i + 1) & mask
        table[i] = slot
    return table


@numba.njit(cache=True, nogil=True, inline="always")
def _split_key(kx, ky, kz, bits):
    bx, by, bz = bits
    local = (kx & ((1 << bx) - 1)) | ((ky & ((1 << by) - 1)) << bx) | ((kz & ((1 << bz) - 1)) << (bx + by))
    return pack_block(kx >> bx, ky >> by, kz >> bz), local


@numba.njit(cache=True, nogil=True)
def _cell_limits(origin, rays, t_stop, voxel_size):
    """Per ray, a bound on the voxels it visits (0 when it casts nothing); the traversal's length guard."""
    limits = np.zeros(rays.shape[0], dtype=np.int64)
    for i in range(rays.shape[0]):
        if t_stop[i] > 0.0:
            limits[i] = _span(origin, rays[i], t_stop[i], voxel_size, (0, 0, 0))
    return limits


@numba.njit(cache=True, nogil=True, inline="always")
def _span(origin, ray, stop, voxel_size, bits):
    """A bound on the voxels (``bits = (0, 0, 0)``) or blocks a ray visits up to depth ``stop``."""
    inv = 1.0 / voxel_size
    limit = 3
    for ax in range(3):
        start = np.int64(np.floor(origin[ax] * inv)) >> bits[ax]
        end = np.int64(np.floor((origin[ax] + ray[ax] * stop) * inv)) >> bits[ax]
        limit += abs(end - start)
    return limit


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
def _walk(origin, ray, stop, exclusive, voxel_size, limit, keys, t_in_out, t_out_out, m):
    """Amanatides-Woo traversal of one ray, writing its voxels from row ``m`` on; returns the next free row.

    The rule of :func:`cast_rays`; ``limit`` (from :func:`_cell_limits`) bounds the steps. The state is
    kept in scalars (one per axis) so that it stays in registers.
    """
    kx, sx, tx, dx = _axis_setup(origin[0], ray[0], voxel_size)
    ky, sy, ty, dy = _axis_setup(origin[1], ray[1], voxel_size)
    kz, sz, tz, dz = _axis_setup(origin[2], ray[2], voxel_size)
    min_length = 1e-9 * voxel_size / np.sqrt(ray[0] * ray[0] + ray[1] * ray[1] + ray[2] * ray[2])
    t_in = 0.0
    # Step phase; the loop bound is the length guard against floating-point drift.
    for _ in range(limit):
        t_out = min(tx, min(ty, tz))
        if _past_stop(t_in, t_out, stop, exclusive):
            break
        if t_out - t_in > min_length:
            keys[m, 0] = kx
            keys[m, 1] = ky
            keys[m, 2] = kz
            t_in_out[m] = t_in
            t_out_out[m] = t_out
            m += 1
        kx, ky, kz, tx, ty, tz = _step(kx, ky, kz, tx, ty, tz, sx, sy, sz, dx, dy, dz)
        t_in = t_out
    return m


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
    limits = _cell_limits(origin, rays, t_stop, voxel_size)
    total = limits.sum()
    ray_of_cell = np.empty(total, dtype=np.int64)
    keys = np.empty((total, 3), dtype=np.int32)
    t_in = np.empty(total, dtype=np.float64)
    t_out = np.empty(total, dtype=np.float64)
    m = 0
    for i in range(rays.shape[0]):
        if limits[i] > 0:
            end = _walk(origin, rays[i], t_stop[i], exclusive[i], voxel_size, limits[i], keys, t_in, t_out, m)
            ray_of_cell[m:end] = i
            m = end
    return ray_of_cell[:m], keys[:m], t_in[:m], t_out[:m]


@numba.njit(cache=True, nogil=True)
def cast_rays_into(table, block_keys, n_blocks, acc, links, origin, rays, t_stop, exclusive, voxel_size, bits):
    """:func:`cast_rays` fused with :func:`register_keys`: each crossed voxel's accumulator row, no keys.

    Returns ``ray_of_cell (C,) int64, cell_index (C,) int64, t_in (C,), t_out (C,) float64`` and the
    number of rays done: fewer than ``len(rays)`` when a new block found the accumulator full (that
    ray's cells are left out; grow the accumulator and cast the remaining rays).
    """
    limits = _cell_limits(origin, rays, t_stop, voxel_size)
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
        n = _walk(origin, rays[i], t_stop[i], exclusive[i], voxel_size, limits[i], scratch, t_in[m:], t_out[m:], 0)
        done, last_block, last_slot = _register(
            table, block_keys, n_blocks, acc, links, scratch, 0, n, bits, cell_index[m:], last_block, last_slot
        )
        if done < n:
            return ray_of_cell[:m], cell_index[:m], t_in[:m], t_out[:m], i
        ray_of_cell[m : m + n] = i
        m += n
    return ray_of_cell[:m], cell_index[:m], t_in[:m], t_out[:m], rays.shape[0]


@numba.njit(cache=True, nogil=True)
def cast_hit_miss(table, block_keys, n_blocks, acc, links, origin, rays, t_stop, exclusive, z_hit, l_hit, l_miss,
                  voxel_size, bits):
    """Cast rays and add hit/miss increments straight into the accumulator (no per-cell arrays).

    Voxels as :func:`cast_rays` keeps them; one of interval ``[t_in, t_out)`` on ray ``i`` gets ``l_hit``
    if it holds ``z_hit[i]``, ``l_miss`` if it ends at or before it, 0 beyond (the rule of
    ``sensor_models._kernels.hitmiss_cells``), added as :func:`scatter` adds. Returns the number of rays
    done and the blocks the next ray may need: a ray starts only when the accumulator has room for every
    block it may cross, so when it stops short, grow the accumulator and cast the remaining rays.

    ``links[slot]`` caches the slots of a block's six face neighbours (order of :func:`_side`; -1 = not
    yet known): a ray entering the next block reads it instead of hashing (:func:`_link_block`).
    """
    limits = _cell_limits(origin, rays, t_stop, voxel_size)
    capacity = min(block_keys.size, table.size // 2)
    hit = np.float32(l_hit)
    miss = np.float32(l_miss)
    zero = np.float32(0.0)
    last_block, last_slot = EMPTY, np.int64(-1)
    for i in range(rays.shape[0]):
        if limits[i] == 0:
            continue
        blocks = _span(origin, rays[i], t_stop[i], voxel_size, bits)
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
                block, local = _split_key(kx, ky, kz, bits)
                if block != last_block:
                    side = _side(block - last_block)
                    slot = np.int64(links[last_slot, side]) if side >= 0 else np.int64(-1)
                    if slot < 0:
                        slot = _link_block(table, block_keys, n_blocks, acc, links, block, side, last_slot, capacity)
                    last_block, last_slot = block, slot
                x = miss if t_out <= z else (hit if t_in <= z else zero)
                acc[last_slot, local, 0] += x
                acc[last_slot, local, 1] += 1.0
                if x > acc[last_slot, local, 2]:
                    acc[last_slot, local, 2] = x
                if x < acc[last_slot, local, 3]:
                    acc[last_slot, local, 3] = x
            kx, ky, kz, tx, ty, tz = _step(kx, ky, kz, tx, ty, tz, sx, sy, sz, dx, dy, dz)
            t_in = t_out
    return rays.shape[0], 0


@numba.njit(cache=True, nogil=True, inline="always")
def _side(step):
    """Face of a block that a packed block-key difference crosses: 0/1 for +x/-x, 2/3 for +y/-y, 4/5 for
    +z/-z, -1 when the blocks are not face neighbours (``side ^ 1`` is the opposite face)."""
    if step == 1 << 42:
        return 0
    if step == -(1 << 42):
        return 1
    if step == 1 << 21:
        return 2
    if step == -(1 << 21):
        return 3
    if step == 1:
        return 4
    if step == -1:
        return 5
    return -1


@numba.njit(cache=True, nogil=True)
def _link_block(table, block_keys, n_blocks, acc, links, block, side, last_slot, capacity):
    """Slot of accumulator block ``block`` by hashing (adding it when absent), linked to ``last_slot`` on
    face ``side`` (if >= 0); -1 when absent and the accumulator holds ``capacity`` blocks. The slow path
    of a block change: the caller first tries ``links[last_slot, side]`` (inline: a call per block
    change costs ~3x the whole cast)."""
    slot = find_block(table, block_keys, block)
    if slot < 0:
        if n_blocks[0] >= capacity:
            return np.int64(-1)
        slot = _accumulator_block(table, block_keys, n_blocks, acc, links, block)
    if side >= 0:
        links[last_slot, side] = slot
        links[slot, side ^ 1] = last_slot
    return slot


@numba.njit(cache=True, nogil=True)
def _accumulator_block(table, block_keys, n_blocks, acc, links, block):
    """Slot of accumulator block ``block``, added with neutral rows ``(0, 0, -inf, +inf)`` and no links
    when absent (room reserved)."""
    slot, new = insert_block(table, block_keys, n_blocks, block)
    if new:
        links[slot, :] = -1
        for v in range(acc.shape[1]):
            acc[slot, v, 0] = 0.0
            acc[slot, v, 1] = 0.0
            acc[slot, v, 2] = -np.inf
            acc[slot, v, 3] = np.inf
    return slot


@numba.njit(cache=True, nogil=True)
def project_voxels(key_min, shape, origin, R_cam_world, focal, cx, cy, subsample, ray_index, rays, t_stop, exclusive,
                   voxel_size, capacity):
    """Voxels of a key box seen by a pixel ray, with the voxel's depth interval on that ray.

    Each voxel centre is projected into the (subsampled) image; the nearest grid pixel with a valid
    ray (``ray_index >= 0``) is the voxel's ray. The interval is the slab intersection of that ray with
    the voxel's box; if the ray misses the box (it passes up to half a pixel beside the centre), the
    interval is the centre's depth +- half a voxel. The voxel is kept by the same rule as
    :func:`cast_rays`. Returns ``ray_of_cell, keys, t_in, t_out`` as :func:`cast_rays` does, in the
    order of the box (x, then y, then z), and how many voxels are kept: when that exceeds ``capacity``
    (the outputs' size) only the first ``capacity`` are returned; call again with room for all.
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    ray_of_cell = np.empty(capacity, dtype=np.int64)
    keys = np.empty((capacity, 3), dtype=np.int32)
    t_in_out = np.empty(capacity, dtype=np.float64)
    t_out_out = np.empty(capacity, dtype=np.float64)
    rows, cols = ray_index.shape
    half = 0.5 * voxel_size
    reach = np.sqrt(0.75) * voxel_size  # centre to corner: no point of the voxel is nearer in depth
    col_offset = cx / subsample + 0.5
    row_offset = cy / subsample + 0.5
    m = 0
    for ix in range(nx):
        kx = key_min[0] + ix
        wx = (kx + 0.5) * voxel_size - origin[0]
        for iy in range(ny):
            ky = key_min[1] + iy
            wy = (ky + 0.5) * voxel_size - origin[1]
            z_lo, z_hi = _column_in_image(R_cam_world, wx, wy, key_min[2], nz, origin[2], voxel_size, focal / subsample,
                                          col_offset, row_offset, cols, rows)
            for iz in range(z_lo, z_hi):
                kz = key_min[2] + iz
                wz = (kz + 0.5) * voxel_size - origin[2]
                pz = R_cam_world[2, 0] * wx + R_cam_world[2, 1] * wy + R_cam_world[2, 2] * wz
                if pz <= 0.0:
                    continue
                px = R_cam_world[0, 0] * wx + R_cam_world[0, 1] * wy + R_cam_world[0, 2] * wz
                py = R_cam_world[1, 0] * wx + R_cam_world[1, 1] * wy + R_cam_world[1, 2] * wz
                scale = focal / (pz * subsample)
                col = np.floor(px * scale + col_offset)
                row = np.floor(py * scale + row_offset)
                if col < 0 or row < 0 or col >= cols or row >= rows:
                    continue
                ray = ray_index[np.int64(row), np.int64(col)]
                if ray < 0:
                    continue
                stop = t_stop[ray]
                if pz - reach > stop:  # the whole voxel lies beyond the ray's stop depth
                    continue
                # Slab intersection of the ray with the voxel box, in depth units.
                t0, t1 = _slab(rays[ray, 0], rays[ray, 1], rays[ray, 2], kx * voxel_size - origin[0],
                               ky * voxel_size - origin[1], kz * voxel_size - origin[2], voxel_size)
                t0 = max(t0, 0.0)
                if t1 <= t0:
                    t0 = max(pz - half, 0.0)
                    t1 = pz + half
                if exclusive[ray]:
                    if t1 > stop:
                        continue
                elif t0 > stop:
                    continue
                if m >= capacity:  # full: only count (the caller repeats with room for all)
                    m += 1
                    continue
                ray_of_cell[m] = ray
                keys[m, 0] = kx
                keys[m, 1] = ky
                keys[m, 2] = kz
                t_in_out[m] = t0
                t_out_out[m] = t1
                m += 1
    n = min(m, capacity)
    return ray_of_cell[:n], keys[:n], t_in_out[:n], t_out_out[:n], m


@numba.njit(cache=True, nogil=True, inline="always")
def _half_line(slope, value, lo, hi):
    """Narrow ``[lo, hi)`` (indices ``i``) to where ``value + i slope >= 0`` may hold, one index of margin.

    The margin absorbs rounding: the caller still tests each index exactly, so this only skips
    indices that surely fail. A zero slope leaves the range alone (the exact test decides).
    """
    if slope > 0.0:
        bound = -value / slope
        if bound > lo:
            lo = max(lo, np.int64(np.floor(min(bound, hi + 1.0))) - 1)
    elif slope < 0.0:
        bound = -value / slope
        if bound < hi:
            hi = min(hi, np.int64(np.ceil(max(bound, lo - 1.0))) + 2)
    return lo, hi


@numba.njit(cache=True, nogil=True, inline="always")
def _column_in_image(R_cam_world, wx, wy, kz_min, nz, oz, voxel_size, scale, col_offset, row_offset, cols, rows):
    """Index range ``[lo, hi)`` of the voxels ``iz`` of one key column (centre ``(wx, wy, (kz_min + iz +
    0.5) voxel_size - oz)`` relative to the origin) that may be in front of the camera and project into
    the image, a superset of those that do.

    Each condition is linear in ``iz`` once multiplied by the (positive) depth ``pz``: ``pz > 0``,
    ``px scale + col_offset pz >= 0``, ``px scale + (col_offset - cols) pz < 0`` and the same for rows.
    """
    wz = (kz_min + 0.5) * voxel_size - oz
    px = R_cam_world[0, 0] * wx + R_cam_world[0, 1] * wy + R_cam_world[0, 2] * wz
    py = R_cam_world[1, 0] * wx + R_cam_world[1, 1] * wy + R_cam_world[1, 2] * wz
    pz = R_cam_world[2, 0] * wx + R_cam_world[2, 1] * wy + R_cam_world[2, 2] * wz
    dx, dy, dz = R_cam_world[0, 2] * voxel_size, R_cam_world[1, 2] * voxel_size, R_cam_world[2, 2] * voxel_size
    lo, hi = np.int64(0), np.int64(nz)
    lo, hi = _half_line(dz, pz, lo, hi)
    lo, hi = _half_line(dx * scale + col_offset * dz, px * scale + col_offset * pz, lo, hi)
    lo, hi = _half_line(-(dx * scale + (col_offset - cols) * dz), -(px * scale + (col_offset - cols) * pz), lo, hi)
    lo, hi = _half_line(dy * scale + row_offset * dz, py * scale + row_offset * pz, lo, hi)
    lo, hi = _half_line(-(dy * scale + (row_offset - rows) * dz), -(py * scale + (row_offset - rows) * pz), lo, hi)
    return lo, max(lo, hi)


@numba.njit(cache=True, nogil=True, inline="always")
def _slab_axis(r, lo, size, t0, t1):
    """Clip the depth interval ``[t0, t1]`` to where ``lo <= t r < lo + size`` on one axis."""
    if r != 0.0:
        inv = 1.0 / r
        ta = lo * inv
        tb = (lo + size) * inv
        return max(t0, min(ta, tb)), min(t1, max(ta, tb))
    if lo > 0.0 or lo + size <= 0.0:
        return t0, -np.inf
    return t0, t1


@numba.njit(cache=True, nogil=True, inline="always")
def _slab(rx, ry, rz, lx, ly, lz, size):
    """Depth interval of the ray ``t (rx, ry, rz)`` inside the box ``[l, l + size)`` (empty: t1 <= t0)."""
    t0, t1 = _slab_axis(rx, lx, size, -np.inf, np.inf)
    t0, t1 = _slab_axis(ry, ly, size, t0, t1)
    return _slab_axis(rz, lz, size, t0, t1)


@numba.njit(cache=True, nogil=True)
def rotate_rays(rays, rotation):
    """``rays @ rotation.T`` for (R, 3) rays: numpy's BLAS product of this shape costs ~10x more."""
    out = np.empty_like(rays)
    for i in range(rays.shape[0]):
        x, y, z = rays[i, 0], rays[i, 1], rays[i, 2]
        for a in range(3):
            out[i, a] = rotation[a, 0] * x + rotation[a, 1] * y + rotation[a, 2] * z
    return out


@numba.njit(cache=True, nogil=True)
def frustum_box(origin, rays, t_stop, voxel_size):
    """Key box of the origin and every ray's stop point, one voxel of margin: ``(key_min (3,), shape (3,))``
    int64 and the number of rays that cast anything (``t_stop > 0``)."""
    lo = np.floor(origin / voxel_size)
    hi = lo.copy()
    n = 0
    for i in range(rays.shape[0]):
        if t_stop[i] > 0.0:
            n += 1
            for ax in range(3):
                k = np.floor((origin[ax] + rays[i, ax] * t_stop[i]) / voxel_size)
                lo[ax] = min(lo[ax], k)
                hi[ax] = max(hi[ax], k)
    key_min = lo.astype(np.int64) - 1
    return key_min, hi.astype(np.int64) + 2 - key_min, n


@numba.njit(cache=True, nogil=True)
def sort_by_ray(ray_of_cell, n_rays, cell_index, t_in, t_out):
    """Cells grouped by ray, in their order within a ray (a counting sort).

    Returns the sorted ``cell_index, t_in, t_out`` (C,), the rays that have cells ``used (U,)``
    (increasing) and, per sorted cell, the index of its ray in ``used`` (C,).
    """
    counts = np.zeros(n_rays + 1, dtype=np.int64)
    for i in range(ray_of_cell.size):
        counts[ray_of_cell[i] + 1] += 1
    n_used = 0
    for r in range(n_rays):
        if counts[r + 1] > 0:
            n_used += 1
        counts[r + 1] += counts[r]
    used = np.empty(n_used, dtype=np.int64)
    local = np.empty(ray_of_cell.size, dtype=np.int64)
    u = 0
    for r in range(n_rays):
        if counts[r + 1] > counts[r]:
            used[u] = r
            local[counts[r] : counts[r + 1]] = u
            u += 1
    sorted_index = np.empty(cell_index.size, dtype=np.int64)
    sorted_in = np.empty(t_in.size)
    sorted_out = np.empty(t_out.size)
    for i in range(ray_of_cell.size):
        r = ray_of_cell[i]
        j = counts[r]
        counts[r] = j + 1
        sorted_index[j] = cell_index[i]
        sorted_in[j] = t_in[i]
        sorted_out[j] = t_out[i]
    return sorted_index, sorted_in, sorted_out, used, local


@numba.njit(cache=True, nogil=True, inline="always")
def _register(table, block_keys, n_blocks, acc, links, keys, start, stop, bits, out, last_block, last_slot):
    """Accumulator row (``slot * V + local``) of ``keys[start:stop]`` into ``out[0:]``, adding blocks.

    A new block's rows start neutral: ``(0, 0, -inf, +inf)``. ``(last_block, last_slot)`` caches the
    block of the previous key across calls. Returns ``(index of the first key not registered, last_block,
    last_slot)``; the index is ``stop`` unless a new block would exceed the accumulator's room (the
    table at most half full).
    """
    capacity = min(block_keys.size, table.size // 2)
    voxels = acc.shape[1]
    for i in range(start, stop):
        block, local = _split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        if block != last_block:
            side = _side(block - last_block)
            slot = np.int64(links[last_slot, side]) if side >= 0 else np.int64(-1)
            if slot < 0:
                slot = _link_block(table, block_keys, n_blocks, acc, links, block, side, last_slot, capacity)
                if slot < 0:
                    return i, last_block, last_slot
            last_block = block
            last_slot = slot
        out[i - start] = last_slot * voxels + local
    return stop, last_block, last_slot


@numba.njit(cache=True, nogil=True)
def register_keys(table, block_keys, n_blocks, acc, links, keys, start, bits, out):
    """Accumulator rows of ``keys[start:]`` into ``out[start:]``; returns the first index not registered."""
    return _register(table, block_keys, n_blocks, acc, links, keys, start, keys.shape[0], bits, out[start:], EMPTY, np.int64(-1))[0]


@numba.njit(cache=True, nogil=True)
def scatter(acc, cell_index, increment):
    """Add each cell's increment to its accumulator row: ``(sum, count, max, min)``, float32.

    ``acc`` is the accumulator payload seen as (rows, 4); ``cell_index`` from :func:`register_keys`.
    """
    for i in range(cell_index.size):
        row = cell_index[i]
        x = np.float32(increment[i])
        acc[row, 0] += x
        acc[row, 1] += 1.0
        if x > acc[row, 2]:
            acc[row, 2] = x
        if x < acc[row, 3]:
            acc[row, 3] = x


@numba.njit(cache=True, nogil=True)
def _policy_increment(total, count, largest, smallest, policy):
    if policy == 0:
        return total / count
    if policy == 1:
        return largest if abs(largest) >= abs(smallest) else smallest
    if policy == 2:
        return largest if largest > 0.0 else total / count
    if policy == 3:
        return largest
    return total


@numba.njit(cache=True, nogil=True)
def _map_block(table, block_keys, n_blocks, log, count, key, prior_log):
    """Slot of map block ``key``, created with every voxel at the prior and count 0 when absent."""
    slot, new = insert_block(table, block_keys, n_blocks, key)
    if new:
        log[slot, :] = prior_log
        count[slot, :] = 0
    return slot


@numba.njit(cache=True, nogil=True)
def apply_frame(table, block_keys, n_blocks, log, count, frame_keys, n_frame, acc, policy, clamp_lo, clamp_hi, prior_log):
    """One update per voxel the frame touched: ``log += policy(increments)``, clamped, ``count += 1``.

    The map must have room for ``n_frame`` new blocks. Counts saturate at 65535.
    """
    for s in range(n_frame):
        slot = _map_block(table, block_keys, n_blocks, log, count, frame_keys[s], prior_log)
        for v in range(acc.shape[1]):
            n = acc[s, v, 1]
            if n == 0.0:
                continue
            inc = _policy_increment(acc[s, v, 0], n, acc[s, v, 2], acc[s, v, 3], policy)
            log[slot, v] = min(max(log[slot, v] + inc, clamp_lo), clamp_hi)
            if count[slot, v] < 65535:
                count[slot, v] += 1


@numba.njit(cache=True, nogil=True)
def merge_blocks(table, block_keys, n_blocks, log, count, other_keys, n_other, other_log, other_count, clamp_lo, clamp_hi, prior_log):
    """Add another map's blocks: known in both -> ``l1 + l2 - l0`` (clamped); counts add (saturating)."""
    for s in range(n_other):
        slot = _map_block(table, block_keys, n_blocks, log, count, other_keys[s], prior_log)
        for v in range(other_log.shape[1]):
            c = np.int64(other_count[s, v])
            if c == 0:
                continue
            mine = np.int64(count[slot, v])
            if mine == 0:
                log[slot, v] = other_log[s, v]
            else:
                log[slot, v] = min(max(log[slot, v] + other_log[s, v] - prior_log, clamp_lo), clamp_hi)
            count[slot, v] = min(mine + c, 65535)


@numba.njit(cache=True, nogil=True)
def set_voxels(table, block_keys, n_blocks, log, count, keys, values, counts, bits, prior_log):
    """Overwrite the log-odds and count of each key, creating blocks as needed (room must be reserved)."""
    for i in range(keys.shape[0]):
        block, local = _split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        slot = _map_block(table, block_keys, n_blocks, log, count, block, prior_log)
        log[slot, local] = values[i]
        count[slot, local] = counts[i]


@numba.njit(cache=True, nogil=True)
def count_new_blocks(table, block_keys, keys, bits):
    """Upper bound on the blocks ``keys`` would add: keys whose block is absent and differs from the previous key's."""
    n = 0
    last = EMPTY
    for i in range(keys.shape[0]):
        block, _ = _split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        if block != last and find_block(table, block_keys, block) < 0:
            n += 1
        last = block
    return n


@numba.njit(cache=True, nogil=True)
def count_absent_blocks(table, block_keys, packed, n_packed):
    """How many of the packed block keys ``packed[:n_packed]`` (distinct) the table lacks."""
    n = 0
    for i in range(n_packed):
        if find_block(table, block_keys, packed[i]) < 0:
            n += 1
    return n


@numba.njit(cache=True, nogil=True)
def lookup(table, block_keys, log, count, keys, bits, prior_log):
    """Log-odds and observation count at each key; ``(prior_log, 0)`` for voxels never stored."""
    n = keys.shape[0]
    out_log = np.empty(n, dtype=np.float32)
    out_count = np.empty(n, dtype=np.uint16)
    for i in range(n):
        block, local = _split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        slot = find_block(table, block_keys, block)
        if slot < 0:
            out_log[i] = prior_log
            out_count[i] = 0
        else:
            out_log[i] = log[slot, local]
            out_count[i] = count[slot, local]
    return out_log, out_count
