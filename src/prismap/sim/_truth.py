"""Exact ground-truth occupancy of box worlds: solid voxels, and the voxels a perfect sensor observes."""

import numpy as np

from prismap._validate import check_integer, check_positive
from prismap.errors import PrismapInputError
from prismap.grid import crossed_voxels, frame_overhang_m
from prismap.io._sequence import GroundTruthOccupancy
from prismap.sim._kernels import count_occupied_before, mark_visible


def solid_key_ranges(box_lo, box_hi, voxel_size_m):
    """Inclusive key ranges ``(lo, hi)`` ((B, D) int64 each) of closed boxes: keys ``floor(p / voxel)`` of their points.

    A voxel is the half-open cube ``[k s, (k + 1) s)``; a box ``[lo, hi]`` is closed, so a face lying exactly
    on a voxel boundary marks the voxel beyond it too: that is where ``floor`` puts a ray hit on that face.
    """
    return (
        np.floor(np.asarray(box_lo, dtype=np.float64) / voxel_size_m).astype(np.int64),
        np.floor(np.asarray(box_hi, dtype=np.float64) / voxel_size_m).astype(np.int64),
    )


def ground_truth(box_lo, box_hi, frames, voxel_size_m, *, planar=False, max_depth_m=np.inf):
    """Occupied and observed voxels of a world of closed axis-aligned boxes seen by ``frames``.

    Occupied: every voxel containing a point of a box (boxes are solid, so their inside is occupied too).
    Observed by a frame: (a) voxels whose centre projects (nearest pixel) into the image at a camera depth in
    (0, min(true surface depth at that pixel, ``max_depth_m``)] -- the free space a noise-free sensor sweeps,
    tested like a projective mapper does -- and (b) the voxels holding the visible surface points of the
    pixels (their true hits within ``max_depth_m``). Only voxels inside the boxes' bounding box count.

    Parameters
    ----------
    box_lo, box_hi : (B, 3) float, metres, world frame
    frames : iterable
        Objects with ``camera`` (StereoCamera), ``T_world_cam`` (4, 4) and ``disparity_gt`` (H, W), pixels,
        NaN where nothing is hit. The true depth comes from ``extras["depth_m"]`` (float64, inf = no hit) when
        a frame has it (rendered frames: no float32 rounding), else from ``disparity_gt``.
    voxel_size_m : float, metres
    planar : bool
        2-D world: voxel centres are taken in the sensor plane z = 0 and only the layer z key 0 is used.
    max_depth_m : float, metres of camera depth (z)

    Returns
    -------
    GroundTruthOccupancy
    """
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    max_depth = float(max_depth_m)
    occupied, bounds_lo = _occupied_volume(box_lo, box_hi, voxel, planar)
    shape = occupied.shape
    seen = np.zeros(shape, dtype=np.bool_)
    for index, frame in enumerate(frames):
        camera, pose, depth = _true_view(index, frame)
        mark_visible(
            seen, bounds_lo, voxel, 0.0 if planar else np.nan, np.ascontiguousarray(pose[:3, :3]),
            np.ascontiguousarray(pose[:3, 3]),
            camera.focal_px, camera.cx_px, camera.cy_px, np.where(np.isnan(depth), np.inf, depth), max_depth,
        )
        hit = np.isfinite(depth) & (depth <= max_depth)
        points_w = (camera.pixel_rays(depth.shape)[hit] * depth[hit, None]) @ pose[:3, :3].T + pose[:3, 3]
        keys = np.floor(points_w / voxel).astype(np.int64) - bounds_lo
        if planar:
            keys[:, 2] = 0
        inside = np.all((keys >= 0) & (keys < np.array(shape)), axis=1)
        seen[tuple(keys[inside].T)] = True
    return GroundTruthOccupancy(voxel, np.argwhere(occupied) + bounds_lo, np.argwhere(seen) + bounds_lo)


