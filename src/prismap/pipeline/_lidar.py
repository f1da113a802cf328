"""Reference occupancy from LiDAR scans (thesis sec. 6.3.3): noise-free rays, OctoMap's hit/miss rule."""

import numpy as np

from prismap._progress import progress as progress_bar
from prismap._validate import as_float_array, check_positive
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap
from prismap.io import GroundTruthOccupancy
from prismap.sensor_models import make_sensor_model

LIDAR_P0 = 0.5
"""Prior of the reference map: OctoMap's uninformed 0.5, so one hit in a scan makes a voxel occupied."""

_FOCAL_BASELINE = 1.0
"""Virtual camera's ``f b`` (pixel-metres): a point at range ``r`` gets the disparity ``1 / r``."""


def lidar_reference_map(scans, voxel_size_m, *, max_range_m=np.inf, p_hit=0.7, p_miss=0.4, progress=True):
    """Integrate LiDAR scans into a map with the noise-free hit/miss model (OctoMap's ``insertPointCloud``).

    Each point is a ray from the sensor origin; the voxel holding the point gets ``logit(p_hit)``, the
    voxels the ray crosses before it ``logit(p_miss)``, and within a scan a voxel that is some ray's
    end stays occupied (``occupied-wins``). The rays go through :meth:`OccupancyMap.integrate_rays`
    with unit direction vectors and the disparity ``1 / r`` of a virtual camera with ``f b = 1``, so
    the measured depth is the point's range exactly.

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
    model = make_sensor_model("hitmiss", focal_baseline=_FOCAL_BASELINE, voxel_size_m=voxel, p0=LIDAR_P0,
                              p_hit=p_hit, p_miss=p_miss)
    total = len(scans) if hasattr(scans, "__len__") else None
    for index, scan in enumerate(progress_bar(scans, total=total, desc="lidar", unit="scan",
                                              enabled=None if progress else False)):
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
        grid.integrate_rays(pose[:3, 3], offsets_w[keep] / ranges[keep, None], _FOCAL_BASELINE / ranges[keep],
                            model, policy="occupied-wins", max_range_m=max_range_m)
    if grid.n_frames == 0:
        raise PrismapInputError("`scans` is empty: a reference map needs at least one scan")
    return grid


def ground_truth_from_map(grid):
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
