"""Stereo sequences on disk in the KITTI odometry layout, plus a ground-truth occupancy file.

Layout of a sequence directory (KITTI odometry, with prismap's own additions marked *)::

    calib.txt             P0: .. P3: 12 numbers each (3x4 row-major projection matrices, pixels / pixel-metres)
    image_2/NNNNNN.png    left (reference) images, 8-bit grey or RGB
    image_3/NNNNNN.png    right images, same names and sizes
    poses.txt             optional: one line per frame, the 3x4 row-major T_world_cam (metres) of the left camera
    disp/NNNNNN.png     * optional: left ground-truth disparity, uint16, value = round(256 * d), 0 = invalid
    occupancy.npz       * optional: ground-truth occupancy (:class:`GroundTruthOccupancy`)

``P2 = K [I | 0]`` and ``P3 = K_right [I | (-f b, 0, 0)]`` with ``K_right`` the left ``K`` whose ``cx`` is
shifted by the disparity offset ``doffs``; so ``f = P2[0, 0]``, ``baseline = (P2[0, 3] - P3[0, 3]) / f`` and
``doffs = P3[0, 2] - P2[0, 2]``. ``P0``/``P1`` are written equal to ``P2``/``P3`` (KITTI's grey pair) and ignored
on reading. Unlike KITTI's ``poses/NN.txt`` (poses of the grey camera P0), ``poses.txt`` here holds the poses
of the image_2 camera itself.

A KITTI odometry download is read as it is: a directory ``ROOT/sequences/NN`` (a name of digits in a folder
named ``sequences``) without ``poses.txt`` takes its poses from ``ROOT/poses/NN.txt`` when that file exists,
converted from camera 0 to the image_2 camera exactly as :class:`prismap.io.KittiOdometry` does. ``times.txt``
and ``velodyne/`` are ignored. Sequences 11-21 ship without poses and open without them.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from prismap._files import atomic_path, save_npz, umask_mode
from prismap._validate import check_pose, check_positive
from prismap.errors import PrismapInputError
from prismap.grid import PACK_OFFSET, pack_keys
from prismap.io._frame import StereoFrame, frame_index
from prismap.io._images import (
    paired_names,
    png_size,
    read_disparity_png,
    read_pair,
    write_disparity_png,
)
from prismap.io._kitti import (
    _camera_poses,
    _rectified_pair,
    read_kitti_calib,
    read_kitti_poses,
)
from prismap.io._npz import INTEGER, REAL, TEXT, array_field, read_npz
from prismap.io._text import homogeneous, read_number_rows

GROUND_TRUTH_FORMAT = "prismap-ground-truth-occupancy"
GROUND_TRUTH_VERSION = 1
_DISPARITY_SCALE = 256.0


@dataclass(frozen=True)
class GroundTruthOccupancy:
    """Exact occupancy of a simulated world, restricted to what a perfect sensor would have observed.

    ``evaluate`` scores a map on the ``observed_keys``: those in ``occupied_keys`` are truly occupied,
    the rest (:attr:`free_keys`) truly free. Voxels never observed are not scored: no sensor could know them.

    Attributes
    ----------
    voxel_size_m : float, metres
    occupied_keys : (N, 3) int64, sorted, unique, in [-2**20, 2**20) (``grid.pack_keys``)
        Keys ``floor(p / voxel_size_m)`` of every voxel containing a point of a solid (observed or not);
        2-D worlds use the layer z key 0.
    observed_keys : (M, 3) int64, sorted, unique, in [-2**20, 2**20) (``grid.pack_keys``)
        Keys of the voxels a noise-free sensor saw along the frames: free space in front of the surfaces
        and the voxels holding the visible surface points (see ``prismap.sim``).
    """

    voxel_size_m: float
    occupied_keys: np.ndarray
    observed_keys: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "voxel_size_m", check_positive(self.voxel_size_m, "voxel_size_m"))
        for name in ("occupied_keys", "observed_keys"):
            keys = np.asarray(getattr(self, name))
            if keys.ndim != 2 or keys.shape[1] != 3 or not np.issubdtype(keys.dtype, np.integer):
                raise PrismapInputError(f"`{name}` must be an (N, 3) integer array; got {keys.dtype} {keys.shape}")
            keys = keys.astype(np.int64)
            if keys.size and (keys.min() < -PACK_OFFSET or keys.max() >= PACK_OFFSET):
                raise PrismapInputError(
                    f"`{name}` must lie in [-{PACK_OFFSET}, {PACK_OFFSET}) (+-{PACK_OFFSET * self.voxel_size_m:.6g} m at "
                    f"{self.voxel_size_m:g} m voxels); got values in [{keys.min()}, {keys.max()}]"
                )
            packed = pack_keys(keys)
            if np.any(np.diff(packed) <= 0):  # not yet sorted and unique
                keys = keys[np.unique(packed, return_index=True)[1]]
            keys.setflags(write=False)
            object.__setattr__(self, name, keys)

    @property
    def free_keys(self) -> np.ndarray:
        """(K, 3) int64: observed keys that hold no solid, sorted."""
        return self.observed_keys[~self._observed_is_occupied()]

    @property
    def observed_occupied_keys(self) -> np.ndarray:
        """(K, 3) int64: observed keys that hold a solid, sorted."""
        return self.observed_keys[self._observed_is_occupied()]

    def _observed_is_occupied(self):
        """(M,) bool: whether each observed key is also an occupied key."""
        return np.isin(pack_keys(self.observed_keys), pack_keys(self.occupied_keys), assume_unique=True)


_GROUND_TRUTH_SPEC = {
    "format": TEXT,
    "version": INTEGER,
    "voxel_size_m": REAL,
    "occupied_keys": array_field((None, 3), "integer"),
    "observed_keys": array_field((None, 3), "integer"),
}


def write_ground_truth(path: str | os.PathLike[str], truth: GroundTruthOccupancy) -> None:
    """Write ``truth`` (:class:`GroundTruthOccupancy`) to ``path`` (``.npz``) atomically.

    Fields: ``format`` (str), ``version`` (int), ``voxel_size_m`` (float), ``occupied_keys`` and
    ``observed_keys`` ((N, 3) int64).
    """
    with atomic_path(path) as tmp:
        save_npz(
            tmp,
            format=np.array(GROUND_TRUTH_FORMAT),
            version=np.array(GROUND_TRUTH_VERSION),
            voxel_size_m=np.array(truth.voxel_size_m),
            occupied_keys=truth.occupied_keys,
            observed_keys=truth.observed_keys,
        )


def read_ground_truth(path: str | os.PathLike[str]) -> GroundTruthOccupancy:
    """Read a file written by :func:`write_ground_truth`; clear errors name the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise PrismapInputError(f"{path}: ground-truth occupancy file not found")
    fields = read_npz(path, "ground-truth occupancy file", _GROUND_TRUTH_SPEC)
    if fields["format"] != GROUND_TRUTH_FORMAT or fields["version"] != GROUND_TRUTH_VERSION:
        raise PrismapInputError(
            f"{path}: expected format {GROUND_TRUTH_FORMAT!r} version {GROUND_TRUTH_VERSION}; "
            f"got {fields['format']!r} version {fields['version']}"
        )
    try:
        return GroundTruthOccupancy(fields["voxel_size_m"], fields["occupied_keys"], fields["observed_keys"])
    except PrismapInputError as exc:
        raise PrismapInputError(f"{path}: {exc}") from None


