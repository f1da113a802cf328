"""PRISM's table cache: the tables of every (measured disparity, surface rate) a model has met, packed in one
node array, least recently used ones dropped beyond a memory budget, and the keys that find them."""

import mmap
import threading
import weakref

import numpy as np

from prismap.sensor_models import _kernels_pack
from prismap.sensor_models._kernel_args import RayTables
from prismap.sensor_models._kernels_pack import _OFFSET, _STORED
from prismap.sensor_models._table_store import table_store

_LAMBDA_STEP = 0.1  # table grid in log(lambda_z): one table every ~10 % of ray norm, at its bin's centre
_KEY_L_SPAN = 1 << 16  # table key = disparity key * span + rate key
KEY_TAG_SPAN = 1 << 40
"""Table keys of models sharing one cache (a conditioned model's) are this far apart: model ``i``'s start at
``i * KEY_TAG_SPAN`` (``PrismModel._table_tag``)."""

AUTO_TABLE_CALLS = 2
"""A model with ``table_memory_mb=None`` keeps this many times the tables of its largest call."""
EVICT_TO = 0.75
"""Share of its budget a cache holds after an eviction: the least recently used tables go until it is reached, so
the next frames' tables fit without another eviction (each one copies every kept table into new memory)."""
ROOM_GROWTH = 4
"""Rows a new node array reserves, in multiples of the rows it is made for: the tables to come go in behind without
a copy of the kept ones. Rows not yet written cost address space only (a private mapping's untouched pages are
not resident), so a sequence copies a cache's tables a few times, not once a frame."""
_ROW_BYTES = np.dtype(np.float32).itemsize * _kernels_pack.TABLE_COLUMNS
_PRIVATE_MAP = {"flags": mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS} if hasattr(mmap, "MAP_PRIVATE") else {}  # not Windows


