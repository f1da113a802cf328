"""Reference occupancy from LiDAR scans (thesis sec. 6.3.3): noise-free rays, OctoMap's hit/miss rule."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import numpy.typing as npt

from prismap._progress import progress as progress_bar
from prismap._validate import as_float_array, check_positive
from prismap.camera import StereoCamera
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap
from prismap.io import GroundTruthOccupancy, KittiOdometry, KittiRaw
from prismap.sensor_models import make_sensor_model

LIDAR_P0 = 0.5
"""Prior of the reference map: OctoMap's uninformed 0.5, so one hit in a scan makes a voxel occupied."""


def lidar_reference_map(
    scans: Iterable[tuple[np.ndarray, np.ndarray]],
    voxel_size_m: float,
    *,
    max_range_m: float = np.inf,
    p_hit: float = 0.7,
    p_miss: float = 0.4,
    progress: bool = True,
) -> OccupancyMap:
    """Integrate LiDAR scans into a map with the noise-free hit/miss model (OctoMap's ``insertPointCloud``).

    Each point is a ray from the sensor origin; the voxel holding the point gets ``logit(p_hit)``, the
    voxels the ray crosses before it ``logit(p_miss)``, and within a scan a voxel that is some ray's
    end stays occupied (``occupied-wins``). Each scan is one batch of ranges along unit rays
    (:meth:`OccupancyMap.integrate_rays` with ``kind="range"``) for a hit/miss model of ranges.

    Parameters
    ----------
    scans : iterable of (points, T_world_sensor)
        ``points`` (N, 3) float (or (N, 4) with reflectance, ignored), metres, sensor frame;
        ``T_world_sensor`` (4, 4) float, sensor -> world.
    voxel_size_m : float, metres
    max_range_m : float, metres
        Points farther than this only clear free space up to it.
    p_hit, p_miss : float
        OctoMap's defaults.

    Returns
    -------
    OccupancyMap
        Prior :data:`LIDAR_P0`; one frame per scan.

    Notes
    -----
    The thesis's "ideal" sensor is noise-free; the ideal ISM evaluated at cell centres would miss the
    end voxel of a ray that crosses it diagonally (centre farther than ``alpha / 2`` from the point
    along the ray), so the hit/miss rule, which marks exactly the voxel holding the point, is used.
    """
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    grid = OccupancyMap(voxel, p0=LIDAR_P0)
    model = make_sensor_model(
        "hitmiss", measurement="range", voxel_size_m=voxel, p0=LIDAR_P0, p_hit=p_hit, p_miss=p_miss
    )
    total = len(scans) if hasattr(scans, "__len__") else None
    for index, scan in enumerate(
        progress_bar(scans, total=total, desc="lidar", unit="scan", enabled=None if progress else False)
    ):
        try:
            points, pose = scan
        except (TypeError, ValueError):
            raise PrismapInputError(f"`scans[{index}]` must be a (points, T_world_sensor) pair") from None
        points = as_float_array(points, f"scans[{index}] points", ndim=2, allow_nan=False)
        if points.shape[1] not in (3, 4):
            raise PrismapInputError(f"`scans[{index}]` points must be (N, 3) or (N, 4); got {points.shape}")
        pose = as_float_array(pose, f"scans[{index}] T_world_sensor", shape=(4, 4), allow_nan=False)
        offsets_w = points[:, :3] @ pose[:3, :3].T
        ranges = np.sqrt((offsets_w**2).sum(axis=1))
        keep = ranges > 0
        grid.integrate_rays(
            pose[:3, 3],
            offsets_w[keep] / ranges[keep, None],
            ranges[keep],
            model,
            kind="range",
            policy="occupied-wins",
            max_range_m=max_range_m,
        )
    if grid.n_frames == 0:
        raise PrismapInputError("`scans` is empty: a reference map needs at least one scan")
    return grid


def ground_truth_from_map(grid: OccupancyMap) -> GroundTruthOccupancy:
    """A reference map as ground truth: occupied = ``P > 0.5``, evaluated region = the known voxels.

    Parameters
    ----------
    grid : OccupancyMap
        E.g. from :func:`lidar_reference_map`.

    Returns
    -------
    GroundTruthOccupancy
        Write it with :func:`prismap.io.write_ground_truth`; ``prismap evaluate --gt FILE``
        reads it.
    """
    if not isinstance(grid, OccupancyMap):
        raise PrismapInputError(f"`grid` must be an OccupancyMap; got {type(grid).__name__}")
    keys, log, _ = grid.known_voxels()
    occupied = log > 0.0  # P > 0.5
    return GroundTruthOccupancy(grid.voxel_size_m, keys[occupied].astype(np.int64), keys.astype(np.int64))


