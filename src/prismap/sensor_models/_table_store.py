"""PRISM's tables kept on disk between runs. A table is a function of its model and key alone, so a rig that maps
again with the same error model reads its tables instead of building them (a conditioned model's street frame meets
thousands of new keys). Like numba's cache it only saves time: a table read back is the one built, byte for byte,
so maps do not depend on the store.

The store is a directory (``PRISMAP_TABLE_CACHE``; default ``$XDG_CACHE_HOME/prismap/tables``, else
``~/.cache/prismap/tables``; ``off`` or ``0`` turns it off) of segment files, each written whole under a temporary
name and renamed, so that processes mapping at once (Dask workers) share it without locks. A table is found by
its model's fingerprint (:func:`model_fingerprint`: the kernels' sources and every parameter its tables depend on)
and its key, and taken only when its rate and shift equal the caller's; anything else (another version,
a truncated or foreign file) is built again. Segments are mapped read-only and their pages let go after each read
(they would count in the process's resident memory). Writing stops once the directory holds
:data:`STORE_BUDGET_BYTES`.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import mmap
import os
import threading
import uuid
from pathlib import Path

import numpy as np

from prismap.sensor_models import _kernels_pack
from prismap.sensor_models._kernels_pack import _LAM, _OFFSET, _SHIFT, _STORED

STORE_ENV = "PRISMAP_TABLE_CACHE"
"""Environment variable naming the store's directory; ``off`` or ``0`` (or empty) turns the store off."""
STORE_BUDGET_BYTES = 1 << 30
"""Bytes of segments beyond which a store writes no more (delete the directory to start again)."""
FLUSH_BYTES = 8 << 20
"""Bytes of new tables a process holds before it writes them as one segment (and when it exits)."""
_MAGIC = b"PRISMAPT"
_VERSION = 1
_HEADER = np.dtype([("magic", "S8"), ("version", "<i8"), ("tables", "<i8"), ("meta_columns", "<i8"), ("rows", "<i8")])
_META_COLUMNS = len(_kernels_pack.META_COLUMNS)
_NODE_BYTES = np.dtype(np.float32).itemsize * _kernels_pack.TABLE_COLUMNS
_KERNEL_SOURCES = ("_kernel_args.py", *(p.name for p in Path(__file__).parent.glob("_kernels_*.py")))


def store_directory() -> Path | None:
    """The store's directory from ``PRISMAP_TABLE_CACHE`` and the XDG convention, or None when it is off."""
    value = os.environ.get(STORE_ENV)
    if value is not None:
        value = value.strip()
        return None if value.lower() in ("", "0", "off") else Path(value).expanduser()
    base = os.environ.get("XDG_CACHE_HOME")
    if not base:
        try:
            base = Path.home() / ".cache"
        except (RuntimeError, KeyError):  # no home directory to be found: no store
            return None
    return Path(base) / "prismap" / "tables"


_SOURCE_DIGEST = None


def _source_digest():
    """sha256 of the sources of the kernels that build tables (a changed kernel finds none of the old tables), or of
    prismap's version where they are not on disk."""
    global _SOURCE_DIGEST
    if _SOURCE_DIGEST is None:
        digest = hashlib.sha256(str(_VERSION).encode())
        try:
            for name in sorted(_KERNEL_SOURCES):
                digest.update(name.encode())
                digest.update((Path(__file__).parent / name).read_bytes())
        except OSError:
            from prismap import __version__

            digest.update(f"prismap {__version__}".encode())
        _SOURCE_DIGEST = digest.digest()
    return _SOURCE_DIGEST


def model_fingerprint(geometry, spec, mixture, key_inputs, error_model):
    """64-bit fingerprint of what every table of a model shares: ``_kernels_pack.prism_tables``' ``geometry``,
    ``spec`` and ``mixture``, the numbers that turn a key into a table's inputs (``key_inputs``: rate, shift and
    grid steps), the error model (its far density and failure part; a ``to_dict`` form) and the kernels' sources."""
    digest = hashlib.sha256(_source_digest())
    for part in (*geometry, *spec, *mixture, *key_inputs):
        digest.update(np.ascontiguousarray(part, dtype=np.float64).tobytes())
    digest.update(json.dumps(error_model, sort_keys=True).encode())
    return int.from_bytes(digest.digest()[:8], "little", signed=True)


