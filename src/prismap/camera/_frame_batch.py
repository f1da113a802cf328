"""The camera side of mapping: a disparity image seen from a pose becomes the map's :class:`~prismap.grid.RayBatch`.

The map takes measurements along rays and knows nothing of cameras, poses or stereo; this module is where
those meet. For every ``subsample``-th pixel with a valid disparity it makes the camera ray rotated into the
world, and, when asked:

- the disparity noise equivalent to the pose's uncertainty (:func:`pose_noise_px`, thesis sec. 4.4.3);
- the ray's voxel overhang from surface normals fitted to the disparity image (:func:`frame_overhang_m`);
- the image geometry projective integration needs (the pinhole projector, :func:`~prismap.grid.make_projector`).

Voxel overhang. How far in front of a measured surface a voxel the ray crosses can still hold part of that surface.

A map's voxel is occupied when any part of a surface lies in it, but a ray only says where IT meets the
surface. Seen at a grazing angle (a floor, a road, a wall along the street), the ray crosses voxels the
surface plane passes through before it reaches the plane itself: a model that calls every cell before the
hit free carves the floor out of the map. For a locally planar surface with unit normal ``n`` (world
axes) hit at incidence ``cos(theta) = |n . r/|r||``, a voxel of side ``v`` the ray leaves ``t`` metres (along
the ray) before the hit is ``t cos(theta)`` from the plane, and its points reach at most ``v |n|_1`` further
along ``n`` (axis-aligned voxels), so it can hold part of the plane only if ``t <= v |n|_1 / cos(theta)``:
the *overhang*. Models that reason about it (PRISM's ``overhang_fraction``) get it per ray.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba as nb
import numpy as np
import numpy.typing as npt

from prismap._depth import depth_from_disparity
from prismap._validate import as_float_array, check_classes, check_integer
from prismap.camera._stereo_camera import StereoCamera
from prismap.camera._surface import plane_normals
from prismap.errors import PrismapInputError
from prismap.grid import FLOOR_RAYS, OccupancyMap, RayBatch, image_levels, make_projector
from prismap.grid._sensor_model import SensorModel

OVERHANG_CAP_VOXELS = 8.0
"""Largest overhang (voxels): at grazing incidence the bound grows without limit, and across a depth
discontinuity the plane fit leans toward grazing."""


def voxel_overhang_m(
    normals_cam: np.ndarray,
    rays_cam: np.ndarray,
    R_world_cam: np.ndarray,
    voxel_size_m: float,
    *,
    cap_voxels: float = OVERHANG_CAP_VOXELS,
) -> npt.NDArray[np.float64]:
    """The overhang bound ``v |n_w|_1 / cos(theta)`` of each ray, capped (metres along the ray).

    Parameters
    ----------
    normals_cam : (R, 3) float, camera frame, unit (NaN = no normal: overhang 0, the one-dimensional model;
        a one-row image has none, and neither does a pixel whose window is mostly invalid)
    rays_cam : (R, 3) float, camera frame, the rays ``((u - cx)/f, (v - cy)/f, 1)``
    R_world_cam : (3, 3) float, rotation camera -> world (voxels are aligned with the world axes)
    voxel_size_m : float, metres
    cap_voxels : float, voxels

    Returns
    -------
    (R,) float64, metres, in ``[0, cap_voxels * voxel_size_m]``
    """
    return _overhang(
        np.ascontiguousarray(normals_cam, dtype=np.float64),
        np.ascontiguousarray(rays_cam, dtype=np.float64),
        np.ascontiguousarray(R_world_cam, dtype=np.float64),
        float(voxel_size_m),
        float(cap_voxels) * float(voxel_size_m),
    )


def frame_overhang_m(
    disparity_px: npt.ArrayLike,
    camera: StereoCamera,
    R_world_cam: np.ndarray,
    voxel_size_m: float,
    subsample: int,
    rays_cam: np.ndarray,
) -> npt.NDArray[np.float64]:
    """:func:`voxel_overhang_m` of every ``subsample``-th pixel of a disparity image, flattened row by row.

    The normals are fitted on windows of the full image (:func:`prismap.camera.plane_normals`) at those
    pixels; ``rays_cam`` ((R, 3), camera frame) are the same pixels' rays.
    """
    normals = plane_normals(disparity_px, camera, subsample=subsample).reshape(-1, 3)
    return voxel_overhang_m(normals, rays_cam, R_world_cam, voxel_size_m)


@nb.njit(cache=True, nogil=True)
def _overhang(normals, rays, R, voxel, cap):
    out = np.empty(rays.shape[0])
    for k in range(rays.shape[0]):
        nx, ny, nz = normals[k, 0], normals[k, 1], normals[k, 2]
        rx, ry, rz = rays[k, 0], rays[k, 1], rays[k, 2]
        cos_incidence = abs(nx * rx + ny * ry + nz * rz) / np.sqrt(rx * rx + ry * ry + rz * rz)
        extent = 0.0
        for a in range(3):
            extent += abs(R[a, 0] * nx + R[a, 1] * ny + R[a, 2] * nz)
        if not cos_incidence >= 0:  # no normal (NaN)
            out[k] = 0.0
        elif cos_incidence == 0:
            out[k] = cap
        else:
            out[k] = min(voxel * extent / cos_incidence, cap)
    return out


@nb.njit(cache=True, nogil=True)
def rotate_rays(rays, rotation):
    """``rays @ rotation.T`` for (R, 3) rays: numpy's BLAS product of this shape costs ~10x more."""
    out = np.empty_like(rays)
    for i in range(rays.shape[0]):
        x, y, z = rays[i, 0], rays[i, 1], rays[i, 2]
        for a in range(3):
            out[i, a] = rotation[a, 0] * x + rotation[a, 1] * y + rotation[a, 2] * z
    return out


