"""Middlebury 2014/2021 stereo folders (``im0.png``, ``im1.png``, ``calib.txt``, ``disp0.pfm``).

``calib.txt`` holds one ``key=value`` per line: ``cam0=[f 0 cx; 0 f cy; 0 0 1]``, ``cam1=[...]``,
``doffs`` (pixels), ``baseline`` (millimetres), ``width``, ``height``, ``ndisp`` and a few more
scalars (``isint``, ``vmin``, ``vmax``, ``dyavg``, ``dymax``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from prismap.camera import MOTORCYCLE_CAMERA, StereoCamera
from prismap.errors import PrismapInputError
from prismap.io._frame import LazyFrames, StereoFrame
from prismap.io._images import png_size, read_pair
from prismap.io._pfm import read_pfm
from prismap.io._text import location, parse_numbers, read_text


def read_middlebury_calib(path: str | os.PathLike[str]) -> StereoCamera:
    """The stereo camera of a Middlebury ``calib.txt``.

    Parameters
    ----------
    path : str or Path
        The ``calib.txt`` file.

    Returns
    -------
    StereoCamera
        ``f, cx, cy`` from ``cam0``, baseline converted from millimetres to metres, ``doffs``,
        ``width`` and ``height`` from the file.
    """
    path = Path(path)
    return StereoCamera.from_middlebury_calib(_parse_calib(path), source=str(path))


def load_middlebury_folder(path: str | os.PathLike[str]) -> StereoFrame:
    """One Middlebury scene folder as a :class:`StereoFrame`.

    Parameters
    ----------
    path : str or Path
        Folder with ``im0.png`` (left), ``im1.png`` (right), ``calib.txt`` and, when the ground
        truth is public, ``disp0.pfm``.

    Returns
    -------
    StereoFrame
        RGB (or grey) uint8 images; ``disparity_gt`` (H, W) float32 pixels with ``inf`` -> NaN, or
        None without ``disp0.pfm``; ``name`` = the folder's name; ``extras["calib"]`` = the
        remaining scalar fields of ``calib.txt`` (``ndisp``, ``vmin``, ``vmax``, ...).
    """
    folder = Path(path)
    if not folder.is_dir():
        raise PrismapInputError(
            f"{folder}: not a Middlebury folder (expected a directory with im0.png, im1.png, calib.txt)"
        )
    fields = _parse_calib(folder / "calib.txt")
    camera = StereoCamera.from_middlebury_calib(fields, source=str(folder / "calib.txt"))
    left, right = read_pair(folder / "im0.png", folder / "im1.png", colour=False)
    if (camera.height, camera.width) != left.shape[:2]:
        raise PrismapInputError(
            f"{folder}: calib.txt says width={camera.width}, height={camera.height}; "
            f"im0.png is {left.shape[1]}x{left.shape[0]}"
        )
    disparity_gt = _read_disparity(folder, left.shape[:2]) if (folder / "disp0.pfm").exists() else None
    extras = {"calib": {key: value for key, value in fields.items() if key not in ("cam0", "cam1")}}
    return StereoFrame(left, right, camera, disparity_gt=disparity_gt, name=folder.name, extras=extras)


def _read_disparity(folder, size):
    """``folder/disp0.pfm`` as (H, W) float32 pixels, ``inf`` -> NaN; it must have the images' ``size``."""
    disparity = read_pfm(folder / "disp0.pfm")
    if disparity.shape != tuple(size):
        raise PrismapInputError(
            f"{folder}: disp0.pfm must be one-channel of the images' size {tuple(size)}; got shape {disparity.shape}"
        )
    return np.where(np.isinf(disparity), np.float32(np.nan), disparity)


class MiddleburyScenes(LazyFrames):
    """Middlebury scene folders as a sequence of frames: ``len(scenes)``, ``scenes[i] -> StereoFrame``.

    Parameters
    ----------
    path : str or Path
        One scene folder (with ``im0.png``), or a folder whose sub-folders with ``im0.png`` are
        scenes (e.g. ``MiddEval3/trainingQ`` or an unpacked Middlebury 2014 set), taken in name order.

    Notes
    -----
    Every scene has its own camera and image size. A scene is read with
    :func:`load_middlebury_folder` when accessed.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        path = Path(path)
        if (path / "im0.png").is_file():
            self.folders = [path]
        else:
            self.folders = sorted(p for p in path.iterdir() if (p / "im0.png").is_file()) if path.is_dir() else []
        if not self.folders:
            raise PrismapInputError(f"{path}: no Middlebury scene (a folder with im0.png, im1.png, calib.txt)")

    def __len__(self):
        return len(self.folders)

    def _frame(self, index):
        return load_middlebury_folder(self.folders[index])

    def ground_truth_path(self, index: int) -> Path:
        """Path of scene ``index``'s ``disp0.pfm``, whether or not it exists."""
        return self.folders[self._index(index)] / "disp0.pfm"

    def disparity_gt(self, index: int) -> np.ndarray:
        """Scene ``index``'s ground truth, (H, W) float32, pixels, NaN = unknown; the images are not decoded."""
        folder = self.folders[self._index(index)]
        return _read_disparity(folder, png_size(folder / "im0.png", "left image"))


def load_middlebury_motorcycle() -> StereoFrame:
    """Middlebury 2014 Motorcycle at quarter resolution, from scikit-image's bundled copy.

    Returns
    -------
    StereoFrame
        (500, 741, 3) RGB uint8 images, ground-truth disparity (pixels, NaN where unknown),
        f = 994.978 px, (cx, cy) = (311.193, 254.877) px, doffs = 31.086 px, baseline 0.193001 m.
    """
    from skimage import data

    left, right, disparity = data.stereo_motorcycle()
    camera = MOTORCYCLE_CAMERA
    disparity_gt = np.where(np.isfinite(disparity), disparity, np.nan).astype(np.float32)
    return StereoFrame(left, right, camera, disparity_gt=disparity_gt, name="middlebury-2014/Motorcycle (quarter)")


def _parse_calib(path):
    """``calib.txt`` as a dict: matrices ``[a b c; d e f; g h i]`` as (3, 3) float64, other values as float."""
    fields = {}
    for number, line in enumerate(read_text(path, "Middlebury calibration file").splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        key, sep, value = line.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key:
            raise PrismapInputError(f"{location(path, number)}: expected 'key=value'; got {line[:60]!r}")
        if value.startswith("["):
            rows = [parse_numbers(row, path, number, key) for row in value.strip("[]").split(";")]
            if len(rows) != 3 or any(row.size != 3 for row in rows):
                raise PrismapInputError(
                    f"{location(path, number, key)}: expected a 3x3 matrix [a b c; d e f; g h i]; got {value[:60]!r}"
                )
            fields[key] = np.array(rows)
        else:
            numbers = parse_numbers(value, path, number, key)
            if numbers.size != 1:
                raise PrismapInputError(f"{location(path, number, key)}: expected one number; got {value[:60]!r}")
            fields[key] = float(numbers[0])
    return fields