class KittiLidarScans(Sequence):
    """The Velodyne scans of a KITTI sequence as lazy ``(points, T_world_sensor)`` pairs.

    Made by :func:`kitti_lidar_scans`; ``scans[i]`` reads the i-th chosen frame's scan from disk, so a
    long drive is never held in memory. Feed it to :func:`lidar_reference_map`.
    """

    def __init__(
        self, sequence: KittiOdometry | KittiRaw, frames: Sequence[int], poses: np.ndarray, camera: StereoCamera | None
    ) -> None:
        self._sequence = sequence
        self._frames = frames
        self._poses = poses
        self._camera = camera
        self._T_cam_sensor = np.eye(4)
        self._T_cam_sensor[:3, 3] = sequence.T_cam_velo[:3, 3]  # the Velodyne's origin, the camera's axes

    def __len__(self):
        return len(self._frames)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        frame = self._frames[index]
        points_cam = self._sequence.velodyne(frame)
        if self._camera is not None:
            points_cam = points_cam[in_camera_view(points_cam, self._camera)]
        return points_cam - self._T_cam_sensor[:3, 3], self._poses[frame] @ self._T_cam_sensor


def kitti_lidar_scans(
    sequence: KittiOdometry | KittiRaw,
    *,
    frames: Iterable[int] | None = None,
    poses: npt.ArrayLike | None = None,
    camera_view: bool = True,
) -> KittiLidarScans:
    """The Velodyne scans of a KITTI odometry sequence or raw drive, posed in the colour camera's world.

    Parameters
    ----------
    sequence : KittiOdometry or KittiRaw
        Needs its Velodyne transform (``T_cam_velo``) and the ``velodyne/`` scans of the chosen frames.
    frames : sequence of int or None, keyword-only
        Frame indices to use (default every frame).
    poses : (N, 4, 4) float or None, metres, keyword-only
        ``T_world_cam`` of the left colour camera for every frame of ``sequence`` (prismap's
        ``poses.txt`` convention); default ``sequence.poses`` (odometry ``poses/NN.txt``, converted
        from camera 0). Raw drives have no poses, so they need this.
    camera_view : bool, keyword-only
        Keep only the points in front of the colour camera that project into its image (see
        :func:`in_camera_view`), i.e. the part of the 360-degree scan a stereo map can observe.

    Returns
    -------
    KittiLidarScans
        ``scans[i] = (points (M, 3) float64, metres, sensor frame; T_world_sensor (4, 4))``. The sensor
        frame has the camera's axes and the Velodyne's origin (``points_cam - t_cam_velo``), so
        :func:`lidar_reference_map` casts each ray from the laser, not from the camera.
    """
    count = len(sequence)
    if poses is None:
        poses = sequence.poses
        if poses is None:
            raise PrismapInputError(
                "the KITTI sequence has no poses (raw drives carry none; odometry has poses/NN.txt for 00-10): "
                "give `poses`, T_world_cam of the left colour camera per frame"
            )
    poses = as_float_array(poses, "poses", ndim=3, allow_nan=False)
    if poses.shape != (count, 4, 4):
        raise PrismapInputError(
            f"`poses` must be ({count}, 4, 4), one pose per frame of the sequence; got {poses.shape}"
        )
    frames = list(range(count)) if frames is None else [int(i) for i in frames]
    if not frames:
        raise PrismapInputError("`frames` is empty: a reference map needs at least one scan")
    bad = [i for i in frames if not 0 <= i < count]
    if bad:
        raise PrismapInputError(f"`frames` must lie in 0..{count - 1} (the sequence's frames); got {bad[0]}")
    camera = None
    if camera_view:
        camera = sequence.camera
        if camera.width is None or camera.height is None:
            camera = sequence[frames[0]].camera  # the image size comes with the images
    return KittiLidarScans(sequence, frames, poses, camera)


def in_camera_view(points_cam: npt.ArrayLike, camera: StereoCamera) -> npt.NDArray[np.bool_]:
    """Which points lie in front of a camera and project into its image.

    Parameters
    ----------
    points_cam : (N, 3) float, metres, camera frame
    camera : StereoCamera
        With ``width`` and ``height``; its left (reference) image is used.

    Returns
    -------
    (N,) bool
        ``z > 0`` and the projection ``(u, v)`` within ``[-0.5, W - 0.5) x [-0.5, H - 0.5)`` pixels
        (pixel centres at integers, as in :meth:`StereoCamera.pixel_rays`).
    """
    points = as_float_array(points_cam, "points_cam", ndim=2)
    if points.shape[1] != 3:
        raise PrismapInputError(f"`points_cam` must be (N, 3); got {points.shape}")
    if camera.width is None or camera.height is None:
        raise PrismapInputError("`camera` needs its image size (width, height) to decide what it sees")
    u, v = camera.project(points)  # NaN behind the camera: every comparison below is False there
    return (u >= -0.5) & (u < camera.width - 0.5) & (v >= -0.5) & (v < camera.height - 0.5)
