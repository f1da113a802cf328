"""Reader of the New Tsukuba Stereo Dataset (CVLAB, University of Tsukuba; Martull et al. 2012).

Layout::

    illumination/<name>/left/tsukuba_<name>_L_00001.png    (and right/..._R_...; 640x480 RGB)
    groundtruth/disparity_maps/left/tsukuba_disparity_L_00001.png
    groundtruth/depth_maps/left/tsukuba_depth_L_00001.xml
    groundtruth/camera_track.txt

with ``<name>`` one of daylight, flashlight, fluorescent, lamps; frames are numbered from 1.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from prismap.camera import TSUKUBA_CAMERA
from prismap.errors import PrismapInputError
from prismap.io._frame import LazyFrames, StereoFrame
from prismap.io._images import png_size, read_disparity_png, read_pair, with_image_size
from prismap.io._text import read_number_rows

_OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
_GROUND_TRUTH = (None, "disparity", "depth")


def read_tsukuba_track(
    path: str | os.PathLike[str], *, baseline_m: float = TSUKUBA_CAMERA.baseline_m
) -> npt.NDArray[np.float64]:
    """Read ``groundtruth/camera_track.txt`` into left-camera poses.

    Parameters
    ----------
    path : str or Path
        One line per frame, ``X, Y, Z, A, B, C`` (commas and/or spaces): the position of the middle
        of the stereo baseline in centimetres and Euler angles in degrees.
    baseline_m : float, keyword-only, metres
        Distance between the cameras; the left camera sits ``baseline_m / 2`` to the left of the
        tracked point.

    Returns
    -------
    (N, 4, 4) float64
        ``T_world_cam`` of the left camera, metres, OpenCV camera axes.

    Notes
    -----
    The published convention (dataset README and the converters that use it): the rotation is
    ``R = Rz(C) Ry(B) Rx(A)`` (static x-y-z axes) in a world and camera frame with y up and the
    camera looking down -z (Maya/OpenGL). Both frames are turned to OpenCV axes with
    ``F = diag(1, -1, -1)``: ``T_world_cam = F [R | t] F [I | (-b/2, 0, 0)]``. The world frame is
    therefore the dataset's with y and z negated (y points down).

    Raises
    ------
    PrismapInputError
        An empty file or line, or a line without exactly 6 finite numbers, named with file and line.
    """
    rows = read_number_rows(path, "Tsukuba camera track", 6, layout="X, Y, Z, A, B, C", commas=True)
    T_rig_left = np.eye(4)
    T_rig_left[0, 3] = -0.5 * baseline_m
    poses = np.empty((len(rows), 4, 4))
    for index, values in enumerate(rows):
        a, b, c = np.deg2rad(values[3:])
        T = np.eye(4)
        T[:3, :3] = _rot_z(c) @ _rot_y(b) @ _rot_x(a)
        T[:3, 3] = values[:3] / 100.0
        poses[index] = _OPENGL_TO_OPENCV @ T @ _OPENGL_TO_OPENCV @ T_rig_left
    return poses


def _rot_x(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def read_tsukuba_depth(path: str | os.PathLike[str]) -> npt.NDArray[np.float64]:
    """Read a ground-truth depth map ``tsukuba_depth_L_00001.xml`` (OpenCV FileStorage, node ``depth``).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    (H, W) float64, metres
        Depth along the optical axis (z), converted from the file's centimetres.

    Raises
    ------
    PrismapInputError
        Missing or unparsable file, no 2-D single-channel ``depth`` matrix, or a depth that is not
        finite and positive.
    """
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"{path}: Tsukuba depth map not found")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        message = str(exc).strip().splitlines()[-1][:120] if str(exc).strip() else type(exc).__name__
        raise PrismapInputError(f"{path}: Tsukuba depth map is not a readable OpenCV XML file ({message})") from None
    try:
        if not storage.isOpened():
            raise PrismapInputError(f"{path}: Tsukuba depth map is not a readable OpenCV XML file")
        node = storage.getNode("depth")
        depth = None if node.empty() or not node.isMap() else node.mat()
    except (cv2.error, SystemError):
        depth = None
    finally:
        storage.release()
    if depth is None or depth.ndim != 2 or depth.size == 0:
        raise PrismapInputError(f"{path}: Tsukuba depth map must hold a 2-D single-channel matrix named 'depth'")
    depth = depth.astype(np.float64) / 100.0
    if not np.all(np.isfinite(depth) & (depth > 0)):
        raise PrismapInputError(
            f"{path}: Tsukuba depths must be finite and > 0; got values in [{depth.min()}, {depth.max()}] m"
        )
    return depth


def read_tsukuba_disparity(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a ground-truth disparity map ``tsukuba_disparity_L_00001.png``.

    Parameters
    ----------
    path : str or Path
        Single-channel 8-bit PNG whose value is the disparity in whole pixels, as published
        (scenes span about 5-100 px; 0 never occurs in the rendered scene and is read as unknown).

    Returns
    -------
    (H, W) float32, pixels, NaN = unknown
        Quantised to 1 px: use ``NewTsukuba(ground_truth="depth")`` for sub-pixel truth.

    Raises
    ------
    PrismapInputError
        Missing, not a PNG, truncated or corrupt, or not single-channel uint8.
    """
    return read_disparity_png(path, "Tsukuba disparity", dtype=np.uint8, scale=1.0)