class TableCache:
    """PRISM tables packed in one node array, least recently used ones evicted beyond a memory budget.

    ``meta`` has one row per table (``_kernels_pack.META_COLUMNS``, float64: the grid's positions), ``nodes`` the
    packed rows of every table back to back (``stored`` of them from ``offset``; float32: values and slopes,
    rounded far below ``TABLE_TOLERANCE``).
    Tables used by the current call are never evicted, so one call may exceed the budget. Readers take ``nodes``
    through :meth:`view`: an eviction while none of those views lives moves the kept tables to the front of their
    room in place (no new memory, nothing copied into fresh pages); otherwise it copies them into a new room and
    the readers keep the old one. A budget of
    ``None`` is the larger of ``floor_bytes`` and :data:`AUTO_TABLE_CALLS` times the bytes of the largest
    call's tables so far (:attr:`limit_bytes`). ``hits`` and ``builds`` count the distinct keys of every call found
    in the cache and not (built, or read from the table store on disk, to which the tables an eviction drops are
    written first; a thrashing cache asks for the same keys again and again). Callers
    hold ``lock`` around :meth:`rows` and their reads of ``meta`` and ``nodes``: a build replaces them by
    longer ones (it writes new nodes only behind the rows an earlier ``nodes`` holds, into room kept for them,
    resident only once written), an eviction by new arrays with rows renumbered.
    """

    def __init__(self, budget_bytes, floor_bytes):
        self.budget_bytes = budget_bytes
        self.floor_bytes = floor_bytes
        self.largest_call_bytes = 0
        self.keys = np.empty(0, dtype=np.int64)
        self.order = np.empty(0, dtype=np.int64)  # rows by increasing key and those keys: binary search
        self.sorted_keys = self.keys
        self.meta = np.empty((0, len(_kernels_pack.META_COLUMNS)))
        self.nodes = np.empty((0, _kernels_pack.TABLE_COLUMNS), dtype=np.float32)
        self._node_room = self.nodes  # self.nodes is its head; new tables go in behind
        self._views = []  # weak references to the views of _node_room handed to readers (view)
        self.last_used = np.empty(0, dtype=np.int64)
        self.clock = 0
        self.hits = 0
        self.builds = 0
        self.lock = threading.Lock()

    def __getstate__(self):
        """The budget only: a model pickled to another process (a Dask worker) arrives with an empty cache and
        builds its tables there, once, as it meets them (they are a function of the model; shipping them would
        only cost bandwidth), and a lock does not pickle."""
        return {"budget_bytes": self.budget_bytes, "floor_bytes": self.floor_bytes}

    def __setstate__(self, state):
        self.__init__(state["budget_bytes"], state["floor_bytes"])

    @property
    def nbytes(self):
        """Bytes held by the nodes and metadata."""
        return self.nodes.nbytes + self.meta.nbytes

    def __len__(self):
        return self.keys.size

    @property
    def limit_bytes(self):
        """Bytes beyond which least recently used tables are dropped."""
        if self.budget_bytes is not None:
            return self.budget_bytes
        return max(self.floor_bytes, AUTO_TABLE_CALLS * self.largest_call_bytes)

    def _table_bytes(self, rows=slice(None)):
        """Bytes of each table of ``rows`` (default: all), its nodes and metadata row."""
        return (
            self.meta[rows, _STORED] * (self.nodes.itemsize * _kernels_pack.TABLE_COLUMNS)
            + self.meta.itemsize * self.meta.shape[1]
        )

    def rows(self, keys, build):
        """Metadata row of each (distinct) key, calling ``build(missing keys)`` for absent ones (it returns
        their ``nodes``, an array or a list of arrays read back to back, and ``meta`` rows, offsets from its first
        node: ``PrismModel._build_tables``)."""
        rows = self._find(keys)
        missing = keys[rows < 0]
        self.hits += keys.size - missing.size
        self.builds += missing.size
        if missing.size:
            nodes, meta = build(missing)
            meta[:, _OFFSET] += self.nodes.shape[0]
            first = self.keys.size
            self._append_nodes(nodes if isinstance(nodes, list) else [nodes])
            self.meta = np.concatenate([self.meta, meta])
            self.keys = np.concatenate([self.keys, missing])
            self.last_used = np.concatenate([self.last_used, np.zeros(missing.size, dtype=np.int64)])
            self._sort()
            rows[rows < 0] = first + np.arange(missing.size)
        self.clock += 1
        self.last_used[rows] = self.clock
        self.largest_call_bytes = max(self.largest_call_bytes, int(self._table_bytes(rows).sum()))
        if self.nbytes > self.limit_bytes:
            store = table_store()
            if store is not None:  # the tables it drops go to disk first, to be read back, not built, if met again
                store.flush()
            rows = self._evict(rows)
        return rows

    def view(self):
        """``meta`` and a view of ``nodes`` for a reader, who keeps the view while it reads (call under ``lock``)."""
        nodes = self._node_room[: self.nodes.shape[0]]
        self._views = [ref for ref in self._views if ref() is not None]
        self._views.append(weakref.ref(nodes))
        return self.meta, nodes

    def _append_nodes(self, parts):
        """Append the rows of the arrays ``parts``, one after another, to ``nodes``: into the room behind them (rows
        no reader indexes yet), else into a new array with room (:func:`_room_for`), so that a sequence copies its
        tables a few times, not every call."""
        n, m = self.nodes.shape[0], sum(part.shape[0] for part in parts)
        if n + m > self._node_room.shape[0]:
            room = _room_for(n + m)
            room[:n] = self.nodes
            self._node_room, self._views = room, []
        for part in parts:
            self._node_room[n : n + part.shape[0]] = part
            n += part.shape[0]
        self.nodes = self._node_room[:n]

    def _sort(self):
        self.order = np.argsort(self.keys, kind="stable")
        self.sorted_keys = self.keys[self.order]

    def _find(self, keys):
        """Row of each key, -1 where absent."""
        if not self.keys.size:
            return np.full(keys.size, -1, dtype=np.int64)
        at = np.minimum(np.searchsorted(self.sorted_keys, keys), self.keys.size - 1)
        return np.where(self.sorted_keys[at] == keys, self.order[at], -1)

    def _evict(self, rows):
        """Drop the least recently used tables (never those of ``rows``) until within :data:`EVICT_TO` of the budget;
        new rows. The kept tables move to the front of their room when no reader's view lives (:meth:`view`), else
        into a new array with room behind them (:func:`_room_for`), so that the next call's new tables do not copy
        them again."""
        size = self._table_bytes()
        order = np.argsort(self.last_used, kind="stable")
        order = order[self.last_used[order] < self.clock]
        excess = self.nbytes - EVICT_TO * self.limit_bytes
        drop = order[: np.searchsorted(np.cumsum(size[order]), excess) + 1]
        keep = np.setdiff1d(np.arange(self.keys.size), drop)
        keep = keep[np.argsort(self.meta[keep, _OFFSET], kind="stable")]  # in the order of their rows
        starts = self.meta[keep, _OFFSET].astype(np.int64)
        lengths = self.meta[keep, _STORED].astype(np.int64)
        total = int(lengths.sum())
        if all(ref() is None for ref in self._views):  # nobody reads the room: compact it
            _kernels_pack.compact_rows(self._node_room, starts, lengths)
        else:
            kept = self.nodes
            self._node_room, self._views = _room_for(total), []
            if keep.size:
                np.concatenate([kept[s : s + n] for s, n in zip(starts, lengths)], out=self._node_room[:total])
        self.nodes = self._node_room[:total]
        self.meta = self.meta[keep]
        self.meta[:, _OFFSET] = np.concatenate(([0], np.cumsum(lengths)[:-1]))
        self.keys = self.keys[keep]
        self.last_used = self.last_used[keep]
        self._sort()
        new_row = np.full(len(keep) + len(drop), -1, dtype=np.int64)
        new_row[keep] = np.arange(keep.size)
        return new_row[rows]


