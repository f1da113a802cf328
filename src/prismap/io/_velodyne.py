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
