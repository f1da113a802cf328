"""PNG images and disparity maps of the dataset readers, read with OpenCV.

OpenCV's ``imread`` returns ``None`` for a missing, foreign or corrupt file and hands back BGR; these
helpers turn both into the reader conventions: a :class:`PrismapInputError` that names the file and
its role, and RGB channel order.
"""

from __future__ import annotations

import dataclasses
import os
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from prismap._files import atomic_path
from prismap._memory import check_memory
from prismap.errors import PrismapInputError
from prismap.io._text import read_bytes

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Most pixels an image may declare (16384 x 8192): a PNG of a few hundred KB can declare 20000 x 20000.
MAX_IMAGE_PIXELS = 2**27


def read_png(path, what, flags=cv2.IMREAD_UNCHANGED):
    """Decode a PNG with ``cv2.imdecode(data, flags)``; channels stay in OpenCV's BGR(A) order.

    Before decoding, the file's chunk structure is checked (:func:`_png_header`): a truncated or corrupt
    file is refused with one message (libpng never gets to print its own), and so is an image whose
    declared size exceeds :data:`MAX_IMAGE_PIXELS` or the memory budget, which a small file can declare.

    Parameters
    ----------
    path : str or Path
    what : str
        The file's role in messages (e.g. ``"left image"``).
    flags : int
        OpenCV ``IMREAD_*`` flags.

    Returns
    -------
    (H, W) or (H, W, C) ndarray
    """
    path = Path(path)
    data = read_bytes(path, what, max_bytes=_png_byte_bound(path, what), bound="its header's pixels")
    height, width, bytes_per_pixel = _png_header(data, path, what)
    check_memory(width * height * bytes_per_pixel, f"{path}: decoding the {width}x{height} {what}")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if image is None:
        raise PrismapInputError(f"{path}: {what} cannot be decoded (truncated or corrupt PNG)")
    return image


def check_image_pixels(path, what, width, height):
    """Refuse an image that declares more than :data:`MAX_IMAGE_PIXELS` (every image source, before decoding)."""
    if width * height > MAX_IMAGE_PIXELS:
        raise PrismapInputError(
            f"{path}: {what} declares {width}x{height} pixels, more than the limit of "
            f"{MAX_IMAGE_PIXELS} pixels (MAX_IMAGE_PIXELS)"
        )


PNG_SLACK_BYTES = 1 << 20
"""Bytes a PNG may hold beyond its compressed pixels (ancillary chunks: text, colour profiles)."""


def png_max_bytes(width, height, bit_depth, colour_type):
    """Most bytes a PNG of this header needs: its filtered rows stored uncompressed (deflate's worst case adds
    5 bytes per 64 KiB block) plus :data:`PNG_SLACK_BYTES`."""
    samples = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}.get(colour_type, 4)
    raw = height * (1 + (width * samples * max(bit_depth, 1) + 7) // 8)
    return raw + raw // 1024 + PNG_SLACK_BYTES


def _png_byte_bound(path, what):
    """The size :func:`read_png` reads of ``path`` at most, from its IHDR before the rest is read."""
    if not path.is_file():
        raise PrismapInputError(f"{path}: {what} not found")
    try:
        with open(path, "rb") as handle:
            head = handle.read(len(PNG_SIGNATURE) + 8 + 13)
    except OSError as exc:
        raise PrismapInputError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None
    if len(head) < 29 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        return PNG_SLACK_BYTES  # refused by _png_header once read
    width, height, bit_depth, colour_type = struct.unpack(">IIBB", head[16:26])
    check_image_pixels(path, what, width, height)
    return png_max_bytes(width, height, bit_depth, colour_type)


_PNG_BIT_DEPTHS = {0: (1, 2, 4, 8, 16), 2: (8, 16), 3: (1, 2, 4, 8), 4: (8, 16), 6: (8, 16)}
"""Bit depths the PNG specification allows per colour type (libpng refuses the rest, printing a line)."""
_PNG_SAMPLES = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))
"""Interlaced PNG passes: (x start, y start, x step, y step)."""


