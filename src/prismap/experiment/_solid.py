"""How deep the solid behind a ray's first surface reaches, measured on a box world's exact geometry.

PRISM's ``solid_depth_m`` (docs/SENSOR_MODELS.md, "Solid depth") is a property of the world, like ``p0`` and
``pass_through``: the experiments measure it from the ground truth of the characterisation frames.
"""

import numpy as np

from prismap._validate import as_float_array, check_positive
from prismap.errors import PrismapInputError

_STEP_M = 1e-6  # how far past a box's exit face the march looks for the next box (metres)
_ENTRY_M = 1e-3  # the march starts this far behind the hit: a depth from a float32 disparity misses the face by up to ~1e-4 m
_MAX_BOXES = 64  # most boxes one ray marches through before its depth counts as ``cap_m``


def solid_depth_along_rays(box_lo, box_hi, origins_w, directions_w, hit_m, *, cap_m):
    """Distance behind each ray's hit over which the ray stays inside the union of closed boxes.

    From 1 mm behind the hit point (a depth from float32 disparities misses the face) the ray is followed
    through every box that contains it (slab exit distances), box after box while the next point is inside
    another one, up to ``cap_m``.

    Parameters
    ----------
    box_lo, box_hi : (B, 3) float, metres, world frame
    origins_w : (R, 3) float, metres, world frame
    directions_w : (R, 3) float, world frame, unit
    hit_m : (R,) float, metres along each ray to its first surface
    cap_m : float > 0, metres

    Returns
    -------
    (R,) float64, metres, in ``[0, cap_m]``: 0 where the hit point lies in no box.
    """
    lo = as_float_array(box_lo, "box_lo", shape=(None, 3), allow_nan=False)
    hi = as_float_array(box_hi, "box_hi", shape=lo.shape, allow_nan=False)
    origins = as_float_array(origins_w, "origins_w", shape=(None, 3), allow_nan=False)
    directions = as_float_array(directions_w, "directions_w", shape=origins.shape, allow_nan=False)
    hit = as_float_array(hit_m, "hit_m", shape=(origins.shape[0],), allow_nan=False)
    cap = check_positive(cap_m, "cap_m")
    if directions.size and np.abs(np.linalg.norm(directions, axis=1) - 1.0).max() > 1e-6:
        raise PrismapInputError("`directions_w` must be unit vectors")
    t = hit + _ENTRY_M
    active = np.ones(hit.size, dtype=bool)
    entered = np.zeros(hit.size, dtype=bool)
    tolerance = 1e-9 * max(1.0, float(np.abs(lo).max(initial=0.0)), float(np.abs(hi).max(initial=0.0)))
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / directions
    for _ in range(_MAX_BOXES):
        rows = np.flatnonzero(active)
        if rows.size == 0:
            break
        points = origins[rows] + t[rows, None] * directions[rows]
        inside = np.all((points[:, None, :] >= lo - tolerance) & (points[:, None, :] <= hi + tolerance), axis=2)
        # exit distance of each box along the ray (slab method): the nearest face ahead on each axis
        face = np.where(directions[rows, None, :] > 0, hi, lo)
        exit_axis = np.where(directions[rows, None, :] != 0, (face - points[:, None, :]) * inverse[rows, None, :], np.inf)
        exit_m = np.where(inside, exit_axis.min(axis=2), -np.inf).max(axis=1)
        stop = ~np.isfinite(exit_m)  # in no box (or in none along this ray)
        t[rows[~stop]] += np.maximum(exit_m[~stop], 0.0) + _STEP_M
        entered[rows[~stop]] = True
        active[rows[stop]] = False
        active &= t - hit < cap
    return np.where(entered, np.clip(t - hit, 0.0, cap), 0.0)


SOLID_DEPTH_QUANTILE = 0.1
"""PRISM's ``solid_depth_m`` in the experiments: the depth of solid behind all but this share of the
characterisation frames' noise-free hits (a depth most first surfaces really have behind them)."""

SOLID_DEPTH_CAP_VOXELS = 8.0
"""Longest solid depth measured (voxels; the overhang's cap): beyond it a ray's solid no longer matters."""


def measured_solid_depth(box_lo, box_hi, frames, voxel_size_m, *, max_depth_m=np.inf, subsample=1,
                         quantile=SOLID_DEPTH_QUANTILE):
    """PRISM's ``solid_depth_m`` of a box world: the ``quantile`` of the solid depth behind noise-free hits.

    Every ``subsample``-th pixel of each frame whose true surface lies within ``max_depth_m`` (camera depth)
    is cast to that surface (``extras["depth_m"]`` when the frame has it, else from ``disparity_gt``), and
    :func:`solid_depth_along_rays` measures how far the solid reaches behind it (at most
    :data:`SOLID_DEPTH_CAP_VOXELS` voxels).

    Parameters
    ----------
    box_lo, box_hi : (B, 3) float, metres, world frame
    frames : sequence of StereoFrame with ``camera``, ``T_world_cam`` and ``disparity_gt``
    voxel_size_m : float, metres
    max_depth_m : float, metres of camera depth
    subsample : int >= 1, pixel step
    quantile : float in [0, 1]

    Returns
    -------
    float, metres along the ray
    """
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    depths = []
    for frame in frames:
        depth = frame.extras.get("depth_m") if getattr(frame, "extras", None) else None
        if depth is None:
            depth = frame.camera.depth_from_disparity(frame.disparity_gt)
        depth = np.asarray(depth, dtype=np.float64)[::subsample, ::subsample].reshape(-1)
        rays_cam = frame.camera.pixel_rays(frame.disparity_gt.shape)[::subsample, ::subsample].reshape(-1, 3)
        hit = np.isfinite(depth) & (depth <= max_depth_m)
        norm = np.linalg.norm(rays_cam[hit], axis=1)
        pose = np.asarray(frame.T_world_cam, dtype=np.float64)
        directions = (rays_cam[hit] / norm[:, None]) @ pose[:3, :3].T
        depths.append(solid_depth_along_rays(box_lo, box_hi, np.broadcast_to(pose[:3, 3], directions.shape),
                                             directions, depth[hit] * norm, cap_m=SOLID_DEPTH_CAP_VOXELS * voxel))
    depths = np.concatenate(depths) if depths else np.empty(0)
    if depths.size == 0:
        raise PrismapInputError("no ray of `frames` meets a surface within `max_depth_m`: no solid depth")
    return float(np.quantile(depths, quantile))
