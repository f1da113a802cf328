"""Any dataset with ground-truth disparity, opened by name or folder layout, as a lazy frame selection.

``prismap characterise`` and :func:`prismap.pipeline.characterise_sequence` open their data here. The kind
is recognised from the folder's layout, checked in this order:

==========================  ====================================================================
kind                        layout
==========================  ====================================================================
``middlebury-motorcycle``   the name itself: scikit-image's bundled quarter-size Motorcycle
``middlebury``              ``im0.png``, ``im1.png``, ``calib.txt``, ``disp0.pfm``; or sub-folders that are such scenes
``kitti-stereo-2012``       ``image_0/``, ``image_1/``, ``calib/``, ``disp_noc/`` or ``disp_occ/``
``kitti-stereo-2015``       ``image_2/``, ``image_3/``, ``calib_cam_to_cam/`` or ``calib/``, ``disp_noc_0/`` or ``disp_occ_0/``
``sequence``                ``image_2/``, ``image_3/``, ``calib.txt``, ``disp/`` (prismap's KITTI-layout sequence)
``kitti-odometry``          ``image_2/``, ``image_3/``, ``calib.txt`` with ``Tr``, ``velodyne/`` (no ``disp/``)
``kitti-raw``               ``image_02/data``, ``image_03/data``, ``velodyne_points/data``; calibration in the parent
``new-tsukuba``             ``illumination/``, ``groundtruth/``
==========================  ====================================================================

KITTI odometry and raw drives have no disparity maps: the ground truth is the Velodyne scan projected into
the left colour camera (:func:`points_to_disparity`, the thesis's fig. 3.16), sparse, NaN elsewhere.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from prismap._progress import progress as progress_bar
from prismap._validate import check_integer, parse_frame_range
from prismap.errors import PrismapInputError
from prismap.io._frame import LazyFrames
from prismap.io._kitti import KITTI_DISPARITIES, KittiOdometry, KittiRaw, KittiStereo
from prismap.io._middlebury import MiddleburyScenes, load_middlebury_motorcycle
from prismap.io._sequence import read_sequence
from prismap.io._tsukuba import NewTsukuba

MOTORCYCLE = "middlebury-motorcycle"

_LOOKED_FOR = (
    "a Middlebury scene (im0.png, im1.png, calib.txt, disp0.pfm) or a folder of them; KITTI stereo 2012 "
    "(image_0/, image_1/, calib/, disp_noc/) or 2015 (image_2/, image_3/, calib_cam_to_cam/, disp_noc_0/); "
    "a KITTI-layout sequence (image_2/, image_3/, calib.txt) with disp/ or velodyne/; a KITTI raw drive "
    "(image_02/data, velodyne_points/data); New Tsukuba (illumination/, groundtruth/)"
)


def open_ground_truth(
    dataset: str | os.PathLike[str],
    *,
    frames: str | tuple[int | None, int | None] | None = None,
    every: int = 1,
    kitti_disparity: str = "noc",
) -> GroundTruthFrames:
    """Open a dataset with ground-truth disparity and select frames; nothing is decoded yet.

    Parameters
    ----------
    dataset : str or Path
        ``"middlebury-motorcycle"`` or a folder in one of the layouts of the module docstring.
    frames : str ``"A:B"`` or (int or None, int or None) or None, keyword-only
        Frames ``A`` up to (excluding) ``B`` of the dataset, Python-style (``A`` or ``B`` may be
        left out or negative); None = all. An index beyond the dataset is an error, not clipped.
    every : int >= 1, keyword-only
        Keep every ``every``-th frame of that range.
    kitti_disparity : {"noc", "occ"}, keyword-only
        KITTI stereo ground truth: non-occluded pixels only (default), or occluded ones too.

    Returns
    -------
    GroundTruthFrames
        ``len()`` frames; each access reads one frame from disk.

    Raises
    ------
    PrismapInputError
        No layout recognised (the message lists what was looked for), a selection that is empty or out
        of range, or a selected frame whose ground-truth file is missing (checked before returning).
    """
    if kitti_disparity not in KITTI_DISPARITIES:
        raise PrismapInputError(f"`kitti_disparity` must be one of {KITTI_DISPARITIES}; got {kitti_disparity!r}")
    every = check_integer(every, "every", expected="an integer >= 1", condition=lambda k: k >= 1)
    kind, reader = _open(dataset, kitti_disparity)
    indices = _select(frames, every, len(reader), dataset)
    missing = [
        i for i in indices if reader.ground_truth_path(i) is not None and not reader.ground_truth_path(i).is_file()
    ]
    if missing:
        raise PrismapInputError(
            f"{dataset}: {len(missing)} of the {len(indices)} selected frames have no ground truth; first "
            f"frame {missing[0]}: {reader.ground_truth_path(missing[0])} not found"
        )
    return GroundTruthFrames(reader, kind, str(dataset), indices)


class GroundTruthFrames(LazyFrames):
    """Selected frames of a dataset, each a :class:`StereoFrame` with ``disparity_gt``, read on access.

    Made by :func:`open_ground_truth`. Only the frame asked for is in memory, so characterising over
    hundreds of frames streams them. Pickles small (paths and calibrations), so Dask workers can read
    their own frames.

    Attributes
    ----------
    kind : str
        The recognised layout (see :mod:`prismap.io._ground_truth`), e.g. ``"kitti-stereo-2015"``.
    source : str
        The dataset as given.
    indices : tuple of int
        The selected frames' positions in the whole dataset.
    """

    def __init__(self, reader: Any, kind: str, source: str, indices: Iterable[int]) -> None:
        self._reader = reader
        self.kind = kind
        self.source = source
        self.indices = tuple(indices)

    def __len__(self):
        return len(self.indices)

    def _frame(self, position):
        index = self.indices[position]
        frame = self._reader[index]
        _check_bound(frame.disparity_gt, self._where(index))
        return frame

    def disparity_gt(self, position: int) -> np.ndarray:
        """Ground truth of selected frame ``position`` without decoding its images.

        Returns
        -------
        (H, W) float32, pixels, NaN = unknown
        """
        index = self.indices[position]
        disparity = self._reader.disparity_gt(index)
        _check_bound(disparity, self._where(index))
        return disparity

    def max_disparity_px(self, *, progress: bool | None = None) -> float:
        """The largest valid ground-truth disparity over the selection, from one pass over the ground truth only.

        The matcher's search range is set from it. Every value has been checked to lie below its image's
        width (no match can lie farther), so a corrupt pixel cannot blow up the search.

        Parameters
        ----------
        progress : bool or None, keyword-only
            Show a progress bar (None: when stderr is a terminal).

        Returns
        -------
        float, pixels

        Raises
        ------
        PrismapInputError
            A disparity at or beyond the image width, no valid ground-truth pixel at all, or none above 0 px.
        """
        largest, where = -np.inf, None
        for position in progress_bar(
            range(len(self)), total=len(self), desc="ground truth", unit="frame", enabled=progress
        ):
            disparity = self.disparity_gt(position)
            valid = np.isfinite(disparity)
            if valid.any() and float(disparity[valid].max()) > largest:
                largest, where = float(disparity[valid].max()), self._where(self.indices[position])
        if largest == -np.inf:
            raise PrismapInputError(
                f"{self.source}: the dataset has no valid ground-truth disparity to characterise "
                f"against ({len(self)} frames)"
            )
        if largest <= 0:
            raise PrismapInputError(
                f"{where}: every valid ground-truth disparity of {self.source} is <= 0 px (the largest, {largest:.6g} "
                f"px, is in this file); a disparity (left x - right x) is positive, so it cannot set the search range"
            )
        return largest

    def _where(self, index):
        path = self._reader.ground_truth_path(index)
        return f"{self.source} frame {index}" if path is None else str(path)


def _check_bound(disparity, where):
    """Refuse a ground-truth disparity at or beyond the image width: no pixel's match can lie that far."""
    width = disparity.shape[1]
    finite = np.where(np.isfinite(disparity), disparity, -np.inf)
    if finite.size and finite.max() >= width:
        row, col = np.unravel_index(np.argmax(finite), finite.shape)
        raise PrismapInputError(
            f"{where}: ground-truth disparity {finite[row, col]:.6g} px at (row {row}, column {col}) is not below "
            f"the image width {width} px; no match lies that far, so it cannot set the search range"
        )


