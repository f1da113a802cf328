"""Velodyne scans as KITTI stores them: float32 (x, y, z, reflectance) records, sensor frame."""

from __future__ import annotations

import os

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array
from prismap.camera import DISPARITY_MARGIN_PX, StereoCamera, project_points, visible_points
from prismap.errors import PrismapInputError
from prismap.io._text import read_bytes

_RECORD_BYTES = 16


def read_velodyne_bin(path: str | os.PathLike[str]) -> npt.NDArray[np.float32]:
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


def velodyne_to_camera(points_velo: npt.ArrayLike, T_cam_velo: npt.ArrayLike) -> npt.NDArray[np.float64]:
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


def points_to_disparity(
    points_cam: npt.ArrayLike,
    camera: StereoCamera,
    *,
    occlusion_window_px: int = 0,
    disparity_margin_px: float = DISPARITY_MARGIN_PX,
) -> npt.NDArray[np.float32]:
    """Sparse ground-truth disparity of the left image from 3-D points, e.g. a Velodyne scan (thesis fig. 3.16).

    Every point in front of the camera is projected with the pinhole model to the pixel whose centre is
    nearest (centres at integer ``(u, v)``, as in :meth:`StereoCamera.pixel_rays`); where several points
    fall into one pixel the nearest one (smallest depth) is kept, since it hides the others. Its disparity is
    ``f b / z - doffs``. With ``occlusion_window_px > 0`` a point is also dropped when a point within that
    many pixels has a disparity larger by more than ``disparity_margin_px``: a scan taken from beside the camera
    holds points the camera cannot see, and in a sparse scan nothing else covers their pixels
    (:func:`prismap.camera.visible_points`).

    Parameters
    ----------
    points_cam : (N, 3) float, metres, left camera frame (OpenCV axes)
        E.g. ``KittiOdometry.velodyne(i)``.
    camera : StereoCamera
        With ``width`` and ``height``.
    occlusion_window_px : int >= 0, pixels
        Half-width of the occlusion window; 0 = the per-pixel z-buffer alone.
    disparity_margin_px : float > 0, pixels

    Returns
    -------
    (H, W) float32, pixels, NaN where no visible point projects.
    """
    if camera.width is None or camera.height is None:
        raise PrismapInputError("`camera` needs its image size (width, height) to project points into its image")
    shape = (camera.height, camera.width)
    depth, row, col = project_points(points_cam, camera, shape)[:3]
    keep = visible_points(
        camera.disparity_from_depth(depth),
        row,
        col,
        shape,
        occlusion_window_px=occlusion_window_px,
        disparity_margin_px=disparity_margin_px,
    )
    nearest = np.full(shape, np.inf)
    np.minimum.at(nearest, (row[keep], col[keep]), depth[keep])
    return camera.disparity_from_depth(nearest).astype(np.float32)
