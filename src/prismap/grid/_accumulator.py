"""The frame accumulator: per voxel a frame touches, ``(sum, count, max, min)`` of its increments.

A :class:`~prismap.grid._storage.BlockTable` of the map's block shape whose blocks also link to their six
face neighbours. Its size is bounded (:data:`MAX_FRAME_BYTES`): a frame that would touch more blocks is
refused with an error naming what to change, instead of exhausting memory.
"""

import numpy as np

from prismap.errors import PrismapInputError
from prismap.grid import _kernels_accumulate, _kernels_traverse
from prismap.grid._storage import BlockTable

MAX_FRAME_BYTES = 2 << 30
"""Memory the frame accumulator may hold (bytes): about 2 M blocks of 4^3 voxels, 128 M voxels in 3-D."""


def new_accumulator(bits):
    """An empty frame accumulator for blocks of ``bits`` (see :mod:`prismap.grid._keys`): per voxel
    ``(sum, count, max, min)`` of its increments, float32, and per block the slots of its six face
    neighbours (``links``, see ``_kernels_traverse.cast_hit_miss``)."""
    return BlockTable(bits, {"acc": ((1 << sum(bits), 4), np.float32), "links": ((6,), np.int32)})


def grow(accumulator, blocks):
    """Make room for ``blocks`` more blocks (at least 64, or as many as held), within :data:`MAX_FRAME_BYTES`."""
    extra = max(64, len(accumulator), int(blocks))
    per_block = sum(a.itemsize * int(np.prod(a.shape[1:])) for a in accumulator.payload.values()) + 8 + 8
    if (len(accumulator) + extra) * per_block > MAX_FRAME_BYTES:
        extra = max(int(blocks), MAX_FRAME_BYTES // per_block - len(accumulator))
        if extra <= 0 or (len(accumulator) + extra) * per_block > MAX_FRAME_BYTES:
            raise PrismapInputError(
                f"one frame touches more than {MAX_FRAME_BYTES // per_block} voxel blocks ({MAX_FRAME_BYTES >> 30} GiB, "
                "the frame accumulator's bound; docs/errors.md): lower `max_range_m`, raise `voxel_size_m`, or "
                "subsample the rays"
            )
    accumulator.reserve(extra)


def register_cells(accumulator, keys):
    """(C,) int64 accumulator row of each voxel key, adding blocks and growing the accumulator as needed."""
    rows = np.empty(keys.shape[0], dtype=np.int64)
    start = 0
    while True:
        table = accumulator
        start = _kernels_accumulate.register_keys(table.table, table.block_keys, table.n_blocks, table.payload["acc"],
                                                  table.payload["links"], keys, start, table.bits, rows)
        if start == keys.shape[0]:
            return rows
        grow(accumulator, 0)


def cast_into(accumulator, origin, rays, t_stop, exclusive, voxel_size, *, grow_room=True):
    """Cast rays, registering the voxels they cross in the accumulator.

    Returns ``[ray_of_cell, cell_index (accumulator rows), t_in, t_out]`` as
    ``_kernels_traverse.cast_rays_into``, and how many rays are done. With ``grow_room=False`` it never
    reallocates the accumulator (safe beside a :func:`scatter` into it in another thread) and may stop
    short; call :func:`finish_cast` afterwards.
    """
    table = accumulator
    *cells, done = _kernels_traverse.cast_rays_into(table.table, table.block_keys, table.n_blocks, table.payload["acc"],
                                                    table.payload["links"], origin, rays, t_stop, exclusive, voxel_size,
                                                    table.bits)
    if grow_room:
        return finish_cast(accumulator, origin, rays, t_stop, exclusive, voxel_size, (cells, done))
    return cells, done


def finish_cast(accumulator, origin, rays, t_stop, exclusive, voxel_size, partial):
    """Complete a :func:`cast_into` that stopped short, growing the accumulator; returns the cells."""
    cells, done = partial
    parts = [cells]
    while done < rays.shape[0]:
        grow(accumulator, 0)
        more, n = cast_into(accumulator, origin, rays[done:], t_stop[done:], exclusive[done:], voxel_size,
                            grow_room=False)
        more[0] += done
        parts.append(more)
        done += n
    if len(parts) == 1:
        return cells
    return [np.concatenate(column) for column in zip(*parts)]


def scatter(accumulator, cell_index, increment):
    """Add the cells' increments to their accumulator rows."""
    acc = accumulator.payload["acc"]
    _kernels_accumulate.scatter(acc.reshape(-1, acc.shape[2]), cell_index, increment)
