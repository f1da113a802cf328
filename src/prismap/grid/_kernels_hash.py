"""numba kernels of the block hash table: find, insert, rehash, count (called only by the grid's wrappers).

A packed block key (:mod:`prismap.grid._keys`) is found through an open-addressing hash table (linear
probing, Fibonacci hashing) of int32 block slots: a table entry is a slot ``s`` (the block's packed key is
``block_keys[s]``) or -1 when empty, so the table costs 4 bytes per entry. Kernels assume their inputs are
checked and converted; they never grow arrays (each dtype would specialise a generic helper: seconds of
first-call compile), they count and let the caller retry with room. Every kernel releases the GIL.
"""

import numba
import numpy as np

from prismap.grid._keys import AXIS_BITS, split_key

EMPTY = np.int64(-1)
"""Empty table entry; also 'no block' in the last-block caches."""


@numba.njit(cache=True, nogil=True)
def _hash_index(key, mask):
    """Table index of a packed block key: the axes folded together, then Fibonacci hashing (high bits)."""
    k = np.uint64(key)
    h = (k ^ (k >> np.uint64(AXIS_BITS)) ^ (k >> np.uint64(2 * AXIS_BITS))) * np.uint64(0x9E3779B97F4A7C15)
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


@numba.njit(cache=True, nogil=True)
def count_new_blocks(table, block_keys, keys, bits):
    """Upper bound on the blocks ``keys`` would add: keys whose block is absent and differs from the previous key's."""
    n = 0
    last = EMPTY
    for i in range(keys.shape[0]):
        block, _ = split_key(np.int64(keys[i, 0]), np.int64(keys[i, 1]), np.int64(keys[i, 2]), bits)
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
