"""Exact ground-truth occupancy of box worlds: solid voxels, and the voxels a perfect sensor observes."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_integer, check_positive
from prismap.camera import frame_overhang_m
from prismap.errors import PrismapInputError
from prismap.grid import crossed_voxels, point_to_key
from prismap.io._sequence import GroundTruthOccupancy
from prismap.sim._kernels import mark_visible, occupied_before_per_ray


def solid_key_ranges(box_lo, box_hi, voxel_size_m):
    """Inclusive key ranges ``(lo, hi)`` ((B, D) int64 each) of closed boxes: keys ``floor(p / voxel)`` of their points.

    A voxel is the half-open cube ``[k s, (k + 1) s)``; a box ``[lo, hi]`` is closed, so a face lying exactly
    on a voxel boundary marks the voxel beyond it too: that is where ``floor`` puts a ray hit on that face.
    """
    return point_to_key(box_lo, voxel_size_m), point_to_key(box_hi, voxel_size_m)


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
            seen,
            bounds_lo,
            voxel,
            0.0 if planar else np.nan,
            np.ascontiguousarray(pose[:3, :3]),
            np.ascontiguousarray(pose[:3, 3]),
            camera.focal_px,
            camera.cx_px,
            camera.cy_px,
            np.where(np.isnan(depth), np.inf, depth),
            max_depth,
        )
        hit = np.isfinite(depth) & (depth <= max_depth)
        points_w = (camera.pixel_rays(depth.shape)[hit] * depth[hit, None]) @ pose[:3, :3].T + pose[:3, 3]
        keys = point_to_key(points_w, voxel) - bounds_lo
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
        raise PrismapInputError(
            f"`voxel_size_m` = {voxel_size_m} gives {shape} voxels over the world: choose a larger one"
        )
    occupied = np.zeros(shape, dtype=np.bool_)
    for lo, hi in zip(key_lo - bounds_lo, key_hi - bounds_lo):
        if planar:
            lo[2], hi[2] = 0, 0
        occupied[lo[0] : hi[0] + 1, lo[1] : hi[1] + 1, lo[2] : hi[2] + 1] = True
    return occupied, bounds_lo


def pass_through_ratio(
    box_lo, box_hi, frames, voxel_size_m, *, max_depth_m=np.inf, subsample=1, ray_classes=None, n_classes=None
):
    """How often a ray crosses an occupied voxel without meeting its surface there: PRISM's ``pass_through``.

    A voxel is occupied when any part of a solid lies in it, so a ray can cross one and go on (a table's
    edge, a pole's side, a kerb). Each noise-free ray (every ``subsample``-th pixel, true depth within
    ``max_depth_m``) is cast to its surface; the occupied voxels it leaves more than its voxel overhang
    (:func:`prismap.grid.frame_overhang_m`, from the true disparity) before the surface are passes (the
    voxels within the overhang may hold the hit surface itself, which the overhang models). With surfaces
    that stop a ray with probability ``h`` each, a ray passes ``(1 - h) / h`` of them on average before its
    hit, so ``1 - h = passes / (passes + rays)``.

    With ``ray_classes`` the ratio is taken over the rays of each pixel class apart: passes crowd at the
    silhouettes of solids (the box edges a ray grazes on its way to the wall behind), which a conditioned
    error model's classes pick out by the distance to the nearest disparity discontinuity, so a
    conditioned PRISM gives each class its own ratio (``class_pass_through``). A class's ratio is the posterior
    mean under Jeffreys' prior, ``(passes + 1/2) / (passes + rays + 1)``: a class whose rays never passed an
    occupied voxel (tens of thousands of rays far from every silhouette) still bounds a ray's free evidence
    instead of claiming certainty.

    Parameters
    ----------
    box_lo, box_hi : (B, 3) float, metres, world frame
    frames : iterable of frames as for :func:`ground_truth`
    voxel_size_m : float, metres
    max_depth_m : float, metres of camera depth
    subsample : int >= 1, pixel step
    ray_classes : sequence of (H, W) int arrays or None
        One per frame: the class of each pixel (-1 = none), e.g.
        :meth:`prismap.characterise.ErrorModel.classify_frame` of the matcher's disparity of that frame.
    n_classes : int >= 1 or None
        Number of classes (with ``ray_classes`` only).

    Returns
    -------
    float in [0, 1), or with ``ray_classes`` (n_classes,) float64 in (0, 1): the ratio of each class's rays;
    a class none of whose rays meets a surface takes the ratio of all rays.
    """
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    step = check_integer(subsample, "subsample", expected="an integer >= 1", condition=lambda n: n >= 1)
    frames = list(frames)
    labels = _ray_class_labels(ray_classes, n_classes, frames)
    n_bins = 1 if labels is None else n_classes + 1  # the last bin: pixels without a class
    occupied, bounds_lo = _occupied_volume(box_lo, box_hi, voxel, False)
    passes, rays_hit = np.zeros(n_bins, dtype=np.int64), np.zeros(n_bins, dtype=np.int64)
    for index, frame in enumerate(frames):
        camera, pose, depth = _true_view(index, frame)
        depth = np.where(np.isnan(depth), np.inf, depth)[::step, ::step].reshape(-1)
        rays_cam = camera.pixel_rays(frame.disparity_gt.shape)[::step, ::step].reshape(-1, 3)
        overhang = frame_overhang_m(frame.disparity_gt, camera, pose[:3, :3], voxel, step, rays_cam)
        hit = depth <= max_depth_m
        ray, keys, _, t_out = crossed_voxels(pose[:3, 3], rays_cam @ pose[:3, :3].T, np.where(hit, depth, 0.0), voxel)
        limit = depth - overhang / np.sqrt((rays_cam**2).sum(axis=1))
        per_ray = occupied_before_per_ray(occupied, bounds_lo, ray, keys, t_out, limit, depth.size)
        label = np.zeros(depth.size, dtype=np.int64) if labels is None else labels[index][::step, ::step].reshape(-1)
        label = np.where(label < 0, n_bins - 1, label)
        passes += np.bincount(label, weights=per_ray, minlength=n_bins).astype(np.int64)
        rays_hit += np.bincount(label[hit], minlength=n_bins)
    if rays_hit.sum() == 0:
        raise PrismapInputError("no ray of `frames` meets a surface within `max_depth_m`: no pass-through ratio")
    whole = passes.sum() / (passes.sum() + rays_hit.sum())
    if labels is None:
        return float(whole)
    return np.where(rays_hit[:-1] > 0, (passes[:-1] + 0.5) / (passes[:-1] + rays_hit[:-1] + 1.0), whole)


def _ray_class_labels(ray_classes, n_classes, frames):
    """``ray_classes`` as a list of (H, W) int64 arrays checked against ``frames`` and ``n_classes``; None stays None."""
    if ray_classes is None:
        if n_classes is not None:
            raise PrismapInputError(f"`n_classes` ({n_classes!r}) needs `ray_classes`")
        return None
    count = check_integer(
        n_classes, "n_classes", expected="an integer >= 1 with `ray_classes`", condition=lambda n: n >= 1
    )
    labels = list(ray_classes)
    if len(labels) != len(frames):
        raise PrismapInputError(f"`ray_classes` must hold one array per frame ({len(frames)}); got {len(labels)}")
    checked = []
    for index, (label, frame) in enumerate(zip(labels, frames)):
        label = np.asarray(label)
        shape = np.shape(frame.disparity_gt)
        if label.shape != shape or not np.issubdtype(label.dtype, np.integer):
            raise PrismapInputError(
                f"`ray_classes[{index}]` must be integers of the frame's shape {shape}; got "
                f"shape {label.shape}, dtype {label.dtype}"
            )
        if label.size and (label.min() < -1 or label.max() >= count):
            raise PrismapInputError(
                f"`ray_classes[{index}]` must lie in [-1, {count - 1}]; got values in [{label.min()}, {label.max()}]"
            )
        checked.append(label.astype(np.int64))
    return checked


_STEP_M = 1e-6  # how far past a box's exit face the march looks for the next box (metres)
_ENTRY_M = (
    1e-3  # the march starts this far behind the hit: a depth from a float32 disparity misses the face by up to ~1e-4 m
)
_MAX_BOXES = 64  # most boxes one ray marches through before its depth counts as ``cap_m``


SOLID_DEPTH_QUANTILE = 0.1
"""PRISM's ``solid_depth_m`` in the experiments: the depth of solid behind all but this share of the
characterisation frames' noise-free hits (a depth most first surfaces really have behind them)."""

