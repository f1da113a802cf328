"""numba kernels of accumulation: a frame's per-voxel statistics, and the map updates from them.

The frame accumulator holds, per touched voxel, ``(sum, count, max, min)`` of its increments (float32) and
per block the slots of its six face neighbours, so that a ray stepping into the next block reads one int32
instead of hashing (~8.5 M block changes on a 640x480 frame at 0.1 m). The map holds fixed-point log-odds
(int64 units of ``_logodds.LOG_ODDS_STEP``) and uint16 counts; a frame adds one rounded integer per voxel
(``_policies.combine``), a merge adds integers, so both are exact and independent of order.
Called only by the grid's wrappers. Every kernel releases the GIL.
"""

import numba
import numpy as np

from prismap.grid._kernels_hash import EMPTY, find_block, insert_block
from prismap.grid._keys import PACKED_STEPS, split_key
from prismap.grid._logodds import LOG_ODDS_STEP, Q_MAX, Q_MIN, STEP_MAX
from prismap.grid._policies import combine

_STEP_X, _STEP_Y, _STEP_Z = PACKED_STEPS
_INV_STEP = 1.0 / LOG_ODDS_STEP


@numba.njit(cache=True, nogil=True, inline="always")
def face(step):
    """Face of a block that a packed block-key difference crosses: 0/1 for +x/-x, 2/3 for +y/-y, 4/5 for
    +z/-z, -1 when the blocks are not face neighbours (``side ^ 1`` is the opposite face)."""
    if step == _STEP_X:
        return 0
    if step == -_STEP_X:
        return 1
    if step == _STEP_Y:
        return 2
    if step == -_STEP_Y:
        return 3
    if step == _STEP_Z:
        return 4
    if step == -_STEP_Z:
        return 5
    return -1


@numba.njit(cache=True, nogil=True)
def link_block(accumulator, block, side, last_slot, capacity):
    """Slot of accumulator block ``block`` by hashing (adding it when absent), linked to ``last_slot`` on
    face ``side`` (if >= 0); -1 when absent and the accumulator holds ``capacity`` blocks. The slow path
    of a block change: the caller first tries ``links[last_slot, side]`` (inline: a call per block
    change costs ~3x the whole cast).

    Parameters
    ----------
    accumulator : AccumulatorArrays
        The frame accumulator (:class:`~prismap.grid._kernel_args.AccumulatorArrays`), changed in place.
    block : int64
        Packed block key.
    side : int
        Face of ``last_slot``'s block that leads to ``block`` (:func:`face`), -1 = not a face neighbour.
    last_slot : int64
        Slot of the previous block.
    capacity : int, blocks
        Most blocks the accumulator may hold.
    """
    links = accumulator.links
    slot = find_block(accumulator.table, accumulator.block_keys, block)
    if slot < 0:
        if accumulator.n_blocks[0] >= capacity:
            return np.int64(-1)
        slot = accumulator_block(accumulator, block)
    if side >= 0:
        links[last_slot, side] = slot
        links[slot, side ^ 1] = last_slot
    return slot


@numba.njit(cache=True, nogil=True)
def accumulator_block(accumulator, block):
    """Slot of accumulator block ``block`` (packed key, int64), added with neutral rows ``(0, 0, -inf, +inf)`` and
    no links when absent (room reserved) to ``accumulator`` (:class:`~prismap.grid._kernel_args.AccumulatorArrays`)."""
    table, block_keys, n_blocks, acc, links, _ = accumulator
    slot, new = insert_block(table, block_keys, n_blocks, block)
    if new:
        links[slot, :] = -1
        for v in range(acc.shape[1]):
            acc[slot, v, 0] = 0.0
            acc[slot, v, 1] = 0.0
            acc[slot, v, 2] = -np.inf
            acc[slot, v, 3] = np.inf
    return slot