class _Segment:
    """One segment file, mapped read-only: its fingerprints and keys copied out, meta rows and nodes read on demand."""

    def __init__(self, path):
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size < _HEADER.itemsize:
                raise ValueError("truncated")
            self._map = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        header = np.frombuffer(self._map, dtype=_HEADER, count=1)
        if header["magic"][0] != _MAGIC or header["version"][0] != _VERSION:
            raise ValueError("not a table segment of this version")
        n, columns, rows = (int(header[name][0]) for name in ("tables", "meta_columns", "rows"))
        meta_at = _HEADER.itemsize + 16 * n
        nodes_at = meta_at + 8 * columns * n
        if columns != _META_COLUMNS or n < 0 or rows < 0 or size != nodes_at + _NODE_BYTES * rows:
            raise ValueError("another table layout, or truncated")
        ids = np.frombuffer(self._map, dtype="<i8", count=2 * n, offset=_HEADER.itemsize).copy()
        self.fingerprints, self.keys = ids[:n], ids[n:]
        self.meta = np.frombuffer(self._map, dtype="<f8", count=columns * n, offset=meta_at).reshape(n, columns)
        self.nodes = np.frombuffer(
            self._map, dtype="<f4", count=rows * _kernels_pack.TABLE_COLUMNS, offset=nodes_at
        ).reshape(rows, _kernels_pack.TABLE_COLUMNS)

    def read(self, rows, lam, shift):
        """The tables at ``rows`` whose rate and shift equal ``lam`` and ``shift`` (each
        ``rows``' size) and whose nodes lie in the file: ``(ok, meta, nodes)``, ``meta`` the ok ones' rows with
        offsets into ``nodes``, copies; the mapping's pages are then let go (they would count in the process's
        resident memory)."""
        meta = self.meta[rows]
        start, stored = meta[:, _OFFSET].astype(np.int64), meta[:, _STORED].astype(np.int64)
        ok = (stored > 0) & (start >= 0) & (start + stored <= self.nodes.shape[0])
        ok &= (meta[:, _LAM] == lam) & (meta[:, _SHIFT] == shift)
        meta, start, stored = meta[ok], start[ok], stored[ok]
        first = np.concatenate(([0], np.cumsum(stored)))
        nodes = self.nodes[np.repeat(start - first[:-1], stored) + np.arange(first[-1])]
        meta[:, _OFFSET] = first[:-1]
        if hasattr(mmap, "MADV_DONTNEED"):
            self._map.madvise(mmap.MADV_DONTNEED)
        return ok, meta, nodes


_EMPTY_INDEX = (np.empty(0, np.int64), np.empty(0, dtype=object), np.empty(0, np.int64))