def write_sequence(
    frames: Iterable[StereoFrame], out_dir: str | os.PathLike[str], *, occupancy: GroundTruthOccupancy | None = None
) -> int:
    """Write stereo frames as a KITTI-layout sequence (see the module docstring), all or nothing.

    The files are written into a temporary directory beside ``out_dir`` and moved into ``out_dir``
    only once every frame has been checked and written, so a bad frame (or an interruption) leaves
    ``out_dir`` untouched; frames are still streamed, not held in memory.

    Parameters
    ----------
    frames : iterable of StereoFrame
        One camera for all frames; poses either on every frame or on none; ``disparity_gt`` likewise
        (written to ``disp/``, quantised to 1/256 px; disparities must lie in (0, 255.99] px or be NaN).
    out_dir : str or Path
        Created if missing; existing files of the same names are replaced, other files are kept.
    occupancy : GroundTruthOccupancy, optional
        Written to ``occupancy.npz``.

    Returns
    -------
    count : int
        Number of frames written.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise PrismapInputError(f"{out_dir}: exists and is not a directory; expected a sequence directory")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=out_dir.parent, prefix=f".{out_dir.name}.", suffix=".tmp"))
    os.chmod(staging, umask_mode(0o777))  # mkdtemp makes it 0700; the sequence follows the umask
    try:
        count = _write_files(frames, staging, occupancy)
        _move_into(staging, out_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return count


def _write_files(frames, out_dir, occupancy):
    """Write every file of the sequence into the (new, empty) ``out_dir``; the frame count."""
    camera = None
    poses = []
    has_pose = has_disparity = None
    count = 0
    for index, frame in enumerate(frames):
        if not isinstance(frame, StereoFrame):
            raise PrismapInputError(f"`frames[{index}]` must be a StereoFrame; got {type(frame).__name__}")
        if camera is None:
            camera = frame.camera
            has_pose = frame.T_world_cam is not None
            has_disparity = frame.disparity_gt is not None
        elif not _same_intrinsics(camera, frame.camera):
            raise PrismapInputError(f"`frames[{index}]` has another camera than frame 0: {frame.camera} vs {camera}")
        if (frame.T_world_cam is not None) != has_pose or (frame.disparity_gt is not None) != has_disparity:
            raise PrismapInputError(
                f"`frames[{index}]`: poses and ground-truth disparities must be given for every frame or for none"
            )
        if has_pose:
            poses.append(frame.T_world_cam[:3].ravel())
        stem = f"{index:06d}.png"
        _write_image(out_dir / "image_2" / stem, frame.left, f"frames[{index}].left")
        _write_image(out_dir / "image_3" / stem, frame.right, f"frames[{index}].right")
        if has_disparity:
            write_disparity_png(
                out_dir / "disp" / stem, frame.disparity_gt, f"frames[{index}].disparity_gt", scale=_DISPARITY_SCALE
            )
        count += 1
    if count == 0:
        raise PrismapInputError("`frames` is empty: a sequence needs at least one frame")
    (out_dir / "calib.txt").write_text(_calib_text(camera), encoding="utf-8")
    if has_pose:
        text = "".join(" ".join(f"{v:.17g}" for v in p) + "\n" for p in poses)
        (out_dir / "poses.txt").write_text(text, encoding="utf-8")
    if occupancy is not None:
        write_ground_truth(out_dir / "occupancy.npz", occupancy)
    return count


def _move_into(staging, out_dir):
    """Move the written sequence into ``out_dir``: one rename when it is new (or empty), else file by file."""
    try:
        os.rename(staging, out_dir)  # atomic; replaces an empty directory
        return
    except OSError:
        pass
    for source in sorted(staging.rglob("*")):
        if source.is_file():
            target = out_dir / source.relative_to(staging)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(source, target)


def _same_intrinsics(a, b):
    fields = ("focal_px", "cx_px", "cy_px", "baseline_m", "doffs_px")
    return all(np.isclose(getattr(a, f), getattr(b, f), rtol=1e-12, atol=1e-12) for f in fields)


def _write_image(path, image, name):
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    elif image.ndim != 2:
        raise PrismapInputError(f"`{name}` must be (H, W) or (H, W, 3); got shape {image.shape}")
    if image.dtype not in (np.uint8, np.uint16):
        raise PrismapInputError(f"`{name}` must be uint8 (or uint16 for disparity); got {image.dtype}")
    path.parent.mkdir(exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise PrismapInputError(f"{path}: OpenCV could not write the image")


def _calib_text(camera):
    f, cx, cy = camera.focal_px, camera.cx_px, camera.cy_px
    left = np.array([[f, 0.0, cx, 0.0], [0.0, f, cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
    right = left.copy()
    right[0, 2] += camera.doffs_px
    right[0, 3] = -f * camera.baseline_m
    rows = [("P0", left), ("P1", right), ("P2", left), ("P3", right)]
    return "".join(f"{name}: " + " ".join(f"{v:.17g}" for v in p.ravel()) + "\n" for name, p in rows)


class Sequence:
    """A sequence directory opened by :func:`read_sequence`: frames are read from disk on access.

    Attributes
    ----------
    path : Path
    camera : StereoCamera
        From ``calib.txt``, with the image size.
    poses : (N, 4, 4) float64 or None
        ``T_world_cam`` of the image_2 camera in each frame, metres; None without a pose file.
    pose_path : Path or None
        The file the poses came from: ``poses.txt``, else ``ROOT/poses/NN.txt`` of a KITTI odometry tree
        (see the module docstring); None without either.
    ground_truth : GroundTruthOccupancy or None
        From ``occupancy.npz``, read on first access.
    names : list of str
        Frame file names (``NNNNNN.png``), sorted.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise PrismapInputError(f"{self.path}: sequence directory not found")
        left_dir, right_dir = self.path / "image_2", self.path / "image_3"
        self.names = paired_names(left_dir, right_dir, "*.png")
        size = None
        for name in self.names:
            for folder, what in ((left_dir, "left image"), (right_dir, "right image")):
                this = png_size(folder / name, what)
                if size is None:
                    size = this
                elif this != size:
                    raise PrismapInputError(
                        f"{folder / name}: image size {this[1]}x{this[0]} differs from "
                        f"{left_dir / self.names[0]} ({size[1]}x{size[0]})"
                    )
        calib_path = self.path / "calib.txt"
        self.camera, P_left = _rectified_pair(
            read_kitti_calib(calib_path), calib_path, "P2", "P3", width=size[1], height=size[0]
        )
        self.poses = None
        self.pose_path = self.path / "poses.txt"
        if self.pose_path.is_file():
            rows = read_number_rows(self.pose_path, "pose file", 12, layout="3x4 pose")
            self.poses = homogeneous(rows.reshape(-1, 3, 4))
            for index, pose in enumerate(self.poses):
                check_pose(pose, f"{self.pose_path} line {index + 1}")
        else:
            self.pose_path = _kitti_odometry_pose_path(self.path)
            if self.pose_path is not None:
                self.poses = _camera_poses(read_kitti_poses(self.pose_path), P_left)
        if self.poses is not None and len(self.poses) != len(self.names):
            raise PrismapInputError(f"{self.pose_path}: {len(self.poses)} poses for {len(self.names)} frames")
        self._ground_truth = None

    @property
    def ground_truth(self) -> GroundTruthOccupancy | None:
        """GroundTruthOccupancy of ``occupancy.npz``, or None without the file (read once, then kept)."""
        path = self.path / "occupancy.npz"
        if self._ground_truth is None and path.is_file():
            self._ground_truth = read_ground_truth(path)
        return self._ground_truth

    def __len__(self):
        return len(self.names)

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def __getitem__(self, index):
        index = frame_index(index, len(self), self.path)
        name = self.names[index]
        left, right = read_pair(self.path / "image_2" / name, self.path / "image_3" / name, colour=False)
        disparity = self.disparity_gt(index) if self.ground_truth_path(index).is_file() else None
        pose = None if self.poses is None else self.poses[index].copy()
        return StereoFrame(left, right, self.camera, disparity, pose, name=f"{self.path.name}/{name}")

    def ground_truth_path(self, index: int) -> Path:
        """Path of frame ``index``'s ground-truth disparity ``disp/NNNNNN.png``, whether or not it exists."""
        return self.path / "disp" / self.names[range(len(self))[index]]

    def disparity_gt(self, index: int) -> np.ndarray:
        """Frame ``index``'s ground truth from ``disp/``: (H, W) float32, pixels, NaN = unknown.

        Its size must be the images' (checked on opening); the images are not decoded.
        """
        path = self.ground_truth_path(index)
        disparity = read_disparity_png(path, "ground-truth disparity", dtype=np.uint16, scale=_DISPARITY_SCALE)
        size = (self.camera.height, self.camera.width)
        if disparity.shape != size:
            raise PrismapInputError(f"{path}: size {disparity.shape} differs from the images' {size}")
        return disparity


