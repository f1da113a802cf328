"""Files of the dataset readers read whole: bytes, text, calibration fields and one-pose-per-line files.

Every failure is a :class:`PrismapInputError` that starts with the file (and line and field) and then
says what was expected and what arrived; see ``docs/errors.md``.
"""

from pathlib import Path

import numpy as np

from prismap.errors import PrismapInputError

MAX_READ_BYTES = 256 << 20
"""Largest binary file read whole (bytes) unless its reader bounds it from its header (PNG, PFM)."""
MAX_TEXT_BYTES = 64 << 20
"""Largest text file read whole (bytes): calibrations, pose and track files, error models (64 MiB holds
about 400,000 KITTI pose lines)."""


def file_size(path, what):
    """Size of ``path`` in bytes, or a not-found / cannot-read message naming ``what``."""
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"{path}: {what} not found")
    try:
        return path.stat().st_size
    except OSError as exc:
        raise PrismapInputError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None


def check_size(path, what, size, max_bytes, bound="MAX_READ_BYTES"):
    """Refuse a file of ``size`` bytes above ``max_bytes``, before it is read (``bound`` names the limit)."""
    if size > max_bytes:
        raise PrismapInputError(
            f"{path}: {what} holds {size} bytes, more than the limit of {max_bytes} bytes ({bound})"
        )


def read_bytes(path, what, *, max_bytes=MAX_READ_BYTES, bound="MAX_READ_BYTES"):
    """The bytes of ``path``; ``what`` names the file's role in messages (e.g. ``"velodyne scan"``).

    A file of more than ``max_bytes`` is refused from its size before any byte is read (a sparse file of
    gigabytes would otherwise exhaust memory); ``bound`` names that limit in the message.
    """
    path = Path(path)
    check_size(path, what, file_size(path, what), max_bytes, bound)
    try:
        with open(path, "rb") as handle:
            data = handle.read(max_bytes + 1)
    except OSError as exc:
        raise PrismapInputError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    check_size(path, what, len(data), max_bytes, bound)  # the file grew meanwhile
    return data


def read_text(path, what):
    """The UTF-8 text of ``path`` (at most :data:`MAX_TEXT_BYTES`); ``what`` names the file's role in messages."""
    try:
        return read_bytes(path, what, max_bytes=MAX_TEXT_BYTES, bound="MAX_TEXT_BYTES").decode("utf-8")
    except UnicodeDecodeError as exc:
        raise PrismapInputError(f"{path}: {what} is not UTF-8 text (byte {exc.start})") from None


def location(path, line_no, field=None):
    """``"<path> line <n>[, field <name>]"``, the prefix of every message about one value."""
    return f"{path} line {line_no}" + (f", field {field}" if field else "")


def parse_numbers(text, path, line_no, field=None):
    """The whitespace-separated numbers of ``text``, which must all be finite.

    Parameters
    ----------
    text : str
        One field or line of a text file.
    path : str or Path
    line_no : int
        1-based line of ``text`` in ``path``, for messages.
    field : str, optional
        Name of the field, for messages.

    Returns
    -------
    (K,) float64
    """
    where, shown = location(path, line_no, field), text.strip()[:60]
    try:
        values = np.array([float(token) for token in text.split()], dtype=np.float64)
    except ValueError:
        raise PrismapInputError(f"{where}: expected numbers; got {shown!r}") from None
    if not np.all(np.isfinite(values)):
        raise PrismapInputError(f"{where}: numbers must be finite; got {shown!r}")
    return values


def read_number_rows(path, what, count, *, layout, commas=False):
    """A text file of one row of ``count`` finite numbers per line (pose and track files).

    Parameters
    ----------
    path : str or Path
    what : str
        The file's role in messages.
    count : int
        Numbers per line.
    layout : str
        What a line holds, for messages (e.g. ``"3x4 pose"``).
    commas : bool, keyword-only
        Accept commas as separators too.

    Returns
    -------
    (N, count) float64
        Rows in file order. Trailing blank lines are ignored; a blank line inside the file is an error.
    """
    path = Path(path)
    lines = read_text(path, what).rstrip().splitlines()
    if not lines:
        raise PrismapInputError(f"{path}: {what} is empty")
    rows = np.empty((len(lines), count))
    for index, line in enumerate(lines):
        values = parse_numbers(line.replace(",", " ") if commas else line, path, index + 1)
        if values.size != count:
            raise PrismapInputError(f"{path} line {index + 1}: expected {count} numbers ({layout}); got {values.size}")
        rows[index] = values
    return rows


def homogeneous(top_rows):
    """``[R | t]`` blocks, shape (..., 3, 4), completed to (..., 4, 4) transforms with last row (0, 0, 0, 1)."""
    top_rows = np.asarray(top_rows, dtype=np.float64)
    T = np.zeros(top_rows.shape[:-2] + (4, 4))
    T[..., :3, :] = top_rows
    T[..., 3, 3] = 1.0
    return T