def _png_header(data, path, what):
    """``(height, width, decoded bytes per pixel)`` of the PNG ``data``, after checking it whole.

    Every chunk's length and CRC, one IHDR first with values the specification allows, the pixel bound
    (:func:`check_image_pixels`), and the IDAT stream: it must inflate (streamed, never held) to exactly the
    filtered rows the header declares. libpng prints a line of its own on each of these faults, so they are
    refused here first.
    """
    if data[: len(PNG_SIGNATURE)] != PNG_SIGNATURE:
        raise PrismapInputError(f"{path}: {what} is not a PNG file (wrong signature)")
    corrupt = f"{path}: {what} cannot be decoded (truncated or corrupt PNG"
    offset, headers, idat, ended = len(PNG_SIGNATURE), [], [], False
    while offset + 12 <= len(data) and not ended:
        length, kind = struct.unpack(">I4s", data[offset : offset + 8])
        end = offset + 12 + length
        if end > len(data) or zlib.crc32(data[offset + 4 : end - 4]) != struct.unpack(">I", data[end - 4 : end])[0]:
            break
        if kind == b"IHDR":
            headers.append((offset, data[offset + 8 : end - 4]))
        elif kind == b"IDAT":
            idat.append((offset + 8, end - 4))
        ended = kind == b"IEND"
        offset = end
    if not headers or not ended:
        raise PrismapInputError(corrupt + ")")
    if len(headers) > 1 or headers[0][0] != len(PNG_SIGNATURE) or len(headers[0][1]) != 13:
        raise PrismapInputError(corrupt + ": IHDR must be the first chunk, once, of 13 bytes)")
    width, height, bit_depth, colour_type, compression, filtering, interlace = struct.unpack(">IIBBBBB", headers[0][1])
    if (
        bit_depth not in _PNG_BIT_DEPTHS.get(colour_type, ())
        or compression
        or filtering
        or interlace > 1
        or not width
        or not height
    ):
        raise PrismapInputError(
            corrupt + f": IHDR declares {width}x{height}, bit depth {bit_depth}, colour type "
            f"{colour_type}, methods {compression}/{filtering}/{interlace})"
        )
    check_image_pixels(path, what, width, height)
    _check_idat(data, idat, _png_raw_bytes(width, height, bit_depth * _PNG_SAMPLES[colour_type], interlace), corrupt)
    channels = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}[colour_type]
    return height, width, channels * (2 if bit_depth == 16 else 1)


def _png_raw_bytes(width, height, bits_per_pixel, interlace):
    """Bytes of the filtered rows (a filter byte and the packed pixels per row) of a PNG, over its passes."""
    passes = _ADAM7 if interlace else ((0, 0, 1, 1),)
    total = 0
    for x0, y0, dx, dy in passes:
        columns, rows = (width - x0 + dx - 1) // dx, (height - y0 + dy - 1) // dy
        if columns > 0 and rows > 0:
            total += rows * (1 + (columns * bits_per_pixel + 7) // 8)
    return total


def _check_idat(data, pieces, expected, corrupt):
    """The IDAT ``pieces`` ((start, end) in ``data``) must inflate to exactly ``expected`` bytes, in blocks."""
    inflate, produced = zlib.decompressobj(), 0
    try:
        for start, end in pieces:
            chunk = data[start:end]
            while chunk and produced <= expected:
                produced += len(inflate.decompress(chunk, 1 << 20))
                chunk = inflate.unconsumed_tail
        while not inflate.eof and produced <= expected:
            block = inflate.decompress(b"", 1 << 20)
            if not block:
                break
            produced += len(block)
    except zlib.error:
        raise PrismapInputError(corrupt + ": bad compressed data)") from None
    if produced != expected or not inflate.eof:
        raise PrismapInputError(corrupt + f": the pixel data holds {produced} bytes, the header needs {expected})")


_JPEG_FRAME_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
"""JPEG start-of-frame markers (SOF0-SOF15 but DHT, JPG and DAC), whose segment holds the image size."""


def _jpeg_header(data, where):
    """``(height, width, components)`` from a JPEG's start-of-frame segment, or a message naming ``where``."""
    offset = 2
    while offset + 4 <= len(data):
        if data[offset] != 0xFF:
            break
        marker = data[offset + 1]
        if marker == 0xFF:
            offset += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            offset += 2
            continue
        length = struct.unpack(">H", data[offset + 2 : offset + 4])[0]
        if marker in _JPEG_FRAME_MARKERS and offset + 10 <= len(data) and length >= 8:
            height, width, components = struct.unpack(">HHB", data[offset + 5 : offset + 10])
            return height, width, components
        if marker == 0xDA or length < 2:
            break
        offset += 2 + length
    raise PrismapInputError(f"{where} cannot be decoded (a JPEG without a readable frame header)")


def check_encoded_image(data, where):
    """Check a PNG or JPEG held in memory (a bag's CompressedImage) before it is decoded.

    Its declared size must be within :data:`MAX_IMAGE_PIXELS` and the memory budget, as for image files;
    a PNG's chunks are checked too (libpng then never prints its own message). Other formats are refused.

    Returns
    -------
    (height, width) : pixels
    """
    data = bytes(data)
    if data[: len(PNG_SIGNATURE)] == PNG_SIGNATURE:
        height, width, bytes_per_pixel = _png_header(data, where, "compressed image")
    elif data[:3] == b"\xff\xd8\xff":
        height, width, components = _jpeg_header(data, where)
        bytes_per_pixel = max(components, 1)
    else:
        raise PrismapInputError(f"{where}: compressed image is neither PNG nor JPEG (starts {data[:8]!r})")
    check_image_pixels(where, "compressed image", width, height)
    check_memory(width * height * bytes_per_pixel, f"{where}: decoding the {width}x{height} compressed image")
    return height, width


def read_image(path, what, *, colour):
    """An 8-bit PNG image in RGB order.

    Parameters
    ----------
    path : str or Path
    what : str
        The file's role in messages.
    colour : bool, keyword-only
        True: always (H, W, 3), grey files repeated and 16-bit files scaled to 8 bits by OpenCV
        (KITTI, New Tsukuba). False: as stored, grey (H, W) or RGB (H, W, 3) (alpha dropped), and
        the file must be 8-bit (Middlebury, sequences).

    Returns
    -------
    (H, W, 3) or (H, W) uint8
    """
    image = read_png(path, what, cv2.IMREAD_COLOR if colour else cv2.IMREAD_UNCHANGED)
    if image.dtype != np.uint8:
        raise PrismapInputError(f"{path}: {what} must be an 8-bit PNG; got {image.dtype.name}")
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return image


def read_gray_png(path, what, dtype):
    """A single-channel PNG of exactly ``dtype`` (uint8 or uint16), values untouched.

    Returns
    -------
    (H, W) ndarray of ``dtype``
    """
    image = read_png(path, what)
    if image.ndim != 2 or image.dtype != dtype:
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise PrismapInputError(
            f"{path}: {what} must be a single-channel {np.dtype(dtype).name} PNG; "
            f"got {channels}-channel {image.dtype.name}"
        )
    return image


def read_disparity_png(path, what, *, dtype, scale):
    """A disparity map stored as integers ``round(scale * d)`` in a single-channel PNG, 0 = unknown.

    Parameters
    ----------
    path : str or Path
    what : str
        The file's role in messages.
    dtype : numpy dtype, keyword-only
        The PNG's sample type: uint16 (KITTI and prismap sequences, ``scale`` 256) or uint8 (New
        Tsukuba, ``scale`` 1). Any other type is rejected: an 8-bit file where 16 bits are expected
        would silently lose the scale.
    scale : float, keyword-only
        Stored value per pixel of disparity.

    Returns
    -------
    (H, W) float32, pixels, NaN = unknown
    """
    raw = read_gray_png(path, what, dtype)
    disparity = raw.astype(np.float32) / np.float32(scale)
    disparity[raw == 0] = np.nan
    return disparity


def write_disparity_png(
    path: str | os.PathLike[str], disparity_px: npt.ArrayLike, what: str, *, scale: float = 256.0
) -> None:
    """Write a disparity map as KITTI's uint16 PNG (``round(scale * d)``, 0 = invalid), atomically.

    The inverse of ``read_disparity_png(path, what, dtype=np.uint16, scale=scale)``. Non-finite and
    non-positive disparities become 0; a valid disparity never rounds to 0 (it is stored as at least 1).

    Parameters
    ----------
    path : str or Path, ``.png``
    disparity_px : (H, W) float, pixels, NaN = invalid
    what : str
        The array's role in messages.
    scale : float, keyword-only
        Stored value per pixel of disparity (256 for KITTI and prismap sequences: at most 255.99 px).
    """
    d = np.asarray(disparity_px, dtype=np.float64)
    if d.ndim != 2:
        raise PrismapInputError(f"`{what}` must be (H, W); got shape {d.shape}")
    valid = np.isfinite(d) & (d > 0)
    if np.any(d[valid] > 65535 / scale):
        raise PrismapInputError(
            f"`{what}` reaches {d[valid].max():.2f} px; the uint16 x {scale:g} format stores at most "
            f"{np.floor(65535 / scale * 100) / 100:.2f}"
        )
    encoded = np.where(valid, np.maximum(np.round(d * scale), 1), 0).astype(np.uint16)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), encoded):
            raise PrismapInputError(f"{path}: OpenCV could not write the image")


