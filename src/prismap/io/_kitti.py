"""Readers of the KITTI odometry, raw and stereo 2012/2015 layouts.

Every failure becomes a :class:`PrismapInputError` naming the file (and line or field) and the problem.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import numpy.typing as npt

from prismap._validate import check_pose
from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.io._frame import LazyFrames, StereoFrame
from prismap.io._images import (
    paired_names,
    png_size,
    read_disparity_png,
    read_pair,
    with_image_size,
)
from prismap.io._text import homogeneous, parse_numbers, read_number_rows, read_text
from prismap.io._velodyne import (
    points_to_disparity,
    read_velodyne_bin,
    velodyne_to_camera,
)

_TEXT_FIELDS = frozenset({"calib_time"})


# ----------------------------------------------------------------------------- KITTI files


def read_kitti_calib(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Read a KITTI calibration file of ``name: numbers`` lines.

    Covers odometry ``calib.txt`` (``P0``..``P3``, optional ``Tr``), raw ``calib_cam_to_cam.txt``
    and ``calib_velo_to_cam.txt``, and stereo 2012/2015 calibration files.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict of str -> (K,) float64
        Every field's numbers in file order; the text field ``calib_time`` is skipped.

    Raises
    ------
    PrismapInputError
        A line without ``name:``, a repeated name, or a value that is not a finite number, named
        with the file and line.
    """
    path = Path(path)
    fields = {}
    for line_no, line in enumerate(read_text(path, "KITTI calibration file").splitlines(), start=1):
        if not line.strip():
            continue
        name, colon, values = line.partition(":")
        name = name.strip()
        if not colon or not name or " " in name:
            raise PrismapInputError(f"{path} line {line_no}: expected 'name: numbers'; got {line.strip()[:60]!r}")
        if name in fields:
            raise PrismapInputError(f"{path} line {line_no}: field {name} appears twice")
        if name not in _TEXT_FIELDS:
            fields[name] = parse_numbers(values, path, line_no, name)
    return fields


def _calib_matrix(calib, path, name, shape):
    if name not in calib:
        raise PrismapInputError(f"{path}: missing field {name}; found {sorted(calib)}")
    values = calib[name]
    count = int(np.prod(shape))
    if values.size != count:
        raise PrismapInputError(f"{path}: field {name} must have {count} numbers; got {values.size}")
    return values.reshape(shape)


def _rectified_pair(calib, path, left, right, *, width=None, height=None):
    """The camera of fields ``left`` and ``right`` of a read calibration file, and the left (3, 4) matrix."""
    P_left = _calib_matrix(calib, path, left, (3, 4))
    P_right = _calib_matrix(calib, path, right, (3, 4))
    try:
        camera = StereoCamera.from_kitti_projections(P_left, P_right, width=width, height=height)
    except PrismapInputError as exc:
        raise PrismapInputError(f"{path}: {exc}") from None
    return camera, P_left


def _T_left_cam0(P_left):
    """Rectified camera-0 -> left-camera transform: ``P = K [I | t]``, so ``x_left = x_cam0 + t``."""
    T = np.eye(4)
    T[:3, 3] = np.linalg.solve(P_left[:, :3], P_left[:, 3])
    return T


