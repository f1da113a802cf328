"""numba kernels of the grid: block hashing, Amanatides-Woo traversal, projection, per-frame aggregation.

Only the wrappers in ``_storage.py``, ``_integrate.py`` and ``_map.py`` call these; they validate and
convert their inputs first (contiguous arrays, right dtypes, keys inside the limit). Kernels assume.

Blocks: a voxel key ``(kx, ky, kz)`` lies in block ``(kx >> bx, ky >> by, kz >> bz)`` at local index
``(kx & mx) | (ky & my) << bx | (kz & mz) << (bx + by)``; ``bits = (bx, by, bz)``. A block key is packed
into one int64 (21 bits per axis, offset ``2**20``) and found through an open-addressing hash table
(linear probing, Fibonacci hashing) from packed key to block slot.
"""

import numba
import numpy as np

EMPTY = np.int64(-1)
_OFFSET = 1 << 20
_MASK21 = (1 << 21) - 1

POLICY_CODES = {"mean": 0, "max-abs": 1, "occupied-wins": 2, "max": 3, "sum": 4}
"""Per-frame policy name -> code used by :func:`apply_frame`."""


@numba.njit(cache=True)
def pack_block(bx, by, bz):
    """Packed int64 of a block coordinate triple (each in [-2**20, 2**20))."""
    return ((np.int64(bx) + _OFFSET) << 42) | ((np.int64(by) + _OFFSET) << 21) | (np.int64(bz) + _OFFSET)


@numba.njit(cache=True)
def _hash_index(key, mask):
    h = np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64((h >> np.uint64(29)) & np.uint64(mask))


@numba.njit(cache=True)
def find_block(table_keys, table_slots, key):
    """Slot of packed block ``key``, or -1 when absent."""
    mask = table_keys.size - 1
    i = _hash_index(key, mask)
    while True:
        k = table_keys[i]
        if k == key:
            return np.int64(table_slots[i])
        if k == EMPTY:
            return np.int64(-1)
        i = (i + 1) & mask


@numba.njit(cache=True)
def insert_block(table_keys, table_slots, block_keys, n_blocks, key):
    """Slot of ``key``, adding it as block ``n_blocks[0]`` when absent (returns (slot, is_new)).

    The caller guarantees room: ``n_blocks[0] < block_keys.size`` and the table at most half full.
    """
    mask = table_keys.size - 1
    i = _hash_index(key, mask)
    while True:
        k = table_keys[i]
        if k == key:
            return np.int64(table_slots[i]), False
        if k == EMPTY:
            slot = n_blocks[0]
            table_keys[i] = key
            table_slots[i] = slot
            block_keys[slot] = key
            n_blocks[0] = slot + 1
            return np.int64(slot), True
        i = (i + 1) & mask


@numba.njit(cache=True)
def rehash(block_keys, n_blocks, table_size):
    """A new hash table of ``table_size`` (a power of two) holding blocks ``0 .. n_blocks-1``."""
    table_keys = np.full(table_size, EMPTY, dtype=np.int64)
    table_slots = np.zeros(table_size, dtype=np.int32)
    mask = table_size - 1
    for slot in range(n_blocks):
        key = block_keys[slot]
        i = _hash_index(key, mask)
        while table_keys[i] != EMPTY:
            i = (i + 1) & mask
        table_keys[i] = key
        table_slots[i] = slot
    return table_keys, table_slots


@numba.njit(cache=True)
def _split_key(kx, ky, kz, bits):
    bx, by, bz = bits
    local = (kx & ((1 << bx) - 1)) | ((ky & ((1 << by) - 1)) << bx) | ((kz & ((1 << bz) - 1)) << (bx + by))
    return pack_block(kx >> bx, ky >> by, kz >> bz), local


