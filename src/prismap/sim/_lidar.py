"""A simulated LiDAR beside the stereo camera: sparse, slightly noisy ranges from its own origin.

The scan is cast from the LiDAR's origin, not the camera's, so it holds points the camera cannot see
(behind an object's edge from the camera's view): the occlusion handling of
:func:`prismap.io.points_to_disparity` is what turns it into ground truth, as on a real rig.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_integer
from prismap.camera import StereoCamera
from prismap.io import StereoFrame, points_to_disparity
from prismap.sim._scene3d import Scene3D

LIDAR_FROM_CAMERA_M = (0.3, -0.25, -0.3)
"""Where the simulated LiDAR sits in the left camera's frame (metres; right, up, behind)."""
BEAMS = 64
"""Rows of the scan (a 64-beam spinning LiDAR's front sector)."""
RANGE_SIGMA_M = 0.02
"""Standard deviation of the range noise (metres; a spinning LiDAR's 2 cm)."""


def lidar_scan(
    scene: Scene3D,
    camera: StereoCamera,
    T_world_cam: npt.ArrayLike,
    *,
    T_cam_lidar: npt.ArrayLike | None = None,
    beams: int = BEAMS,
    columns_per_pixel: float = 1.5,
    range_sigma_m: float = RANGE_SIGMA_M,
    rng: np.random.Generator | int | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """A LiDAR scan covering the camera's view, in the LiDAR's frame.

    The beams are the rows of a pinhole view from the LiDAR's origin with the camera's orientation, 15 %
    wider and taller than the camera's view: ``beams`` rows (sparse, as a LiDAR's rings), ``columns_per_pixel``
    times the camera's columns. Each hit's range gets Gaussian noise of ``range_sigma_m``.

    Parameters
    ----------
    scene : Scene3D
    camera : StereoCamera
        With ``width`` and ``height``.
    T_world_cam : (4, 4) float, the left camera's pose
    T_cam_lidar : (4, 4) float or None
        LiDAR -> camera; None = a translation of :data:`LIDAR_FROM_CAMERA_M`.
    beams : int >= 2
    columns_per_pixel : float > 0
    range_sigma_m : float >= 0, metres
    rng : numpy Generator, int or None

    Returns
    -------
    points_lidar : (N, 3) float64, metres, LiDAR frame (the camera's axes)
    T_cam_lidar : (4, 4) float64
    """
    beams = check_integer(beams, "beams", expected="an integer >= 2", condition=lambda n: n >= 2)
    if T_cam_lidar is None:
        T_cam_lidar = np.eye(4)
        T_cam_lidar[:3, 3] = LIDAR_FROM_CAMERA_M
    T_cam_lidar = as_float_array(T_cam_lidar, "T_cam_lidar", shape=(4, 4), allow_nan=False)
    width = max(2, round(camera.width * 1.15 * columns_per_pixel))
    focal_u = camera.focal_px * columns_per_pixel
    focal_v = camera.focal_px * beams / (camera.height * 1.15)
    # a pinhole with separate horizontal and vertical focal lengths: cast square pixels, then scale v
    view = StereoCamera(
        focal_u,
        (width - 1) / 2,
        (beams - 1) / 2 * focal_u / focal_v,
        camera.baseline_m,
        width=width,
        height=round(beams * focal_u / focal_v),
    )
    rows = np.round(np.arange(beams) * focal_u / focal_v).astype(int)
    rows = rows[rows < view.height]
    depth = scene.cast(view, np.asarray(T_world_cam, float) @ T_cam_lidar)[rows]
    rays = view.pixel_rays()[rows]
    hit = np.isfinite(depth)
    points = rays[hit] * depth[hit, None]
    if range_sigma_m > 0:
        ranges = np.linalg.norm(points, axis=1)
        noisy = ranges + np.random.default_rng(rng).normal(0.0, range_sigma_m, ranges.shape)
        points *= (noisy / ranges)[:, None]
    return points, T_cam_lidar


def lidar_disparity(
    scene: Scene3D,
    frame: StereoFrame,
    *,
    T_cam_lidar: npt.ArrayLike | None = None,
    rng: np.random.Generator | int | None = None,
    **options: Any,
) -> npt.NDArray[np.float32]:
    """The sparse ground-truth disparity a LiDAR beside the camera gives ``frame`` (occlusions handled).

    Parameters
    ----------
    scene : Scene3D
    frame : StereoFrame
        With ``T_world_cam`` and a camera with its image size.
    T_cam_lidar, rng, **options
        See :func:`lidar_scan`.

    Returns
    -------
    (H, W) float32, pixels, NaN where no visible point projects.
    """
    points, T_cam_lidar = lidar_scan(
        scene, frame.camera, frame.T_world_cam, T_cam_lidar=T_cam_lidar, rng=rng, **options
    )
    points_cam = points @ T_cam_lidar[:3, :3].T + T_cam_lidar[:3, 3]
    return points_to_disparity(points_cam, frame.camera, occlusion_window_px=2)