def pose_noise_px(
    disparity: np.ndarray,
    rays_cam: np.ndarray,
    R_world_cam: np.ndarray,
    pose_covariance: npt.ArrayLike,
    focal_baseline: float,
    doffs_px: float,
) -> npt.NDArray[np.float64]:
    """Disparity noise (pixels) equivalent to a pose covariance, per ray (first order).

    A small pose error ``(dt, dtheta)`` (world axes) moves the measured point ``p = z r`` (camera frame) by
    ``-(R^T dt) - (R^T dtheta) x p``; its depth changes by ``dz = -J (R^T dt, R^T dtheta)`` with
    ``J = (0, 0, 1, p_y, -p_x, 0)``, so ``sigma_z^2 = J Sigma_cam J^T`` where
    ``Sigma_cam = diag(R, R)^T Sigma diag(R, R)``. Since ``d + doffs = f b / z``, the equivalent disparity
    noise is ``sigma_d = f b sigma_z / z^2`` at the measured depth ``z``. Lateral displacement of the point is
    not represented (the sensor models are one-dimensional along the ray).

    Parameters
    ----------
    disparity : (R,) float, pixels (NaN = invalid: NaN out)
    rays_cam : (R, 3) float, camera rays ``(x/z, y/z, 1)``
    R_world_cam : (3, 3) float, rotation camera -> world
    pose_covariance : (3, 3) or (6, 6) float, m^2 (and rad^2), world axes
    focal_baseline : float, pixel-metres
    doffs_px : float, pixels

    Returns
    -------
    sigma_px : (R,) float64, ``f b sqrt(J Sigma_cam J^T) / z^2``
    """
    cov = as_float_array(pose_covariance, "pose_covariance", ndim=2, allow_nan=False)
    if cov.shape not in ((3, 3), (6, 6)) or not np.allclose(cov, cov.T) or np.linalg.eigvalsh(cov).min() < -1e-12:
        raise PrismapInputError(
            f"`pose_covariance` must be a symmetric positive semi-definite (3, 3) or (6, 6); got shape {cov.shape}"
        )
    full = np.zeros((6, 6))
    full[: cov.shape[0], : cov.shape[0]] = cov
    rot = np.zeros((6, 6))
    rot[:3, :3] = rot[3:, 3:] = R_world_cam
    cov_cam = rot.T @ full @ rot
    depth = depth_from_disparity(disparity, focal_baseline, doffs_px)
    points = rays_cam * depth[:, None]
    jac = np.zeros((depth.size, 6))
    jac[:, 2] = 1.0
    jac[:, 3] = points[:, 1]
    jac[:, 4] = -points[:, 0]
    sigma_z = np.sqrt(np.einsum("ri,ij,rj->r", jac, cov_cam, jac))
    return focal_baseline * sigma_z / depth**2


