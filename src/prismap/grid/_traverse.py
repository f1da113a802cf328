"""The voxels rays cross, for callers outside the integrators (queries, ground truth): the traversal, checked."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_positive
from prismap.grid import _kernels_traverse


def crossed_voxels(
    origin_w: npt.ArrayLike, rays_w: npt.ArrayLike, t_stop: npt.ArrayLike, voxel_size_m: float
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int32], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Voxels each ray ``origin_w + t rays_w[i]`` crosses for ``t_in <= t_stop[i]`` (Amanatides & Woo).

    The voxel holding the stop point is included; voxels a ray only touches are not (as the integrators).

    Parameters
    ----------
    origin_w : (3,) float, metres, world frame
    rays_w : (N, 3) float, world frame, finite; ``t`` is in units of each ray's length (unit rays: metres;
        camera rays with z = 1: camera depth)
    t_stop : (N,) float, units of ``t``; NaN, inf or ``<= 0`` casts nothing from that ray
    voxel_size_m : float, metres

    Returns
    -------
    ray_of_cell : (C,) int64, in ray order, nearest cell first
    keys : (C, 3) int32
    t_in, t_out : (C,) float64, where the ray enters and leaves each voxel (units of ``t``)
    """
    origin = as_float_array(origin_w, "origin_w", shape=(3,), allow_nan=False)
    rays = as_float_array(rays_w, "rays_w", shape=(None, 3), allow_nan=False)
    stop = as_float_array(t_stop, "t_stop", shape=(rays.shape[0],))
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    return _kernels_traverse.cast_rays(
        origin, rays, np.where(np.isfinite(stop), stop, 0.0), np.zeros(rays.shape[0], dtype=np.bool_), voxel
    )