def png_size(path, what):
    """``(height, width)`` in pixels from a PNG header, without decoding the image."""
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"{path}: {what} not found")
    with open(path, "rb") as handle:
        header = handle.read(24)
    if len(header) < 24 or header[:8] != PNG_SIGNATURE or header[12:16] != b"IHDR":
        raise PrismapInputError(f"{path}: {what} is not a PNG file (bad or truncated header)")
    width, height = struct.unpack(">II", header[16:24])
    return height, width


def paired_names(left_dir, right_dir, pattern):
    """Sorted names of the files matching ``pattern`` in ``left_dir``; each must exist in ``right_dir`` too.

    Returns
    -------
    list of str
        Never empty.
    """
    left = sorted(p.name for p in Path(left_dir).glob(pattern))
    if not left:
        raise PrismapInputError(f"{left_dir}: no files matching {pattern!r}")
    right = {p.name for p in Path(right_dir).glob(pattern)}
    missing = [name for name in left if name not in right]
    if missing:
        raise PrismapInputError(f"{right_dir}: missing {len(missing)} right image(s), first {missing[0]!r}")
    return left


def read_pair(left_path, right_path, *, colour):
    """Left and right images of one frame (:func:`read_image`), which must have one shape."""
    left = read_image(left_path, "left image", colour=colour)
    right = read_image(right_path, "right image", colour=colour)
    if right.shape != left.shape:
        raise PrismapInputError(f"{right_path}: right image shape {right.shape} != left {left.shape}")
    return left, right


def with_image_size(camera, image):
    """``camera`` (StereoCamera) with ``width`` and ``height`` of ``image`` ((H, W[, C]))."""
    return dataclasses.replace(camera, width=image.shape[1], height=image.shape[0])