def _select(frames, every, count, dataset):
    """The dataset positions of ``frames`` (``"A:B"``, ``(A, B)`` or None) with step ``every``."""
    text = frames
    if frames is None:
        start, stop = 0, count
    else:
        if isinstance(frames, str):
            start, stop = parse_frame_range(frames, "`frames`")
        else:
            if not isinstance(frames, (tuple, list)) or len(frames) != 2:
                raise PrismapInputError(f"`frames` must be 'A:B', (start, stop) or None; got {frames!r}")
            start, stop = frames
            text = f"{'' if start is None else start}:{'' if stop is None else stop}"
        start = 0 if start is None else check_integer(start, "frames start")
        stop = count if stop is None else check_integer(stop, "frames stop")
        for value in (start, stop):
            if not -count <= value <= count:
                raise PrismapInputError(
                    f"`frames` {text}: {value} lies outside the {count} frames of {dataset} (0..{count - 1})"
                )
        start, stop = start % count if start < count else count, stop % count if stop < count else count
    indices = range(start, stop, every)
    if not indices:
        raise PrismapInputError(f"`frames` {text} selects no frame of the {count} frames of {dataset}")
    return list(indices)


class _Motorcycle:
    """The bundled Motorcycle as a one-frame reader (scikit-image loads it on access)."""

    def __len__(self):
        return 1

    def __getitem__(self, index):
        return load_middlebury_motorcycle()

    def ground_truth_path(self, index):
        return None

    def disparity_gt(self, index):
        return self[index].disparity_gt