@numba.njit(cache=True)
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
    n_rays = rays.shape[0]
    inv = 1.0 / voxel_size
    k0 = np.floor(origin * inv).astype(np.int64)
    limits = np.empty(n_rays, dtype=np.int64)
    total = 0
    for i in range(n_rays):
        limit = 0
        if t_stop[i] > 0.0:
            limit = 3
            for ax in range(3):
                end = np.floor((origin[ax] + rays[i, ax] * t_stop[i]) * inv)
                limit += abs(np.int64(end) - k0[ax])
        limits[i] = limit
        total += limit
    ray_of_cell = np.empty(total, dtype=np.int64)
    keys = np.empty((total, 3), dtype=np.int32)
    t_in_out = np.empty(total, dtype=np.float64)
    t_out_out = np.empty(total, dtype=np.float64)
    key = np.empty(3, dtype=np.int64)
    step = np.empty(3, dtype=np.int64)
    t_max = np.empty(3, dtype=np.float64)
    t_delta = np.empty(3, dtype=np.float64)
    m = 0
    for i in range(n_rays):
        if limits[i] == 0:
            continue
        # Setup phase: first voxel border and voxel-to-voxel depth step on each axis.
        norm = 0.0
        for ax in range(3):
            r = rays[i, ax]
            norm += r * r
            key[ax] = k0[ax]
            if r > 0.0:
                step[ax] = 1
                t_max[ax] = ((k0[ax] + 1) * voxel_size - origin[ax]) / r
                t_delta[ax] = voxel_size / r
            elif r < 0.0:
                step[ax] = -1
                t_max[ax] = (k0[ax] * voxel_size - origin[ax]) / r
                t_delta[ax] = -voxel_size / r
            else:
                step[ax] = 0
                t_max[ax] = np.inf
                t_delta[ax] = np.inf
        min_length = 1e-9 * voxel_size / np.sqrt(norm)
        stop = t_stop[i]
        t_in = 0.0
        # Step phase; the loop bound is the length guard against floating-point drift.
        for _ in range(limits[i]):
            ax = 0
            if t_max[1] < t_max[ax]:
                ax = 1
            if t_max[2] < t_max[ax]:
                ax = 2
            t_out = t_max[ax]
            if exclusive[i]:
                if t_out > stop:
                    break
            elif t_in > stop:
                break
            if t_out - t_in > min_length:
                ray_of_cell[m] = i
                keys[m, 0] = key[0]
                keys[m, 1] = key[1]
                keys[m, 2] = key[2]
                t_in_out[m] = t_in
                t_out_out[m] = t_out
                m += 1
            key[ax] += step[ax]
            t_max[ax] += t_delta[ax]
            t_in = t_out
    return ray_of_cell[:m], keys[:m], t_in_out[:m], t_out_out[:m]


