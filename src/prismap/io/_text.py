"""Files of the dataset readers read whole: bytes, text, calibration fields and one-pose-per-line files.

Every failure is a :class:`PrismapInputError` that starts with the file (and line and field) and then
says what was expected and what arrived; see ``docs/errors.md``.
"""

from pathlib import Path

import numpy as np

from prismap.errors import PrismapInputError


def read_bytes(path, what):
    """The bytes of ``path``; ``what`` names the file's role in messages (e.g. ``"velodyne scan"``)."""
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"{path}: {what} not found")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise PrismapInputError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None


def read_text(path, what):
    """The UTF-8 text of ``path``; ``what`` names the file's role in messages (e.g. ``"KITTI pose file"``)."""
    try:
        return read_bytes(path, what).decode("utf-8")
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