def read_kitti_poses(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an odometry ``poses/NN.txt``: one 3x4 row-major camera-to-world pose per line.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    (N, 4, 4) float64
        ``T_world_cam0`` of the left grey camera (camera 0) for each frame, metres; the world is
        camera 0 of the first frame.

    Raises
    ------
    PrismapInputError
        An empty file or line, a line without exactly 12 finite numbers, or a rotation part that is
        not orthonormal within 1e-3, named with the file and line.
    """
    poses = homogeneous(read_number_rows(path, "KITTI pose file", 12, layout="3x4 pose").reshape(-1, 3, 4))
    for index, pose in enumerate(poses):
        check_pose(pose, f"{path} line {index + 1}")
    return poses


def _camera_poses(T_world_cam0, P_camera):
    """Odometry poses of camera 0 as poses of the rectified camera whose projection is ``P_camera``.

    Parameters
    ----------
    T_world_cam0 : (N, 4, 4) float64
        ``poses/NN.txt`` as read by :func:`read_kitti_poses`, metres.
    P_camera : (3, 4) float64
        The camera's row of ``calib.txt`` (``P2`` for the left colour camera), pixels / pixel-metres.

    Returns
    -------
    (N, 4, 4) float64
        ``T_world_cam = T_world_cam0 @ [I | -t]`` with ``t = K^-1 P_camera[:, 3]``, metres; the world stays
        camera 0 of the first frame. The one conversion used by :class:`KittiOdometry` and
        :func:`prismap.io.read_sequence`.
    """
    return T_world_cam0 @ np.linalg.inv(_T_left_cam0(P_camera))


def read_kitti_disparity(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a KITTI stereo 2012/2015 ground-truth disparity (``disp_occ_0/000000_10.png``, ``disp_noc``...).

    Parameters
    ----------
    path : str or Path
        Single-channel uint16 PNG holding ``256 * disparity``, 0 where unknown.

    Returns
    -------
    (H, W) float32, pixels, NaN = unknown

    Raises
    ------
    PrismapInputError
        Missing, not a PNG, truncated or corrupt, or not single-channel uint16 (an 8-bit PNG would
        silently lose the 1/256 px resolution and scale).
    """
    return read_disparity_png(path, "KITTI disparity", dtype=np.uint16, scale=256.0)


# ----------------------------------------------------------------------------- sequences


class _KittiSequence(LazyFrames):
    """Frames of a folder pair read lazily: ``len(seq)``, ``seq[i] -> StereoFrame``."""

    def __init__(self, left_dir, right_dir, velodyne_dir, camera, T_cam_velo, poses, source):
        self._left_dir = Path(left_dir)
        self._right_dir = Path(right_dir)
        self._velodyne_dir = Path(velodyne_dir)
        self._names = paired_names(left_dir, right_dir, "*.png")
        self.camera = camera
        self._T_cam_velo = T_cam_velo
        self._source = source
        if poses is not None and len(poses) != len(self._names):
            raise PrismapInputError(f"{source}: {len(poses)} poses for {len(self._names)} frames")
        self.poses = poses

    def __len__(self):
        return len(self._names)

    def _frame(self, index):
        name = self._names[index]
        left, right = read_pair(self._left_dir / name, self._right_dir / name, colour=True)
        return StereoFrame(
            left=left,
            right=right,
            camera=with_image_size(self.camera, left),
            T_world_cam=None if self.poses is None else self.poses[index].copy(),
            name=f"{self._source}/{Path(name).stem}",
        )

    @property
    def T_cam_velo(self) -> npt.NDArray[np.float64]:
        """(4, 4) float64: Velodyne frame -> left (reference) camera frame, metres."""
        if self._T_cam_velo is None:
            raise PrismapInputError(f"{self._source}: the calibration has no Velodyne transform (Tr)")
        return self._T_cam_velo.copy()

    def velodyne_path(self, index: int) -> Path:
        """Path of frame ``index``'s Velodyne scan (``velodyne/NNNNNN.bin``), whether or not it exists."""
        return self._velodyne_dir / f"{Path(self._names[self._index(index)]).stem}.bin"

    def velodyne(self, index: int) -> npt.NDArray[np.float64]:
        """Velodyne points of frame ``index`` in the left camera frame: (N, 3) float64, metres."""
        return velodyne_to_camera(read_velodyne_bin(self.velodyne_path(index)), self.T_cam_velo)

    def velodyne_disparity(self, index: int) -> npt.NDArray[np.float32]:
        """Sparse ground-truth disparity of frame ``index`` from its Velodyne scan (thesis fig. 3.16).

        Returns
        -------
        (H, W) float32, pixels, NaN where no laser point projects
            :func:`prismap.io.points_to_disparity` of :meth:`velodyne` in the left colour camera; the
            image size comes from the left PNG's header, the images are not decoded.
        """
        height, width = png_size(self._left_dir / self._names[self._index(index)], "left image")
        camera = dataclasses.replace(self.camera, width=width, height=height)
        return points_to_disparity(self.velodyne(index), camera)


class KittiOdometry(_KittiSequence):
    """A KITTI odometry sequence with the colour pair as the stereo camera.

    Parameters
    ----------
    root : str or Path
        Folder holding ``sequences/NN/{image_2,image_3,velodyne,calib.txt}`` and, for sequences
        00-10, ``poses/NN.txt``; or, with ``sequence=None``, the sequence folder itself (poses from
        ``../../poses/NN.txt`` when it sits at ``ROOT/sequences/NN``).
    sequence : int or str or None
        Sequence number (``3`` or ``"03"``); None = ``root`` is the sequence folder.

    Attributes
    ----------
    camera : StereoCamera
        From ``P2`` (left) and ``P3`` (right) of ``calib.txt``.
    poses : (N, 4, 4) float64 or None
        ``T_world_cam`` of the left colour camera (image_2), metres; None without a pose file.

    Notes
    -----
    ``poses/NN.txt`` holds ``T_world_cam0`` of the left grey camera. ``P2 = K [I | t2]`` maps
    rectified camera-0 coordinates into image 2, so ``x_cam2 = x_cam0 + t2`` with
    ``t2 = K^-1 P2[:, 3]`` (about (0.06, 0, 0) m), and ``T_world_cam2 = T_world_cam0 @ [I | -t2]``:
    the colour camera sits 6 cm to the left of camera 0. Likewise the Velodyne transform is
    ``T_cam2_velo = [I | t2] @ Tr``. The world frame stays camera 0 of the first frame.
    """

    def __init__(self, root: str | os.PathLike[str], sequence: str | int | None, *, load_poses: bool = True) -> None:
        root = Path(root)
        if sequence is None:
            absolute = Path(os.path.abspath(root))  # as the user wrote it, links unresolved
            seq_dir, root, number = root, absolute.parent.parent, absolute.name
        else:
            try:
                number = f"{int(sequence):02d}"
            except (TypeError, ValueError):
                raise PrismapInputError(
                    f"`sequence` must be a sequence number like 3 or '03'; got {sequence!r}"
                ) from None
            seq_dir = root / "sequences" / number
        calib_path = seq_dir / "calib.txt"
        calib = read_kitti_calib(calib_path)
        camera, P2 = _rectified_pair(calib, calib_path, "P2", "P3")
        T_cam2_cam0 = _T_left_cam0(P2)
        T_cam_velo = None
        if "Tr" in calib:
            T_cam_velo = T_cam2_cam0 @ homogeneous(_calib_matrix(calib, calib_path, "Tr", (3, 4)))
        poses = None
        pose_path = root / "poses" / f"{number}.txt"
        in_tree = Path(os.path.abspath(seq_dir)).parent.name == "sequences"
        if load_poses and in_tree and pose_path.exists():
            poses = _camera_poses(read_kitti_poses(pose_path), P2)
        super().__init__(
            seq_dir / "image_2", seq_dir / "image_3", seq_dir / "velodyne", camera, T_cam_velo, poses, str(seq_dir)
        )


class KittiRaw(_KittiSequence):
    """A KITTI raw drive (``*_sync``) with the rectified colour pair as the stereo camera.

    Parameters
    ----------
    drive_dir : str or Path
        E.g. ``2011_09_26/2011_09_26_drive_0001_sync`` with ``image_02/data``, ``image_03/data``
        and ``velodyne_points/data``.
    calib_dir : str or Path or None, keyword-only
        Folder of ``calib_cam_to_cam.txt`` and ``calib_velo_to_cam.txt``; default the drive's parent.

    Notes
    -----
    The camera comes from ``P_rect_02`` and ``P_rect_03``. The Velodyne transform is
    ``T_cam2_velo = [I | t2] @ R_rect_00 @ [R | T]`` (``R``, ``T`` from ``calib_velo_to_cam.txt``,
    into unrectified camera 0; ``R_rect_00`` rectifies; ``t2 = K^-1 P_rect_02[:, 3]``). Raw drives
    carry GPS/IMU (oxts) rather than camera poses: ``poses`` is None.
    """

    def __init__(self, drive_dir: str | os.PathLike[str], *, calib_dir: str | os.PathLike[str] | None = None) -> None:
        drive_dir = Path(drive_dir)
        calib_dir = drive_dir.parent if calib_dir is None else Path(calib_dir)
        cam_path = calib_dir / "calib_cam_to_cam.txt"
        velo_path = calib_dir / "calib_velo_to_cam.txt"
        cam = read_kitti_calib(cam_path)
        camera, P2 = _rectified_pair(cam, cam_path, "P_rect_02", "P_rect_03")
        R_rect = np.eye(4)
        R_rect[:3, :3] = _calib_matrix(cam, cam_path, "R_rect_00", (3, 3))
        velo = read_kitti_calib(velo_path)
        T_cam0_velo = np.eye(4)
        T_cam0_velo[:3, :3] = _calib_matrix(velo, velo_path, "R", (3, 3))
        T_cam0_velo[:3, 3] = _calib_matrix(velo, velo_path, "T", (3,))
        T_cam_velo = _T_left_cam0(P2) @ R_rect @ T_cam0_velo
        super().__init__(
            drive_dir / "image_02" / "data",
            drive_dir / "image_03" / "data",
            drive_dir / "velodyne_points" / "data",
            camera,
            T_cam_velo,
            None,
            str(drive_dir),
        )


_STEREO_LAYOUTS = {
    # year: left, right, (calibration folder, left field, right field) in order of preference, (noc, occ)
    2012: ("image_0", "image_1", (("calib", "P0", "P1"),), ("disp_noc", "disp_occ")),
    2015: (
        "image_2",
        "image_3",
        (("calib_cam_to_cam", "P_rect_02", "P_rect_03"), ("calib", "P2", "P3")),
        ("disp_noc_0", "disp_occ_0"),
    ),
}
KITTI_DISPARITIES = ("noc", "occ")


class KittiStereo(LazyFrames):
    """A KITTI stereo 2012 or 2015 training folder: the ``NNNNNN_10`` pairs with their ground truth.

    Parameters
    ----------
    root : str or Path
        ``training/`` of the 2012 download (``image_0``, ``image_1``, ``calib``, ``disp_noc``,
        ``disp_occ``; grey images) or of the 2015 download (``image_2``, ``image_3``,
        ``calib_cam_to_cam`` or ``calib``, ``disp_noc_0``, ``disp_occ_0``; colour images).
    disparity : {"noc", "occ"}, keyword-only
        ``noc``: ground truth only where the pixel is visible in both views (the default: an
        occluded pixel has no correct match); ``occ``: also at occluded pixels.

    Attributes
    ----------
    year : int
        2012 or 2015, from the image folders.
    names : list of str
        Left image names (``NNNNNN_10.png``), sorted; the ``_11`` frames have no ground truth.

    Notes
    -----
    Every frame has its own calibration file ``NNNNNN.txt`` (``P0``/``P1`` of the grey pair in 2012,
    ``P_rect_02``/``P_rect_03`` of the colour pair in 2015) and image size, so each frame carries its
    own camera. Opening checks that every calibration and disparity file exists; files are read when a
    frame is accessed.
    """

    def __init__(self, root: str | os.PathLike[str], *, disparity: str = "noc") -> None:
        if disparity not in KITTI_DISPARITIES:
            raise PrismapInputError(f"`disparity` must be one of {KITTI_DISPARITIES}; got {disparity!r}")
        self.root = Path(root)
        years = [y for y, layout in _STEREO_LAYOUTS.items() if all((self.root / d).is_dir() for d in layout[:2])]
        if not years:
            raise PrismapInputError(
                f"{self.root}: not a KITTI stereo folder (expected image_0/ and image_1/ of 2012, or image_2/ "
                "and image_3/ of 2015)"
            )
        self.year = years[0]
        left, right, calibrations, disparities = _STEREO_LAYOUTS[self.year]
        self._left_dir, self._right_dir = self.root / left, self.root / right
        self.names = paired_names(self._left_dir, self._right_dir, "*_10.png")
        found = [c for c in calibrations if (self.root / c[0]).is_dir()]
        if not found:
            expected = " or ".join(f"{c[0]}/" for c in calibrations)
            raise PrismapInputError(f"{self.root}: KITTI stereo {self.year} folder without calibration: no {expected}")
        calib_dir, self._fields = self.root / found[0][0], found[0][1:]
        self._disparity_dir = self.root / disparities[KITTI_DISPARITIES.index(disparity)]
        if not self._disparity_dir.is_dir():
            raise PrismapInputError(
                f"{self.root}: KITTI stereo {self.year} folder without ground-truth disparities: no "
                f"{self._disparity_dir.name}/ (the testing split has none)"
            )
        self._calib_paths = [calib_dir / f"{name.removesuffix('_10.png')}.txt" for name in self.names]
        missing = [p for p in self._calib_paths if not p.is_file()]
        if missing:
            raise PrismapInputError(f"{calib_dir}: missing {len(missing)} calibration file(s), first {missing[0].name}")

    def __len__(self):
        return len(self.names)

    def _frame(self, index):
        name = self.names[index]
        left, right = read_pair(self._left_dir / name, self._right_dir / name, colour=True)
        calib_path = self._calib_paths[index]
        camera, _ = _rectified_pair(
            read_kitti_calib(calib_path), calib_path, *self._fields, width=left.shape[1], height=left.shape[0]
        )
        return StereoFrame(
            left,
            right,
            camera,
            disparity_gt=self.disparity_gt(index),
            name=f"kitti-stereo-{self.year}/{name.removesuffix('.png')}",
        )

    def ground_truth_path(self, index: int) -> Path:
        """Path of frame ``index``'s ground-truth disparity PNG, whether or not it exists."""
        return self._disparity_dir / self.names[self._index(index)]

    def disparity_gt(self, index: int) -> np.ndarray:
        """Frame ``index``'s ground truth, (H, W) float32, pixels, NaN = unknown; its size must be the image's."""
        path = self.ground_truth_path(index)
        disparity = read_kitti_disparity(path)
        size = png_size(self._left_dir / path.name, "left image")
        if disparity.shape != size:
            raise PrismapInputError(f"{path}: disparity size {disparity.shape} differs from the left image's {size}")
        return disparity
