"""How far in front of a measured surface a voxel the ray crosses can still hold part of that surface.

A map's voxel is occupied when any part of a surface lies in it, but a ray only says where IT meets the
surface. Seen at a grazing angle (a floor, a road, a wall along the street), the ray crosses voxels the
surface plane passes through before it reaches the plane itself: a model that calls every cell before the
hit free carves the floor out of the map. For a locally planar surface with unit normal ``n`` (world
axes) hit at incidence ``cos(theta) = |n . r/|r||``, a voxel of side ``v`` the ray leaves ``t`` metres (along
the ray) before the hit is ``t cos(theta)`` from the plane, and its points reach at most ``v |n|_1`` further
along ``n`` (axis-aligned voxels), so it can hold part of the plane only if ``t <= v |n|_1 / cos(theta)``:
the *overhang*. Models that reason about it (PRISM's ``overhang_fraction``) get it per ray.
"""

import numba as nb
import numpy as np

from prismap.camera import plane_normals

OVERHANG_CAP_VOXELS = 8.0
"""Largest overhang (voxels): at grazing incidence the bound grows without limit, and across a depth
discontinuity the plane fit leans toward grazing."""


def voxel_overhang_m(normals_cam, rays_cam, R_world_cam, voxel_size_m, *, cap_voxels=OVERHANG_CAP_VOXELS):
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
    return _overhang(np.ascontiguousarray(normals_cam, dtype=np.float64), np.ascontiguousarray(rays_cam, dtype=np.float64),
                     np.ascontiguousarray(R_world_cam, dtype=np.float64), float(voxel_size_m),
                     float(cap_voxels) * float(voxel_size_m))


def frame_overhang_m(disparity_px, camera, R_world_cam, voxel_size_m, subsample, rays_cam):
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