class NewTsukuba(LazyFrames):
    """The New Tsukuba sequence under one illumination: ``len(seq)``, ``seq[i] -> StereoFrame``.

    Parameters
    ----------
    root : str or Path
        The dataset folder (``NewTsukubaStereoDataset``) with ``illumination/`` and ``groundtruth/``.
    illumination : str, keyword-only
        ``daylight``, ``flashlight``, ``fluorescent`` or ``lamps`` (any folder present works).
    ground_truth : {"disparity", "depth", None}, keyword-only
        ``disparity``: the published integer PNGs; ``depth``: ``f b / z`` from the depth maps
        (sub-pixel); None: frames without ground truth.

    Attributes
    ----------
    camera : StereoCamera
        :data:`TSUKUBA_CAMERA`.
    poses : (N, 4, 4) float64 or None
        ``T_world_cam`` of the left camera (:func:`read_tsukuba_track`); None without the track.
    """

    def __init__(
        self, root: str | os.PathLike[str], *, illumination: str = "daylight", ground_truth: str = "disparity"
    ) -> None:
        if ground_truth not in _GROUND_TRUTH:
            raise PrismapInputError(f"`ground_truth` must be one of {_GROUND_TRUTH}; got {ground_truth!r}")
        self._root = Path(root)
        self._ground_truth = ground_truth
        light_dir = self._root / "illumination" / str(illumination)
        self._left_dir = light_dir / "left"
        self._right_dir = light_dir / "right"
        self._illumination = str(illumination)
        pattern = re.compile(rf"tsukuba_{re.escape(self._illumination)}_L_(\d+)\.png")
        self._numbers = sorted(
            int(match.group(1)) for p in self._left_dir.glob("*.png") if (match := pattern.fullmatch(p.name))
        )
        if not self._numbers:
            raise PrismapInputError(f"{self._left_dir}: no images named like tsukuba_{illumination}_L_00001.png")
        missing = [n for n in self._numbers if not self._image_path("R", n).is_file()]
        if missing:
            first = self._image_path("R", missing[0]).name
            raise PrismapInputError(f"{self._right_dir}: missing {len(missing)} right image(s), first {first}")
        self.camera = TSUKUBA_CAMERA
        self.poses = None
        track = self._root / "groundtruth" / "camera_track.txt"
        if track.exists():
            track_poses = read_tsukuba_track(track)
            if max(self._numbers) > len(track_poses) or min(self._numbers) < 1:
                raise PrismapInputError(
                    f"{track}: {len(track_poses)} poses do not cover frames {min(self._numbers)}-{max(self._numbers)}"
                )
            self.poses = track_poses[np.array(self._numbers) - 1]

    def _image_path(self, side, number):
        folder = self._left_dir if side == "L" else self._right_dir
        return folder / f"tsukuba_{self._illumination}_{side}_{number:05d}.png"

    def __len__(self):
        return len(self._numbers)

    def _frame(self, index):
        number = self._numbers[index]
        left, right = read_pair(self._image_path("L", number), self._image_path("R", number), colour=True)
        return StereoFrame(
            left=left,
            right=right,
            camera=with_image_size(self.camera, left),
            disparity_gt=None if self._ground_truth is None else self.disparity_gt(index),
            T_world_cam=None if self.poses is None else self.poses[index].copy(),
            name=f"tsukuba/{self._illumination}/{number:05d}",
        )

    def ground_truth_path(self, index: int) -> Path:
        """Path of frame ``index``'s ground-truth file (disparity PNG or depth XML), whether or not it exists."""
        number = self._numbers[self._index(index)]
        truth = self._root / "groundtruth"
        if self._ground_truth == "depth":
            return truth / "depth_maps" / "left" / f"tsukuba_depth_L_{number:05d}.xml"
        return truth / "disparity_maps" / "left" / f"tsukuba_disparity_L_{number:05d}.png"

    def disparity_gt(self, index: int) -> np.ndarray:
        """Frame ``index``'s ground-truth disparity, (H, W) float32, pixels; the images are not decoded.

        From the integer PNG (``ground_truth="disparity"``) or ``f b / z`` of the depth map (``"depth"``);
        its size must be the left image's.
        """
        if self._ground_truth is None:
            raise PrismapInputError("this NewTsukuba was opened with ground_truth=None: it has no ground truth")
        path = self.ground_truth_path(index)
        if self._ground_truth == "depth":
            disparity = self.camera.disparity_from_depth(read_tsukuba_depth(path)).astype(np.float32)
        else:
            disparity = read_tsukuba_disparity(path)
        size = png_size(self._image_path("L", self._numbers[self._index(index)]), "left image")
        if disparity.shape != size:
            raise PrismapInputError(f"{path}: ground truth has shape {disparity.shape}, the image {size}")
        return disparity