def _true_view(index, frame):
    """``(camera, T_world_cam (4, 4) float64, true depth (H, W), metres, NaN or inf = no hit)`` of ``frames[index]``.

    The depth is ``extras["depth_m"]`` when the frame has it (rendered frames: no float32 rounding), else
    from ``disparity_gt``.
    """
    if frame.T_world_cam is None or frame.disparity_gt is None:
        raise PrismapInputError(f"`frames[{index}]` needs `T_world_cam` and `disparity_gt` for the ground truth")
    depth = getattr(frame, "extras", {}).get("depth_m")
    if depth is None:
        depth = frame.camera.depth_from_disparity(frame.disparity_gt)
    return frame.camera, np.asarray(frame.T_world_cam, dtype=np.float64), depth


def _occupied_volume(box_lo, box_hi, voxel_size_m, planar):
    """Dense occupancy ``(X, Y, Z) bool`` of the boxes' bounding box (keys from ``bounds_lo``, (3,) int64).

    ``planar``: only the layer z key 0.
    """
    key_lo, key_hi = solid_key_ranges(box_lo, box_hi, voxel_size_m)
    bounds_lo, bounds_hi = key_lo.min(axis=0), key_hi.max(axis=0)
    if planar:
        bounds_lo[2] = bounds_hi[2] = 0
    shape = tuple(int(n) for n in bounds_hi - bounds_lo + 1)
    if np.prod(shape, dtype=np.float64) > 2e8:
        raise PrismapInputError(f"`voxel_size_m` = {voxel_size_m} gives {shape} voxels over the world: choose a larger one")
    occupied = np.zeros(shape, dtype=np.bool_)
    for lo, hi in zip(key_lo - bounds_lo, key_hi - bounds_lo):
        if planar:
            lo[2], hi[2] = 0, 0
        occupied[lo[0] : hi[0] + 1, lo[1] : hi[1] + 1, lo[2] : hi[2] + 1] = True
    return occupied, bounds_lo


def pass_through_ratio(box_lo, box_hi, frames, voxel_size_m, *, max_depth_m=np.inf, subsample=1):
    """How often a ray crosses an occupied voxel without meeting its surface there: PRISM's ``pass_through``.

    A voxel is occupied when any part of a solid lies in it, so a ray can cross one and go on (a table's
    edge, a pole's side, a kerb). Each noise-free ray (every ``subsample``-th pixel, true depth within
    ``max_depth_m``) is cast to its surface; the occupied voxels it leaves more than its voxel overhang
    (:func:`prismap.grid.frame_overhang_m`, from the true disparity) before the surface are passes (the
    voxels within the overhang may hold the hit surface itself, which the overhang models). With surfaces
    that stop a ray with probability ``h`` each, a ray passes ``(1 - h) / h`` of them on average before its
    hit, so ``1 - h = passes / (passes + rays)``.

    Parameters
    ----------
    box_lo, box_hi : (B, 3) float, metres, world frame
    frames : iterable of frames as for :func:`ground_truth`
    voxel_size_m : float, metres
    max_depth_m : float, metres of camera depth
    subsample : int >= 1, pixel step

    Returns
    -------
    float in [0, 1)
    """
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    step = check_integer(subsample, "subsample", expected="an integer >= 1", condition=lambda n: n >= 1)
    occupied, bounds_lo = _occupied_volume(box_lo, box_hi, voxel, False)
    passes = rays_hit = 0
    for index, frame in enumerate(frames):
        camera, pose, depth = _true_view(index, frame)
        depth = np.where(np.isnan(depth), np.inf, depth)[::step, ::step].reshape(-1)
        rays_cam = camera.pixel_rays(frame.disparity_gt.shape)[::step, ::step].reshape(-1, 3)
        overhang = frame_overhang_m(frame.disparity_gt, camera, pose[:3, :3], voxel, step, rays_cam)
        hit = depth <= max_depth_m
        rays_hit += int(hit.sum())
        ray, keys, _, t_out = crossed_voxels(pose[:3, 3], rays_cam @ pose[:3, :3].T, np.where(hit, depth, 0.0), voxel)
        limit = depth - overhang / np.sqrt((rays_cam**2).sum(axis=1))
        passes += count_occupied_before(occupied, bounds_lo, ray, keys, t_out, limit)
    if rays_hit == 0:
        raise PrismapInputError("no ray of `frames` meets a surface within `max_depth_m`: no pass-through ratio")
    return passes / (passes + rays_hit)
