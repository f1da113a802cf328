"""Velodyne scans as KITTI stores them: float32 (x, y, z, reflectance) records, sensor frame."""

import numpy as np

from prismap._validate import as_float_array
from prismap.errors import PrismapInputError
from prismap.io._text import read_bytes

_RECORD_BYTES = 16


def read_velodyne_bin(path):
    """Read one KITTI ``velodyne/NNNNNN.bin`` scan.

    Parameters
    ----------
    path : str or Path
        Raw little-endian float32 records of 4 values each (16 bytes per point).

    Returns
    -------
    (N, 4) float32
        ``x, y, z`` in metres in the Velodyne frame (x forward, y left, z up) and the
        reflectance in [0, 1].

    Raises
    ------
    PrismapInputError
        The file is missing, its size is not a multiple of 16 bytes, or a value is NaN or infinite.
    """
    raw = read_bytes(path, "velodyne scan")
    if len(raw) % _RECORD_BYTES:
        raise PrismapInputError(
            f"{path}: velodyne scan size must be a multiple of {_RECORD_BYTES} bytes (x, y, z, reflectance "
            f"float32); got {len(raw)} bytes"
        )
    points = np.frombuffer(raw, dtype="<f4").reshape(-1, 4).astype(np.float32)
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise PrismapInputError(f"{path}: velodyne point {int(np.argmax(bad))} is not finite (NaN or infinity)")
    return points


def velodyne_to_camera(points_velo, T_cam_velo):
    """Move Velodyne points into a camera frame.

    Parameters
    ----------
    points_velo : (N, 3) or (N, 4) float, metres, Velodyne frame
        A fourth (reflectance) column is ignored.
    T_cam_velo : (4, 4) float
        Velodyne-to-camera transform, e.g. ``KittiOdometry.T_cam_velo``.

    Returns
    -------
    (N, 3) float64, metres, camera frame (OpenCV axes).
    """
    points = as_float_array(points_velo, "points_velo", ndim=2)
    if points.shape[1] not in (3, 4):
        raise PrismapInputError(f"`points_velo` must have shape (N, 3) or (N, 4); got {points.shape}")
    T = as_float_array(T_cam_velo, "T_cam_velo", shape=(4, 4), allow_nan=False)
    return points[:, :3] @ T[:3, :3].T + T[:3, 3]


def points_to_disparity(points_cam, camera):
    """Sparse ground-truth disparity of the left image from 3-D points, e.g. a Velodyne scan (thesis fig. 3.16).

    Every point in front of the camera is projected with the pinhole model to the pixel whose centre is
    nearest (centres at integer ``(u, v)``, as in :meth:`StereoCamera.pixel_rays`); where several points
    fall into one pixel the nearest one (smallest depth) is kept, since it hides the others. Its disparity is
    ``f b / z - doffs``.

    Parameters
    ----------
    points_cam : (N, 3) float, metres, left camera frame (OpenCV axes)
        E.g. ``KittiOdometry.velodyne(i)``.
    camera : StereoCamera
        With ``width`` and ``height``.

    Returns
    -------
    (H, W) float32, pixels, NaN where no point projects.
    """
    points = as_float_array(points_cam, "points_cam", shape=(None, 3), allow_nan=False)
    if camera.width is None or camera.height is None:
        raise PrismapInputError("`camera` needs its image size (width, height) to project points into its image")
    points = points[points[:, 2] > 0]
    z = points[:, 2]
    u, v = camera.project(points)
    col, row = np.floor(u + 0.5), np.floor(v + 0.5)
    inside = (col >= 0) & (col < camera.width) & (row >= 0) & (row < camera.height)
    depth = np.full(camera.height * camera.width, np.inf)
    np.minimum.at(depth, (row[inside] * camera.width + col[inside]).astype(np.int64), z[inside])
    return camera.disparity_from_depth(depth.reshape(camera.height, camera.width)).astype(np.float32)