class TableStore:
    """The segments of one store directory, indexed by (fingerprint, key), and the tables this process has built
    and not yet written; ``found`` and ``written`` count the tables this process has read and written. Thread-safe."""

    def __init__(self, directory: str | os.PathLike) -> None:
        self.directory = Path(directory)
        self._segments = {}  # file name -> _Segment
        self._index = {}  # fingerprint -> (sorted keys, their segment names, their rows in the segment)
        self._pending = []  # (fingerprint, keys, nodes, meta) built since the last write
        self._pending_bytes = 0
        self._seen = None  # the directory's mtime at the last scan
        self._full = False
        self._lock = threading.Lock()
        self.found = self.written = 0

    def fetch(
        self, fingerprint: int, keys: np.ndarray, lam: np.ndarray, shift: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The stored tables of ``keys`` ((K,) int64) of the model ``fingerprint`` whose rate and shift equal ``lam``
        and ``shift`` ((K,) float64 each; the far density, a function of the shift and the error model, comes with
        the fingerprint): ``(found (K,) bool, nodes, meta)``, ``nodes`` a list of arrays read back to back (as
        ``TableCache.rows`` takes them: no copy here), ``meta`` the found tables' rows in the order of ``keys``,
        offsets into those rows."""
        with self._lock:
            self._scan()
            sorted_keys, names, rows = self._index.get(fingerprint, _EMPTY_INDEX)
            if not sorted_keys.size:
                return np.zeros(keys.size, dtype=bool), [], np.empty((0, _META_COLUMNS))
            at = np.minimum(np.searchsorted(sorted_keys, keys), sorted_keys.size - 1)
            found = sorted_keys[at] == keys
            candidates = np.flatnonzero(found)
            where = names[at[candidates]]
            metas, parts, first, order = [], [], 0, []
            for name in sorted(set(where)):  # a fixed order: the same layout every run
                mine = candidates[where == name]
                ok, meta, nodes = self._segments[name].read(rows[at[mine]], lam[mine], shift[mine])
                found[mine[~ok]] = False  # a colliding fingerprint's, or out of the file: built again
                meta[:, _OFFSET] += first
                first += nodes.shape[0]
                metas.append(meta)
                parts.append(nodes)
                order.append(mine[ok])
            if not metas:
                return found, [], np.empty((0, _META_COLUMNS))
            rank = np.argsort(np.concatenate(order), kind="stable")  # the found tables in the order of keys
            self.found += rank.size
            return found, parts, np.concatenate(metas)[rank]

    def add(self, fingerprint: int, keys: np.ndarray, nodes: np.ndarray | list[np.ndarray], meta: np.ndarray) -> None:
        """Hold newly built tables (``nodes`` an array or a list read back to back, ``meta`` with offsets into them)
        for the next write, and write when :data:`FLUSH_BYTES` are held."""
        parts = nodes if isinstance(nodes, list) else [nodes]
        with self._lock:
            if self._full or not keys.size:
                return
            self._pending.append((fingerprint, np.array(keys, np.int64), [np.array(p) for p in parts], meta.copy()))
            self._pending_bytes += sum(p.nbytes for p in parts) + meta.nbytes
            if self._pending_bytes >= FLUSH_BYTES:
                self._write()

    def flush(self) -> None:
        """Write the held tables as one segment."""
        with self._lock:
            self._write()

    def _write(self):
        """Write the held tables as one segment, under a temporary name then renamed (readers never see a part of
        one); past the budget, or where the directory cannot be written, hold and write no more."""
        pending, self._pending, self._pending_bytes = self._pending, [], 0
        if not pending or self._full:
            return
        fingerprints = np.concatenate([np.full(keys.size, fp, np.int64) for fp, keys, _, _ in pending])
        keys = np.concatenate([keys for _, keys, _, _ in pending])
        metas, first = [], 0
        for _, _, parts, meta in pending:
            meta = meta.copy()
            meta[:, _OFFSET] += first
            metas.append(meta)
            first += sum(p.shape[0] for p in parts)
        header = np.array([(_MAGIC, _VERSION, keys.size, _META_COLUMNS, first)], dtype=_HEADER)
        total = header.nbytes + 16 * keys.size + sum(m.nbytes for m in metas) + first * _NODE_BYTES
        if self._stored_bytes() + total > STORE_BUDGET_BYTES:
            self._full = True
            return
        name = f"seg-{uuid.uuid4().hex}.bin"
        temporary = self.directory / f".{name}.tmp"
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            with open(temporary, "wb") as f:
                for block in (header, fingerprints, keys, *metas):
                    f.write(np.ascontiguousarray(block).tobytes())
                for _, _, parts, _ in pending:
                    for part in parts:
                        f.write(np.ascontiguousarray(part, dtype=np.float32).tobytes())
            os.replace(temporary, self.directory / name)
            self.written += keys.size
        except OSError:  # a read-only or full disk, or no directory there: the tables are built again next time
            self._full = True
            with contextlib.suppress(OSError):
                temporary.unlink(missing_ok=True)

    def _stored_bytes(self):
        """Bytes of the directory's files (segments of every process, and their temporaries)."""
        total = 0
        try:
            for entry in os.scandir(self.directory):
                try:
                    total += entry.stat().st_size
                except OSError:  # renamed or removed meanwhile
                    continue
        except OSError:
            return 0
        return total

    def _scan(self):
        """Open the segments written since the last scan (by any process) and index them."""
        try:
            seen = os.stat(self.directory).st_mtime_ns
        except OSError:
            return
        if seen == self._seen:
            return
        self._seen = seen
        new = []
        try:
            entries = list(os.scandir(self.directory))
        except OSError:  # not a directory: nothing to read
            return
        for entry in entries:
            if entry.name.startswith("seg-") and entry.name.endswith(".bin") and entry.name not in self._segments:
                try:
                    self._segments[entry.name] = segment = _Segment(entry.path)
                except (OSError, ValueError):  # foreign, truncated or of another version: ignored
                    continue
                new.append((entry.name, segment))
        for fingerprint in {int(fp) for _, segment in new for fp in np.unique(segment.fingerprints)}:
            keys, names, rows = self._index.get(fingerprint, _EMPTY_INDEX)
            for name, segment in new:
                mine = np.flatnonzero(segment.fingerprints == fingerprint)
                keys = np.concatenate([keys, segment.keys[mine]])
                names = np.concatenate([names, np.full(mine.size, name, dtype=object)])
                rows = np.concatenate([rows, mine])
            order = np.argsort(keys, kind="stable")
            self._index[fingerprint] = (keys[order], names[order], rows[order])


_STORES: dict = {}
_STORES_LOCK = threading.Lock()


def table_store() -> TableStore | None:
    """The :class:`TableStore` of the directory :func:`store_directory` names (one per process), or None when off."""
    directory = store_directory()
    if directory is None:
        return None
    with _STORES_LOCK:
        key = (os.getpid(), directory)
        if key not in _STORES:
            _STORES[key] = TableStore(directory)
        return _STORES[key]


def flush_table_stores() -> None:
    """Write the PRISM tables this process has built and not yet stored (done at exit, and after each run of
    ``pipeline.integrate_frames``: a sequence, or a Dask worker's chunk)."""
    with _STORES_LOCK:
        stores = [store for (pid, _), store in _STORES.items() if pid == os.getpid()]
    for store in stores:
        store.flush()


atexit.register(flush_table_stores)