SOLID_DEPTH_CAP_VOXELS = 8.0
"""Longest solid depth measured (voxels; the overhang's cap): beyond it a ray's solid no longer matters."""


def solid_depth_along_rays(
    box_lo: npt.ArrayLike,
    box_hi: npt.ArrayLike,
    origins_w: npt.ArrayLike,
    directions_w: npt.ArrayLike,
    hit_m: npt.ArrayLike,
    *,
    cap_m: float,
) -> npt.NDArray[np.float64]:
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
        exit_axis = np.where(
            directions[rows, None, :] != 0, (face - points[:, None, :]) * inverse[rows, None, :], np.inf
        )
        exit_m = np.where(inside, exit_axis.min(axis=2), -np.inf).max(axis=1)
        stop = ~np.isfinite(exit_m)  # in no box (or in none along this ray)
        t[rows[~stop]] += np.maximum(exit_m[~stop], 0.0) + _STEP_M
        entered[rows[~stop]] = True
        active[rows[stop]] = False
        active &= t - hit < cap
    return np.where(entered, np.clip(t - hit, 0.0, cap), 0.0)


def solid_depth(
    box_lo, box_hi, frames, voxel_size_m, *, max_depth_m=np.inf, subsample=1, quantile=SOLID_DEPTH_QUANTILE
):
    """PRISM's ``solid_depth_m`` of a box world: the ``quantile`` of the solid depth behind noise-free hits.

    Surfaces are the faces of solids (docs/SENSOR_MODELS.md, "Solid depth"). Every ``subsample``-th pixel of
    each frame whose true surface lies within ``max_depth_m`` (camera depth) is cast to that surface, and
    :func:`solid_depth_along_rays` measures how far the solid reaches behind it (at most
    :data:`SOLID_DEPTH_CAP_VOXELS` voxels).

    Parameters
    ----------
    box_lo, box_hi : (B, 3) float, metres, world frame
    frames : iterable of frames as for :func:`ground_truth`
    voxel_size_m : float, metres
    max_depth_m : float, metres of camera depth
    subsample : int >= 1, pixel step
    quantile : float in [0, 1]

    Returns
    -------
    float, metres along the ray
    """
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    step = check_integer(subsample, "subsample", expected="an integer >= 1", condition=lambda n: n >= 1)
    depths = []
    for index, frame in enumerate(frames):
        camera, pose, depth = _true_view(index, frame)
        depth = np.asarray(depth, dtype=np.float64)[::step, ::step].reshape(-1)
        rays_cam = camera.pixel_rays(frame.disparity_gt.shape)[::step, ::step].reshape(-1, 3)
        hit = np.isfinite(depth) & (depth <= max_depth_m)
        norm = np.linalg.norm(rays_cam[hit], axis=1)
        directions = (rays_cam[hit] / norm[:, None]) @ pose[:3, :3].T
        depths.append(
            solid_depth_along_rays(
                box_lo,
                box_hi,
                np.broadcast_to(pose[:3, 3], directions.shape),
                directions,
                depth[hit] * norm,
                cap_m=SOLID_DEPTH_CAP_VOXELS * voxel,
            )
        )
    depths = np.concatenate(depths) if depths else np.empty(0)
    if depths.size == 0:
        raise PrismapInputError("no ray of `frames` meets a surface within `max_depth_m`: no solid depth")
    return float(np.quantile(depths, quantile))