def _room_for(n_nodes):
    """A node array with room for :data:`ROOM_GROWTH` times ``n_nodes`` rows, for the tables to come, in memory of
    its own (a private anonymous ``mmap``), given back to the system as soon as the last view of it goes."""
    rows = ROOM_GROWTH * n_nodes
    buffer = mmap.mmap(-1, max(rows, 1) * _ROW_BYTES, **_PRIVATE_MAP)
    if hasattr(mmap, "MADV_HUGEPAGE"):  # look-ups jump across the nodes; a private mapping gets huge pages where
        # transparent_hugepage/enabled is "madvise" or "always" (a shared one only where shmem_enabled allows)
        buffer.madvise(mmap.MADV_HUGEPAGE)
    return np.frombuffer(buffer, dtype=np.float32, count=rows * _kernels_pack.TABLE_COLUMNS).reshape(
        rows, _kernels_pack.TABLE_COLUMNS
    )


def ray_tables(cache, build, disparity, norm, tag, disparity_step):
    """:class:`~prismap.sensor_models._kernel_args.RayTables` of rays of disparities ``disparity`` and norms ``norm``
    ((R,) each; keys tagged by ``tag`` (R,) int64, ``_kernels_pack.table_keys``): each one's table row in
    ``cache`` and ``delta = log(lambda_ray / lambda_table)``, ``build`` making the missing tables
    (:meth:`PrismModel._build_tables`), and the cache's ``meta`` and ``nodes`` arrays those rows index: taken under
    the cache's lock, so a call in another thread that builds or evicts (new arrays, new rows) leaves this call's
    view intact."""
    log_norm = np.log(np.maximum(norm, 1.0))
    unique, inverse, delta = _kernels_pack.table_keys(
        disparity, log_norm, tag, disparity_step, _LAMBDA_STEP, _KEY_L_SPAN
    )
    with cache.lock:
        rows = cache.rows(unique, build)
        meta, nodes = cache.view()
    return RayTables(rows[inverse], delta, meta, nodes)
