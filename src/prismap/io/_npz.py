"""Versioned ``.npz`` files read safely: every field's type, rank and size checked before anything loads.

The map file and the ground-truth occupancy file are zip archives of ``.npy`` arrays. Their headers
declare each array's dtype and shape, so a 5 MB file declaring 300 M voxels, a ``clamp`` stored as a string
or a version stored as text is refused from the headers alone, before any array is decompressed.
"""

import zipfile
from pathlib import Path

import numpy as np

from prismap._memory import check_memory
from prismap.errors import PrismapInputError

#: Field kinds: a 0-d string, a 0-d integer, a 0-d real number, or an array of a given rank.
TEXT, INTEGER, REAL = "text", "integer", "real"

_KINDS = {TEXT: "U", INTEGER: "iu", REAL: "iuf"}
_WORDS = {TEXT: "a string", INTEGER: "an integer", REAL: "a number"}


_ARRAY_KINDS = {"integer": "iu", "float": "f", "numeric": "iuf"}


def array_field(shape, element):
    """The spec of an array field: ``shape`` with None for a free axis, ``element`` "integer", "float" or "numeric"."""
    return ("array", tuple(shape), element)


def read_npz(path, what, spec, *, loaded_bytes_per_row=None):
    """Read the fields of ``spec`` from ``path`` after checking their declared dtype and shape.

    Parameters
    ----------
    path : str or Path
    what : str
        The file's role in messages (e.g. ``"map file"``).
    spec : dict
        Field name -> ``TEXT``, ``INTEGER``, ``REAL`` (0-d) or :func:`array_field`.
    loaded_bytes_per_row : float, optional
        Bytes that the caller's structures need per row of the largest array once loaded; the file is
        refused when that exceeds :func:`prismap._memory.memory_budget` (default: the arrays' own size).

    Returns
    -------
    dict
        Field name -> value: ``str``, ``int``, ``float`` for 0-d fields, ndarray for arrays.

    Raises
    ------
    PrismapInputError
        Missing, not an ``.npz`` archive, a field missing or of the wrong type or rank, or too large.
    """
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"{path}: {what} not found")
    try:
        with zipfile.ZipFile(path) as archive:
            headers = _headers(archive)
            missing = [name for name in spec if name not in headers]
            if missing:
                raise PrismapInputError(f"{path}: {what} lacks field(s) {missing}; found {sorted(headers)}")
            rows = 0
            for name, kind in spec.items():
                rows = max(rows, _check_header(path, name, kind, *headers[name]))
            nbytes = sum(int(np.prod(shape)) * dtype.itemsize for shape, dtype in (headers[n] for n in spec))
            if loaded_bytes_per_row is not None:
                nbytes = max(nbytes, rows * loaded_bytes_per_row)
            check_memory(
                nbytes,
                f"{path}: the {what}'s {rows} declared rows",
                "the file is corrupt or too large for this machine",
            )
            with np.load(path, allow_pickle=False) as data:
                arrays = {name: data[name] for name in spec}
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
        if isinstance(exc, PrismapInputError):
            raise
        raise PrismapInputError(f"{path}: not a readable .npz {what} (truncated or corrupt?): {exc}") from None
    return {name: _value(arrays[name], kind) for name, kind in spec.items()}


def _headers(archive):
    """Member name (without ``.npy``) -> (shape, dtype) from each ``.npy`` header, without reading data."""
    headers = {}
    for info in archive.infolist():
        if not info.filename.endswith(".npy"):
            continue
        with archive.open(info) as member:
            version = np.lib.format.read_magic(member)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(member)
        headers[info.filename[:-4]] = (shape, dtype)
    return headers


def _check_header(path, name, kind, shape, dtype):
    """Raise unless the declared ``shape``/``dtype`` fit ``kind``; the number of rows (0 for 0-d)."""
    if kind in _KINDS:
        if shape != () or dtype.kind not in _KINDS[kind]:
            raise PrismapInputError(
                f"{path}: `{name}` must be {_WORDS[kind]} (a 0-d array); got shape {shape}, dtype {dtype}"
            )
        return 0
    _, expected, element = kind
    if (
        len(shape) != len(expected)
        or any(e is not None and e != s for e, s in zip(expected, shape, strict=True))
        or dtype.kind not in _ARRAY_KINDS[element]
    ):
        words = "(" + ", ".join("N" if e is None else str(e) for e in expected) + (",)" if len(expected) == 1 else ")")
        raise PrismapInputError(
            f"{path}: `{name}` must be an {words} {element} array; got shape {shape}, dtype {dtype}"
        )
    return shape[0] if expected[0] is None else 0


def _value(array, kind):
    if kind == TEXT:
        return str(array)
    if kind == INTEGER:
        return int(array)
    if kind == REAL:
        return float(array)
    return array