@numba.njit(cache=True)
def project_voxels(key_min, shape, origin, R_cam_world, focal, cx, cy, subsample, ray_index, rays, t_stop, exclusive, voxel_size):
    """Voxels of a key box seen by a pixel ray, with the voxel's depth interval on that ray.

    Each voxel centre is projected into the (subsampled) image; the nearest grid pixel with a valid
    ray (``ray_index >= 0``) is the voxel's ray. The interval is the slab intersection of that ray with
    the voxel's box; if the ray misses the box (it passes up to half a pixel beside the centre), the
    interval is the centre's depth +- half a voxel. The voxel is kept by the same rule as
    :func:`cast_rays`. Returns ``ray_of_cell, keys, t_in, t_out`` as :func:`cast_rays` does.
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    capacity = nx * ny * nz
    ray_of_cell = np.empty(capacity, dtype=np.int64)
    keys = np.empty((capacity, 3), dtype=np.int32)
    t_in_out = np.empty(capacity, dtype=np.float64)
    t_out_out = np.empty(capacity, dtype=np.float64)
    rows, cols = ray_index.shape
    half = 0.5 * voxel_size
    m = 0
    for ix in range(nx):
        kx = key_min[0] + ix
        wx = (kx + 0.5) * voxel_size - origin[0]
        for iy in range(ny):
            ky = key_min[1] + iy
            wy = (ky + 0.5) * voxel_size - origin[1]
            for iz in range(nz):
                kz = key_min[2] + iz
                wz = (kz + 0.5) * voxel_size - origin[2]
                pz = R_cam_world[2, 0] * wx + R_cam_world[2, 1] * wy + R_cam_world[2, 2] * wz
                if pz <= 0.0:
                    continue
                px = R_cam_world[0, 0] * wx + R_cam_world[0, 1] * wy + R_cam_world[0, 2] * wz
                py = R_cam_world[1, 0] * wx + R_cam_world[1, 1] * wy + R_cam_world[1, 2] * wz
                col = np.floor((focal * px / pz + cx) / subsample + 0.5)
                row = np.floor((focal * py / pz + cy) / subsample + 0.5)
                if col < 0 or row < 0 or col >= cols or row >= rows:
                    continue
                ray = ray_index[np.int64(row), np.int64(col)]
                if ray < 0:
                    continue
                # Slab intersection of the ray with the voxel box, in depth units.
                t0 = -np.inf
                t1 = np.inf
                corner = (kx * voxel_size, ky * voxel_size, kz * voxel_size)
                for ax in range(3):
                    r = rays[ray, ax]
                    lo = corner[ax] - origin[ax]
                    if r != 0.0:
                        ta = lo / r
                        tb = (lo + voxel_size) / r
                        if ta > tb:
                            ta, tb = tb, ta
                        t0 = max(t0, ta)
                        t1 = min(t1, tb)
                    elif lo > 0.0 or lo + voxel_size <= 0.0:
                        t1 = -np.inf
                t0 = max(t0, 0.0)
                if t1 <= t0:
                    t0 = max(pz - half, 0.0)
                    t1 = pz + half
                if exclusive[ray]:
                    if t1 > t_stop[ray]:
                        continue
                elif t0 > t_stop[ray]:
                    continue
                ray_of_cell[m] = ray
                keys[m, 0] = kx
                keys[m, 1] = ky
                keys[m, 2] = kz
                t_in_out[m] = t0
                t_out_out[m] = t1
                m += 1
    return ray_of_cell[:m], keys[:m], t_in_out[:m], t_out_out[:m]


@numba.njit(cache=True)
def accumulate(table_keys, table_slots, block_keys, n_blocks, acc, keys, increment, start, bits):
    """Add (key, increment) pairs from index ``start`` into the frame accumulator.

    ``acc[slot, local]`` holds ``(sum, count, max, min)`` of the increments that fell on a voxel this
    frame. Stops early, returning the index of the first pair not added, when a new block would
    exceed the accumulator's room (the caller grows it and calls again); returns ``len(keys)`` when done.
    """
    capacity = min(block_keys.size, table_keys.size // 2)
    last_key = EMPTY
    slot = np.int64(-1)
    for i in range(start, keys.shape[0]):
        block, local = _split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        if block != last_key:
            slot = find_block(table_keys, table_slots, block)
            if slot < 0:
                if n_blocks[0] >= capacity:
                    return i
                slot, _ = insert_block(table_keys, table_slots, block_keys, n_blocks, block)
                for v in range(acc.shape[1]):
                    acc[slot, v, 0] = 0.0
                    acc[slot, v, 1] = 0.0
                    acc[slot, v, 2] = -np.inf
                    acc[slot, v, 3] = np.inf
            last_key = block
        x = np.float32(increment[i])
        acc[slot, local, 0] += x
        acc[slot, local, 1] += 1.0
        if x > acc[slot, local, 2]:
            acc[slot, local, 2] = x
        if x < acc[slot, local, 3]:
            acc[slot, local, 3] = x
    return keys.shape[0]


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def _map_block(table_keys, table_slots, block_keys, n_blocks, log, count, key, prior_log):
    """Slot of map block ``key``, created with every voxel at the prior and count 0 when absent."""
    slot, new = insert_block(table_keys, table_slots, block_keys, n_blocks, key)
    if new:
        log[slot, :] = prior_log
        count[slot, :] = 0
    return slot


@numba.njit(cache=True)
def apply_frame(table_keys, table_slots, block_keys, n_blocks, log, count, frame_keys, n_frame, acc, policy, clamp_lo, clamp_hi, prior_log):
    """One update per voxel the frame touched: ``log += policy(increments)``, clamped, ``count += 1``.

    The map must have room for ``n_frame`` new blocks. Counts saturate at 65535.
    """
    for s in range(n_frame):
        slot = _map_block(table_keys, table_slots, block_keys, n_blocks, log, count, frame_keys[s], prior_log)
        for v in range(acc.shape[1]):
            n = acc[s, v, 1]
            if n == 0.0:
                continue
            inc = _policy_increment(acc[s, v, 0], n, acc[s, v, 2], acc[s, v, 3], policy)
            log[slot, v] = min(max(log[slot, v] + inc, clamp_lo), clamp_hi)
            if count[slot, v] < 65535:
                count[slot, v] += 1


@numba.njit(cache=True)
def merge_blocks(table_keys, table_slots, block_keys, n_blocks, log, count, other_keys, n_other, other_log, other_count, clamp_lo, clamp_hi, prior_log):
    """Add another map's blocks: known in both -> ``l1 + l2 - l0`` (clamped); counts add (saturating)."""
    for s in range(n_other):
        slot = _map_block(table_keys, table_slots, block_keys, n_blocks, log, count, other_keys[s], prior_log)
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


@numba.njit(cache=True)
def set_voxels(table_keys, table_slots, block_keys, n_blocks, log, count, keys, values, counts, bits, prior_log):
    """Overwrite the log-odds and count of each key, creating blocks as needed (room must be reserved)."""
    for i in range(keys.shape[0]):
        block, local = _split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        slot = _map_block(table_keys, table_slots, block_keys, n_blocks, log, count, block, prior_log)
        log[slot, local] = values[i]
        count[slot, local] = counts[i]


@numba.njit(cache=True)
def count_new_blocks(table_keys, table_slots, keys, bits):
    """Upper bound on the blocks ``keys`` would add: keys whose block is absent and differs from the previous key's."""
    n = 0
    last = EMPTY
    for i in range(keys.shape[0]):
        block, _ = _split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        if block != last and find_block(table_keys, table_slots, block) < 0:
            n += 1
        last = block
    return n


@numba.njit(cache=True)
def lookup(table_keys, table_slots, log, count, keys, bits, prior_log):
    """Log-odds and observation count at each key; ``(prior_log, 0)`` for voxels never stored."""
    n = keys.shape[0]
    out_log = np.empty(n, dtype=np.float32)
    out_count = np.empty(n, dtype=np.uint16)
    for i in range(n):
        block, local = _split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        slot = find_block(table_keys, table_slots, block)
        if slot < 0:
            out_log[i] = prior_log
            out_count[i] = 0
        else:
            out_log[i] = log[slot, local]
            out_count[i] = count[slot, local]
    return out_log, out_count
