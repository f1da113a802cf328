"""Camera poses in worlds with z up: OpenCV camera axes (x right, y down, z forward)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array
from prismap.errors import PrismapInputError


def pose_from_heading(
    position_m: npt.ArrayLike, heading_rad: float, *, pitch_rad: float = 0.0
) -> npt.NDArray[np.float64]:
    """``T_world_cam`` of a camera at ``position_m`` looking along ``heading_rad`` in the world x-y plane.

    The heading is measured from world +x towards +y; a positive ``pitch_rad`` tilts the view down. With
    zero pitch the camera z axis is ``(cos h, sin h, 0)``, camera x (right) is ``(sin h, -cos h, 0)`` and
    camera y (down) is world -z.

    Parameters
    ----------
    position_m : (3,) or (2,) float, metres, world frame
        A 2-D position lies in the plane z = 0.
    heading_rad, pitch_rad : float, radians

    Returns
    -------
    T_world_cam : (4, 4) float64
    """
    position = as_float_array(position_m, "position_m", ndim=1, allow_nan=False)
    if position.size not in (2, 3):
        raise PrismapInputError(f"`position_m` must have 2 or 3 entries; got {position.size}")
    heading, pitch = float(heading_rad), float(pitch_rad)
    if not (np.isfinite(heading) and np.isfinite(pitch)):
        raise PrismapInputError(f"heading and pitch must be finite; got {heading_rad!r}, {pitch_rad!r}")
    forward = np.array([np.cos(heading) * np.cos(pitch), np.sin(heading) * np.cos(pitch), -np.sin(pitch)])
    right = np.array([np.sin(heading), -np.cos(heading), 0.0])
    down = np.cross(forward, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, down, forward
    pose[: position.size, 3] = position
    return pose


def poses_from_se2(poses_se2: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """``T_world_cam`` (N, 4, 4) of planar poses ``(x, y, heading)`` (N, 3) (metres, radians) at z = 0."""
    se2 = as_float_array(poses_se2, "poses_se2", shape=(None, 3), allow_nan=False)
    return np.array([pose_from_heading(p[:2], p[2]) for p in se2]).reshape(-1, 4, 4)