class _VelodyneTruth:
    """A KITTI odometry sequence or raw drive whose ground truth is each frame's projected Velodyne scan."""

    def __init__(self, sequence):
        _ = sequence.T_cam_velo  # a calibration without the Velodyne transform fails here, on opening
        self._sequence = sequence

    def __len__(self):
        return len(self._sequence)

    def __getitem__(self, index):
        return replace(self._sequence[index], disparity_gt=self.disparity_gt(index))

    def ground_truth_path(self, index):
        return self._sequence.velodyne_path(index)

    def disparity_gt(self, index):
        return self._sequence.velodyne_disparity(index)


def _open(dataset, kitti_disparity):
    """``(kind, reader)`` of a dataset name or folder; see the module docstring for the layouts."""
    if not isinstance(dataset, (str, Path)):
        raise PrismapInputError(f"`dataset` must be '{MOTORCYCLE}' or a folder path; got {type(dataset).__name__}")
    if str(dataset) == MOTORCYCLE:
        return MOTORCYCLE, _Motorcycle()
    path = Path(dataset)
    if not path.exists():
        raise PrismapInputError(
            f"{dataset}: no such file or directory (expected '{MOTORCYCLE}' or a dataset folder: {_LOOKED_FOR})"
        )
    if not path.is_dir():
        raise PrismapInputError(f"{dataset}: not a folder (expected '{MOTORCYCLE}' or a dataset folder)")

    def has(*names):
        return all((path / name).is_dir() for name in names)

    if (path / "im0.png").is_file():
        return "middlebury", MiddleburyScenes(path)
    if has("image_0", "image_1") or (
        has("image_2", "image_3") and not (path / "calib.txt").is_file() and (has("calib_cam_to_cam") or has("calib"))
    ):
        stereo = KittiStereo(path, disparity=kitti_disparity)
        return f"kitti-stereo-{stereo.year}", stereo
    if has("image_2", "image_3") and (path / "calib.txt").is_file():
        if has("disp"):
            return "sequence", read_sequence(path)
        if has("velodyne"):
            return "kitti-odometry", _VelodyneTruth(KittiOdometry(path, None))
        raise PrismapInputError(
            f"{path}: a KITTI-layout sequence without ground truth: neither disp/ "
            "(ground-truth disparities) nor velodyne/ (scans to project) is there"
        )
    if has("image_02/data", "image_03/data"):
        if not has("velodyne_points/data"):
            raise PrismapInputError(f"{path}: a KITTI raw drive without ground truth: no velodyne_points/data")
        return "kitti-raw", _VelodyneTruth(KittiRaw(path))
    if has("illumination", "groundtruth"):
        return "new-tsukuba", _tsukuba(path)
    if any((child / "im0.png").is_file() for child in path.iterdir()):
        return "middlebury", MiddleburyScenes(path)
    raise PrismapInputError(f"{path}: no dataset layout recognised; looked for {_LOOKED_FOR}")


def _tsukuba(root):
    """New Tsukuba under daylight (else the first illumination present), with sub-pixel depth truth if shipped."""
    lights = sorted(p.name for p in (root / "illumination").iterdir() if p.is_dir())
    if not lights:
        raise PrismapInputError(f"{root / 'illumination'}: no illumination folder (daylight, flashlight, ...)")
    light = "daylight" if "daylight" in lights else lights[0]
    truth = "depth" if (root / "groundtruth" / "depth_maps" / "left").is_dir() else "disparity"
    return NewTsukuba(root, illumination=light, ground_truth=truth)
