"""Hashed voxel blocks: a growable table from packed block key to a slot in flat per-block arrays."""

import numpy as np

from prismap.grid import _kernels_hash
from prismap.grid._keys import block_voxel_keys, unpack_keys


class BlockTable:
    """Blocks of ``2**sum(bits)`` voxels, found through an open-addressing hash table.

    Parameters
    ----------
    bits : tuple of 3 int
        log2 of the block size on x, y, z: the map's ``BLOCK_BITS``, ``(2, 2, 2)`` for 4^3 blocks, ``(3, 3, 0)`` for
        8x8x1.
    payload : dict of str -> (tuple, dtype)
        Per-block arrays: name -> (trailing shape after the block axis, dtype).
    """

    def __init__(self, bits, payload):
        self.bits = tuple(int(b) for b in bits)
        self.block_voxels = 1 << sum(self.bits)
        self.n_blocks = np.zeros(1, dtype=np.int64)
        self.block_keys = np.empty(0, dtype=np.int64)
        self.table = np.full(16, -1, dtype=np.int32)
        self.payload = {name: np.empty((0, *shape), dtype=dtype) for name, (shape, dtype) in payload.items()}

    def __len__(self):
        return int(self.n_blocks[0])

    def clear(self):
        """Forget every block but keep the allocated memory (the frame accumulator is reused)."""
        self.n_blocks[0] = 0
        self.table.fill(-1)

    def reserve(self, extra, *, max_blocks=None):
        """Make room for ``extra`` more blocks (block arrays and a table at most half full).

        Block arrays grow to exactly what is needed, or by half when that is more (amortised O(1)
        growth with at most a third of the capacity spare), but never beyond ``max_blocks`` when given
        (the caller keeps ``len(self) + extra <= max_blocks``); the table doubles.
        """
        n = len(self)
        need = n + int(extra)
        if need > self.block_keys.size:
            capacity = max(need, self.block_keys.size + self.block_keys.size // 2, 16)
            if max_blocks is not None:
                capacity = max(need, min(capacity, int(max_blocks)))
            self.block_keys = _grown(self.block_keys, capacity, n)
            self.payload = {name: _grown(array, capacity, n) for name, array in self.payload.items()}
        if 2 * need > self.table.size:
            self.table = _kernels_hash.rehash(self.block_keys, n, _table_size(need))

    def __getstate__(self):
        """The used blocks only: no spare capacity and no hash table (:meth:`__setstate__` rebuilds it)."""
        n = len(self)
        return {
            "bits": self.bits,
            "block_keys": self.block_keys[:n],
            "payload": {name: array[:n] for name, array in self.payload.items()},
        }

    def __setstate__(self, state):
        self.__init__(state["bits"], {})
        writable = ("C", "W")  # arrays unpickled from a read-only buffer (a Dask message) are copied
        self.block_keys = np.require(state["block_keys"], requirements=writable)
        self.payload = {name: np.require(array, requirements=writable) for name, array in state["payload"].items()}
        self.n_blocks[0] = self.block_keys.size
        self.table = _kernels_hash.rehash(self.block_keys, len(self), _table_size(len(self)))

    def arrays(self, bundle):
        """The table's arrays as the kernels take them: ``bundle`` (a ``NamedTuple`` of
        :mod:`prismap.grid._kernel_args` whose fields are ``table``, ``block_keys``, ``n_blocks``, ``bits`` and the
        payload's names) holding them. :meth:`reserve` replaces arrays, so take them again after it."""
        return bundle(
            table=self.table, block_keys=self.block_keys, n_blocks=self.n_blocks, bits=self.bits, **self.payload
        )

    def count_absent(self, packed_keys, n):
        """How many of the distinct packed block keys ``packed_keys[:n]`` this table lacks."""
        return _kernels_hash.count_absent_blocks(self.table, self.block_keys, packed_keys, n)

    def block_coords(self):
        """(B, 3) int64 block coordinates of the stored blocks."""
        return unpack_keys(self.block_keys[: len(self)])

    def voxel_keys(self):
        """(B, V, 3) int64 voxel keys of every voxel of every stored block (V = voxels per block)."""
        return block_voxel_keys(self.block_coords(), self.bits)

    def bytes_per_block(self):
        """Bytes one more block costs: its payload rows, its packed key and its table entries (at most 4)."""
        return sum(a.itemsize * int(np.prod(a.shape[1:])) for a in self.payload.values()) + 8 + 16

    def nbytes(self):
        """Bytes held by the table and the block arrays (allocated capacity, not just the used part)."""
        arrays = [self.block_keys, self.table, *self.payload.values()]
        return int(sum(a.nbytes for a in arrays))


def _table_size(blocks):
    """Hash table entries for ``blocks`` blocks: the smallest power of two >= ``2 * blocks`` (at most half full),
    at least 16."""
    return 1 << max(4, (2 * int(blocks) - 1).bit_length())


def _grown(array, capacity, used):
    grown = np.empty((capacity, *array.shape[1:]), dtype=array.dtype)
    grown[:used] = array[:used]
    return grown