def _kitti_odometry_pose_path(path):
    """``ROOT/poses/NN.txt`` if ``path`` is ``ROOT/sequences/NN`` and that file exists, else None.

    The path is made absolute without resolving symbolic links, so it is recognised as the user wrote it.
    """
    path = Path(os.path.abspath(path))
    if path.parent.name != "sequences" or not path.name.isdigit():
        return None
    pose_path = path.parent.parent / "poses" / f"{path.name}.txt"
    return pose_path if pose_path.is_file() else None


def read_sequence(path: str | os.PathLike[str]) -> Sequence:
    """Open a sequence directory written by :func:`write_sequence`, or a KITTI odometry ``ROOT/sequences/NN``.

    Poses come from ``poses.txt`` (image_2 camera), else, in a KITTI odometry tree, from ``ROOT/poses/NN.txt``
    (camera 0, converted to the image_2 camera); see the module docstring and :class:`Sequence`.

    Checks eagerly: the images exist in pairs with one size (PNG headers only), ``calib.txt`` has P2 and P3, the
    pose file (if any) has 12 finite numbers per line and one line per frame (KITTI's also orthonormal
    rotations). Images are decoded when a frame is accessed. Errors are :class:`PrismapInputError` naming the
    file (and line).
    """
    return Sequence(path)