@numba.njit(cache=True, nogil=True, inline="always")
def register_run(accumulator, keys, start, stop, out, last_block, last_slot):
    """Accumulator row (``slot * V + local``) of ``keys[start:stop]`` into ``out[0:]``, adding blocks.

    A new block's rows start neutral: ``(0, 0, -inf, +inf)``. ``(last_block, last_slot)`` caches the
    block of the previous key across calls. Returns ``(index of the first key not registered, last_block,
    last_slot)``; the index is ``stop`` unless a new block would exceed the accumulator's room (the
    table at most half full).

    Parameters
    ----------
    accumulator : AccumulatorArrays
        The frame accumulator (:class:`~prismap.grid._kernel_args.AccumulatorArrays`), changed in place.
    keys : (C, 3) int32, voxel keys
        The voxels.
    start, stop : int
        The keys of this call.
    out : (stop - start,) int64 or longer
        Written: each key's accumulator row.
    last_block : int64
        Packed key of the previous key's block (``_kernels_hash.EMPTY`` at first).
    last_slot : int64
        Its slot (-1 at first).
    """
    links, bits = accumulator.links, accumulator.bits
    capacity = min(accumulator.block_keys.size, accumulator.table.size // 2)
    voxels = accumulator.acc.shape[1]
    for i in range(start, stop):
        block, local = split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        if block != last_block:
            side = face(block - last_block)
            slot = np.int64(links[last_slot, side]) if side >= 0 else np.int64(-1)
            if slot < 0:
                slot = link_block(accumulator, block, side, last_slot, capacity)
                if slot < 0:
                    return i, last_block, last_slot
            last_block = block
            last_slot = slot
        out[i - start] = last_slot * voxels + local
    return stop, last_block, last_slot


@numba.njit(cache=True, nogil=True)
def scatter(acc, cell_index, increment, weight):
    """Add each cell's increment to its accumulator row (:func:`add_increment`), counted ``weight[i]`` times (float32;
    empty: once each: a sampled cell stands for the ``weight`` cells of its rays' subsample, ``_floor_sampling``).

    ``acc`` is the accumulator payload seen as (rows, 4); ``cell_index`` from :func:`register_run`.
    """
    weighted, once = weight.size > 0, np.float32(1.0)
    for i in range(cell_index.size):
        add_increment(acc, cell_index[i], np.float32(increment[i]), weight[i] if weighted else once)


SCATTER_RUN = 1024
"""Keys :func:`scatter_keys` registers per :func:`register_run` call (its rows scratch stays in L1)."""


@numba.njit(cache=True, nogil=True)
def scatter_keys(accumulator, keys, increment, start):
    """Register voxels ``keys[start:]`` ((C, 3) int32) in the accumulator in order (:func:`register_run`) and
    add each one's increment ((C,) float64, log-odds; :func:`add_increment`). Returns the index of the first key
    not done: ``C``, or less when a new block found the accumulator full (grow it and call again from there).
    ``accumulator``: :class:`~prismap.grid._kernel_args.AccumulatorArrays`, changed in place."""
    acc = accumulator.acc
    rows = acc.reshape((acc.shape[0] * acc.shape[1], acc.shape[2]))
    scratch = np.empty(SCATTER_RUN, dtype=np.int64)
    last_block, last_slot = EMPTY, np.int64(-1)
    once = np.float32(1.0)
    n = keys.shape[0]
    for lo in range(start, n, SCATTER_RUN):
        hi = min(lo + SCATTER_RUN, n)
        done, last_block, last_slot = register_run(accumulator, keys, lo, hi, scratch, last_block, last_slot)
        for i in range(lo, done):
            add_increment(rows, scratch[i - lo], np.float32(increment[i]), once)
        if done < hi:
            return done
    return n


@numba.njit(cache=True, nogil=True, inline="always")
def add_increment(acc, row, x, w):
    """Add float32 increment ``x`` to accumulator row ``row`` counted float32 ``w`` times: ``(sum += w x,
    count += w, max, min)`` (``w`` 1 but for a floor-sampled cell, exact in float32 then)."""
    acc[row, 0] += w * x
    acc[row, 1] += w
    if x > acc[row, 2]:  # a comparison, not max(): a NaN increment leaves the row alone
        acc[row, 2] = x
    if x < acc[row, 3]:
        acc[row, 3] = x


@numba.njit(cache=True, nogil=True)
def _map_block(store, key, prior_q):
    """Slot of block ``key`` (packed, int64) in ``store`` (:class:`~prismap.grid._kernel_args.MapStore`), created
    with every voxel at the prior ``prior_q`` (int64, units of ``LOG_ODDS_STEP``) and count 0 when absent (room
    reserved)."""
    slot, new = insert_block(store.table, store.block_keys, store.n_blocks, key)
    if new:
        store.log[slot, :] = prior_q
        store.count[slot, :] = 0
    return slot


@numba.njit(cache=True, nogil=True, inline="always")
def _bounded(q, lo, hi):
    """``q`` (int64 units) clamped to ``[lo, hi]`` and saturated to ``[Q_MIN, Q_MAX]``."""
    return min(max(q, max(lo, Q_MIN)), min(hi, Q_MAX))


@numba.njit(cache=True, nogil=True)
def apply_frame(store, accumulator, policy, clamp_lo, clamp_hi, prior_q):
    """One update per voxel the frame touched: ``q += round(policy(increments) / LOG_ODDS_STEP)`` (the step
    bounded to ``+-STEP_MAX``), clamped to ``[clamp_lo, clamp_hi]`` (int64 units), ``count += 1``.

    The map must have room for the accumulator's blocks that it lacks. Counts saturate at 65535.

    Parameters
    ----------
    store : MapStore
        The map's storage (:class:`~prismap.grid._kernel_args.MapStore`), changed in place.
    accumulator : AccumulatorArrays
        The frame's accumulator (:class:`~prismap.grid._kernel_args.AccumulatorArrays`): its blocks' packed keys
        and each voxel's ``(sum, count, max, min)`` of increments.
    policy : int
        The per-frame policy, its index in ``_policies.POLICIES``.
    clamp_lo, clamp_hi : int64, units of ``LOG_ODDS_STEP``
        Clamping bounds.
    prior_q : int64, units of ``LOG_ODDS_STEP``
        The prior's log-odds, of a new block's voxels.
    """
    log, count, acc, frame_keys = store.log, store.count, accumulator.acc, accumulator.block_keys
    for s in range(accumulator.n_blocks[0]):
        slot = _map_block(store, frame_keys[s], prior_q)
        for v in range(acc.shape[1]):
            n = acc[s, v, 1]
            if n == 0.0:
                continue
            inc = combine(acc[s, v, 0], n, acc[s, v, 2], acc[s, v, 3], policy)
            step = np.int64(np.rint(min(max(np.float64(inc) * _INV_STEP, -STEP_MAX), STEP_MAX)))
            log[slot, v] = _bounded(np.int64(log[slot, v]) + step, clamp_lo, clamp_hi)
            if count[slot, v] < 65535:
                count[slot, v] += 1


@numba.njit(cache=True, nogil=True)
def merge_blocks(store, other, clamp_lo, clamp_hi, prior_q):
    """Add another map's blocks: known in both -> ``q1 + q2 - q0`` (clamped); counts add (saturating).

    The map must have room for the other map's blocks that it lacks.

    Parameters
    ----------
    store : MapStore
        The map's storage (:class:`~prismap.grid._kernel_args.MapStore`), changed in place.
    other : MapStore
        The other map's storage, read only.
    clamp_lo, clamp_hi, prior_q : int64, units of ``LOG_ODDS_STEP``
        Clamping bounds, and the prior's log-odds (``q0``).
    """
    log, count, other_keys, other_log, other_count = store.log, store.count, other.block_keys, other.log, other.count
    for s in range(other.n_blocks[0]):
        slot = _map_block(store, other_keys[s], prior_q)
        for v in range(other_log.shape[1]):
            c = np.int64(other_count[s, v])
            if c == 0:
                continue
            mine = np.int64(count[slot, v])
            if mine == 0:
                log[slot, v] = other_log[s, v]
            else:
                log[slot, v] = _bounded(
                    np.int64(log[slot, v]) + np.int64(other_log[s, v]) - prior_q, clamp_lo, clamp_hi
                )
            count[slot, v] = min(mine + c, 65535)


@numba.njit(cache=True, nogil=True)
def set_voxels(store, keys, values, counts, prior_q):
    """Overwrite the fixed-point log-odds and count of each key, creating blocks as needed (room reserved).

    Parameters
    ----------
    store : MapStore
        The map's storage (:class:`~prismap.grid._kernel_args.MapStore`), changed in place.
    keys : (N, 3) int, voxel keys
        The voxels.
    values : (N,) int64, units of ``LOG_ODDS_STEP``
        Their log-odds.
    counts : (N,) uint16
        Their counts.
    prior_q : int64, units of ``LOG_ODDS_STEP``
        The prior's log-odds, of a new block's other voxels.
    """
    log, count, bits = store.log, store.count, store.bits
    last_block, slot = EMPTY, np.int64(-1)
    for i in range(keys.shape[0]):
        block, local = split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        if block != last_block:  # keys of one block in a row (a map's own order) share one look-up
            last_block = block
            slot = _map_block(store, block, prior_q)
        log[slot, local] = values[i]
        count[slot, local] = counts[i]


@numba.njit(cache=True, nogil=True)
def lookup(store, keys, prior_q):
    """Fixed-point log-odds (int64) and observation count (uint16) at each of ``keys`` ((N, 3) int, voxel keys) in
    ``store`` (:class:`~prismap.grid._kernel_args.MapStore`); ``(prior_q, 0)`` for voxels never stored."""
    table, block_keys, log, count, bits = store.table, store.block_keys, store.log, store.count, store.bits
    n = keys.shape[0]
    out_log = np.empty(n, dtype=np.int64)
    out_count = np.empty(n, dtype=np.uint16)
    for i in range(n):
        block, local = split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
        slot = find_block(table, block_keys, block)
        if slot < 0:
            out_log[i] = prior_q
            out_count[i] = 0
        else:
            out_log[i] = log[slot, local]
            out_count[i] = count[slot, local]
    return out_log, out_count


@numba.njit(cache=True, nogil=True)
def map_log_of_rows(store, accumulator, rows, prior_q):
    """The fixed-point log-odds (int64) in ``store`` (:class:`~prismap.grid._kernel_args.MapStore`) of the voxels
    of rows ``rows`` ((N,) int64) of the frame's ``accumulator`` (:class:`~prismap.grid._kernel_args.AccumulatorArrays`,
    blocks of the map's shape).

    A row is ``slot * V + voxel`` in the accumulator, the voxel's index in its block the same in the map;
    ``prior_q`` where the map has no such block. Consecutive rows of one block (a ray's cells) share one hash
    look-up.
    """
    table, block_keys, log, bits = store.table, store.block_keys, store.log, store.bits
    acc_block_keys = accumulator.block_keys
    out = np.empty(rows.size, dtype=np.int64)
    voxel_bits = bits[0] + bits[1] + bits[2]
    mask = (1 << voxel_bits) - 1
    last_block = -1
    slot = -1
    for i in range(rows.size):
        block = rows[i] >> voxel_bits
        if block != last_block:
            last_block = block
            slot = find_block(table, block_keys, acc_block_keys[block])
        out[i] = prior_q if slot < 0 else log[slot, rows[i] & mask]
    return out