def disparity_batch(
    disparity_px: npt.ArrayLike,
    camera: StereoCamera,
    T_world_cam: npt.ArrayLike,
    *,
    subsample: int = 1,
    pose_covariance: npt.ArrayLike | None = None,
    ray_class: npt.ArrayLike | None = None,
    overhang_voxel_m: float | None = None,
    projective: bool = False,
) -> RayBatch:
    """The map's batch of one disparity image seen from pose ``T_world_cam``.

    Parameters
    ----------
    disparity_px : (H, W) float, pixels, NaN = invalid
        Pixels with a non-finite disparity or ``d + doffs <= 0`` become invalid rays (NaN), which the map skips.
    camera : StereoCamera
    T_world_cam : (4, 4) float, metres, camera -> world; must be finite
    subsample : int >= 1
        Use every ``subsample``-th pixel in both directions.
    pose_covariance : (3, 3) or (6, 6) float or None
        Covariance of the camera position (m^2, world axes) or of (position, rotation vector)
        (m^2, rad^2, world axes): each ray's ``extra_noise_px`` (:func:`pose_noise_px`).
    ray_class : (H, W) int or None
        Error-model class of each pixel (-1 = no class).
    overhang_voxel_m : float or None, metres
        Give each ray its voxel overhang for voxels of this size (:func:`frame_overhang_m`; what a model that
        ``takes_voxel_overhang`` needs); None = none.
    projective : bool
        Attach the pinhole projector (:func:`~prismap.grid.make_projector`) projective integration needs.

    Returns
    -------
    RayBatch
        Kind ``"disparity"``, one ray per used pixel in row-major order, from the camera's optical centre, with each
        ray's level in the image's nested sampling (:func:`prismap.grid.image_levels`, for ray mode's floor sampling).
    """
    disparity = as_float_array(disparity_px, "disparity_px", ndim=2)
    pose = as_float_array(T_world_cam, "T_world_cam", shape=(4, 4), allow_nan=False)
    step = check_integer(subsample, "subsample", expected="an integer >= 1", condition=lambda n: n >= 1)
    classes = None
    if ray_class is not None:
        classes = check_classes(ray_class, "ray_class", disparity.shape)[::step, ::step].reshape(-1)
    disparity = disparity[::step, ::step]
    rays_cam = camera.pixel_rays(np.shape(disparity_px))[::step, ::step].reshape(-1, 3)
    d = disparity.reshape(-1).copy()
    d[~(d + camera.doffs_px > 0)] = np.nan
    rotation, origin = pose[:3, :3], pose[:3, 3]
    with ThreadPoolExecutor(max_workers=1) as side:
        overhang = None  # the plane fits run beside the rays' set-up (both in kernels that release the GIL)
        if overhang_voxel_m is not None:
            overhang = side.submit(frame_overhang_m, disparity_px, camera, rotation, overhang_voxel_m, step, rays_cam)
        noise = None
        if pose_covariance is not None:
            noise = pose_noise_px(d, rays_cam, rotation, pose_covariance, camera.focal_baseline, camera.doffs_px)
        image = None
        if projective:
            ray_index = np.arange(d.size, dtype=np.int32).reshape(disparity.shape)
            image = make_projector(
                "pinhole",
                R_cam_world=np.ascontiguousarray(rotation.T),
                focal_px=camera.focal_px,
                cx_px=camera.cx_px,
                cy_px=camera.cy_px,
                subsample=step,
                ray_index=ray_index,
            )
        rays_w = rotate_rays(np.ascontiguousarray(rays_cam), np.ascontiguousarray(rotation))
        overhang = None if overhang is None else overhang.result()
    levels = image_levels(*disparity.shape, step / camera.focal_px)
    return RayBatch(origin, rays_w, d, None, noise, classes, image, overhang, levels=levels)


def integrate_disparity(
    grid: OccupancyMap,
    disparity_px: npt.ArrayLike,
    camera: StereoCamera,
    T_world_cam: npt.ArrayLike,
    model: SensorModel,
    *,
    mode: str = "ray",
    policy: str | None = None,
    max_range_m: float = np.inf,
    subsample: int = 1,
    pose_covariance: npt.ArrayLike | None = None,
    ray_class: npt.ArrayLike | None = None,
    floor_rays: int = FLOOR_RAYS,
) -> None:
    """Integrate one disparity image seen from pose ``T_world_cam`` into ``grid``.

    :func:`disparity_batch` with what ``model`` and ``mode`` need (the voxel overhang of the map's voxels for a
    model that ``takes_voxel_overhang``, the image geometry in projective mode), then
    :meth:`prismap.grid.OccupancyMap.integrate`.

    Parameters
    ----------
    grid : OccupancyMap
        A 3-D map.
    disparity_px, camera, T_world_cam, subsample, pose_covariance, ray_class
        See :func:`disparity_batch`.
    model : InverseSensorModel
    mode : {"ray", "projective"}
        ``ray`` casts every pixel's ray through the grid (the cells at a ray's failure floor by a nested subsample of
        the pixels, ``floor_rays``); ``projective`` visits the voxels of the camera frustum
        (up to where the measurements stop influencing), projects each centre into the image and updates it once
        from the pixel it lands on.
    policy, max_range_m, floor_rays
        See :meth:`prismap.grid.OccupancyMap.integrate`.
    """
    if grid.ndim != 3:
        raise PrismapInputError(
            "`integrate_disparity` needs a 3-D map; a 2-D map takes rays in the plane: `OccupancyMap.integrate_rays`"
        )
    overhang = grid.voxel_size_m if model.takes_voxel_overhang else None
    batch = disparity_batch(
        disparity_px,
        camera,
        T_world_cam,
        subsample=subsample,
        pose_covariance=pose_covariance,
        ray_class=ray_class,
        overhang_voxel_m=overhang,
        projective=mode == "projective",
    )
    grid.integrate(batch, model, mode=mode, policy=policy, max_range_m=max_range_m, floor_rays=floor_rays)
