"""The frame accumulator: per voxel a frame touches, ``(sum, count, max, min)`` of its increments.

A :class:`~prismap.grid._storage.BlockTable` of the map's block shape whose blocks also link to their six
face neighbours. Its size is bounded (:data:`MAX_FRAME_BYTES`): a frame that would touch more blocks is
refused with an error naming what to change, instead of exhausting memory.
"""

import numpy as np

from prismap._memory import address_space_room_bytes, physical_memory_bytes
from prismap.errors import PrismapInputError
from prismap.grid import _kernels_accumulate, _kernels_traverse
from prismap.grid._kernel_args import AccumulatorArrays
from prismap.grid._storage import BlockTable

MAX_FRAME_BYTES = 2 << 30
"""Memory the frame accumulator may hold (bytes), at most: about 2 M blocks of 4^3 voxels (128 M voxels).
Lowered to a quarter of the physical memory and a third of what the address-space limit (``RLIMIT_AS``)
leaves free when those are smaller (:func:`frame_budget_bytes`)."""


def frame_budget_bytes():
    """The frame accumulator's memory bound (bytes) on this machine and under this process's limits
    (:mod:`prismap._memory` measures both)."""
    budget = MAX_FRAME_BYTES
    physical = physical_memory_bytes()
    if physical is not None:
        budget = min(budget, physical // 4)
    room = address_space_room_bytes()
    if room is not None:
        budget = min(budget, room // 3)  # growing copies: old + new arrays
    return budget


def new_accumulator(bits):
    """An empty frame accumulator for blocks of ``bits`` (see :mod:`prismap.grid._keys`): per voxel
    ``(sum, count, max, min)`` of its increments, float32, and per block the slots of its six face
    neighbours (``links``, see ``_kernels_traverse.cast_hit_miss``)."""
    return BlockTable(bits, {"acc": ((1 << sum(bits), 4), np.float32), "links": ((6,), np.int32)})


def kernel_arrays(accumulator):
    """The accumulator's arrays as the kernels take them (:class:`~prismap.grid._kernel_args.AccumulatorArrays`);
    :func:`grow` replaces them, so take them again after it."""
    return accumulator.arrays(AccumulatorArrays)


def grow(accumulator, blocks):
    """Make room for ``max(blocks, 1)`` more blocks (at least 64, or as many as held), within
    :func:`frame_budget_bytes`; a frame that needs more is refused."""
    budget = frame_budget_bytes()
    max_blocks = budget // accumulator.bytes_per_block()
    held = len(accumulator)
    if held + max(int(blocks), 1) > max_blocks:
        raise PrismapInputError(
            f"one frame touches more than {max_blocks} voxel blocks ({budget / 2**30:.3g} GiB, the frame "
            "accumulator's bound; docs/errors.md): lower `max_range_m`, raise `voxel_size_m`, or subsample the rays"
        )
    accumulator.reserve(min(max(64, held, int(blocks)), max_blocks - held), max_blocks=max_blocks)


def expect(accumulator, blocks):
    """Make room for ``blocks`` blocks in all, an estimate of what a frame will touch, within
    :func:`frame_budget_bytes` (never an error: the frame itself is refused only when it needs more): one
    allocation instead of doubling from an empty accumulator, each doubling a copy of every block held."""
    max_blocks = frame_budget_bytes() // accumulator.bytes_per_block()
    extra = min(int(blocks), max_blocks) - len(accumulator)
    if extra > 0:
        accumulator.reserve(extra, max_blocks=max_blocks)


def cast_into(accumulator, origin, rays, t_start, t_stop, exclusive, voxel_size):
    """Cast rays from depths ``t_start`` ((R,) metres; 0: from the origin), registering the voxels they cross in the
    accumulator (grown as needed).

    Returns ``[ray_of_cell, cell_index (accumulator rows), t_in, t_out]`` as
    ``_kernels_traverse.cast_rays_into``. It reallocates the accumulator's arrays: nothing else may use
    them meanwhile.
    """
    parts, done = [], 0
    while True:
        *cells, n = _kernels_traverse.cast_rays_into(
            kernel_arrays(accumulator), origin, rays[done:], t_start[done:], t_stop[done:], exclusive[done:], voxel_size
        )
        if done:
            cells[0] += done
        parts.append(cells)
        done += n
        if done >= rays.shape[0]:
            break
        grow(accumulator, 0)
    if len(parts) == 1:
        return parts[0]
    return [np.concatenate(column) for column in zip(*parts)]


def scatter(accumulator, cell_index, increment, weight=None):
    """Add the cells' increments to their accumulator rows, each counted ``weight`` ((C,) float32) times, or once."""
    acc = accumulator.payload["acc"]
    if weight is None:
        weight = np.ones(0, dtype=np.float32)
    _kernels_accumulate.scatter(acc.reshape(-1, acc.shape[2]), cell_index, increment, weight)


def scatter_keys(accumulator, keys, increment):
    """Register voxels ``keys`` ((C, 3) int32) in the accumulator in their order, growing it as needed, and add
    each one's increment ((C,) float64) to its row. It reallocates the accumulator's arrays: nothing else may
    use them meanwhile."""
    done = 0
    while True:
        done = _kernels_accumulate.scatter_keys(kernel_arrays(accumulator), keys, increment, done)
        if done >= keys.shape[0]:
            return
        grow(accumulator, 0)
