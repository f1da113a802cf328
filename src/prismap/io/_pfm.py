"""Portable float map (PFM) files, as Middlebury stores ground-truth disparities.

Format: a text header ``Pf`` (one channel) or ``PF`` (three), ``width height``, and a scale whose
sign gives the byte order (negative = little-endian), each on its own line; then float32 samples
with the rows stored bottom to top. Middlebury marks unknown disparities with ``+inf``.
"""

from __future__ import annotations

import os

import numpy as np
import numpy.typing as npt

from prismap._files import atomic_path
from prismap.errors import PrismapInputError
from prismap.io._images import check_image_pixels
from prismap.io._text import read_bytes

HEADER_BYTES = 256
"""Bytes a PFM header fits in (three short lines)."""


def read_pfm(path: str | os.PathLike[str]) -> npt.NDArray[np.float32]:
    """Read a PFM file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    array : (H, W) or (H, W, 3) float32
        Rows top to bottom, native byte order; infinities (Middlebury: unknown) are kept.
    """
    raw = read_bytes(path, "PFM file", max_bytes=_byte_bound(path), bound="its header's size")
    header, offset = _header(raw)
    if len(header) < 4 or header[0] not in (b"Pf", b"PF"):
        raise PrismapInputError(f"{path}: not a PFM file (expected a 'Pf' or 'PF' header); got {raw[:16]!r}")
    channels = 1 if header[0] == b"Pf" else 3
    try:
        width, height, scale = int(header[1]), int(header[2]), float(header[3])
    except ValueError:
        raise PrismapInputError(f"{path}: PFM header must hold width, height and scale; got {raw[:40]!r}") from None
    if width <= 0 or height <= 0 or scale == 0 or not np.isfinite(scale):
        raise PrismapInputError(f"{path}: PFM header needs a positive size and a non-zero scale; got {raw[:40]!r}")
    dtype = np.dtype("<f4" if scale < 0 else ">f4")
    expected = width * height * channels * 4
    if len(raw) - offset < expected:
        raise PrismapInputError(
            f"{path}: PFM data truncated: {width}x{height}x{channels} float32 needs {expected} bytes; "
            f"got {len(raw) - offset}"
        )
    data = np.frombuffer(raw, dtype=dtype, count=width * height * channels, offset=offset)
    shape = (height, width) if channels == 1 else (height, width, 3)
    return np.flipud(data.reshape(shape)).astype(np.float32)


def write_pfm(path: str | os.PathLike[str], array: npt.ArrayLike) -> None:
    """Write a PFM file (little-endian, scale -1), atomically.

    Parameters
    ----------
    path : str or Path
    array : (H, W) or (H, W, 3) float
        Rows top to bottom. NaN is written as ``+inf``, Middlebury's marker for unknown.
    """
    data = np.asarray(array)
    if data.ndim not in (2, 3) or (data.ndim == 3 and data.shape[2] != 3) or data.size == 0:
        raise PrismapInputError(f"`array` must be a non-empty (H, W) or (H, W, 3) map; got shape {data.shape}")
    if not np.issubdtype(data.dtype, np.number):
        raise PrismapInputError(f"`array` must be numeric; got dtype {data.dtype}")
    data = data.astype("<f4")
    data[np.isnan(data)] = np.inf
    magic = b"Pf" if data.ndim == 2 else b"PF"
    header = magic + b"\n%d %d\n-1\n" % (data.shape[1], data.shape[0])
    with atomic_path(path) as tmp:
        tmp.write_bytes(header + np.ascontiguousarray(np.flipud(data)).tobytes())


def _byte_bound(path):
    """The most bytes a PFM may hold: its header (read alone first), the samples it declares and
    :data:`HEADER_BYTES` of trailing slack."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(HEADER_BYTES)
    except OSError:
        return HEADER_BYTES  # read_bytes names the problem
    header, offset = _header(head)
    try:
        width, height = int(header[1]), int(header[2])
    except (IndexError, ValueError):
        return HEADER_BYTES  # refused with the header's message once read
    channels = 3 if header[0] == b"PF" else 1
    check_image_pixels(path, "PFM file", width, height)
    return HEADER_BYTES + offset + max(width, 0) * max(height, 0) * channels * 4


def _header(raw):
    """The first four whitespace-separated tokens, and the offset just past the one byte ending them."""
    tokens, position = [], 0
    while len(tokens) < 4 and position < len(raw):
        while position < len(raw) and raw[position : position + 1].isspace():
            position += 1
        end = position
        while end < len(raw) and not raw[end : end + 1].isspace():
            end += 1
        if end > position:
            tokens.append(raw[position:end])
        position = end
    return tokens, position + 1
