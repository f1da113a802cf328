"""The prior occupancy ``p0`` that PRISM and every other model need: from a ground-truth map, or the value that
maximises the measurements' likelihood under PRISM's forward model (SENSOR_MODELS.md section 5)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from prismap._validate import as_float_array, check_probability
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.sensor_models import _kernels_direct
from prismap.sensor_models._prism import _QUAD_STEP, PrismModel
from prismap.sensor_models._prism_discrete import with_floor


def prior_from_ground_truth(occupied: npt.ArrayLike) -> float:
    """``p0`` as the occupancy ratio of a ground-truth map: the fraction of its known cells that are occupied.

    Parameters
    ----------
    occupied : (N,) bool
        Occupancy of every known cell of a ground-truth map with the target voxel size.

    Returns
    -------
    float in (0, 1), kept at least ``1 / (N + 2)`` away from 0 and 1 (Laplace's rule).
    """
    occupied = np.asarray(occupied)
    if occupied.size == 0 or occupied.dtype != bool:
        raise PrismapInputError(
            f"`occupied` must be a non-empty bool array; got dtype {occupied.dtype}, size {occupied.size}"
        )
    return float((occupied.sum() + 1.0) / (occupied.size + 2.0))


def estimate_prior_from_likelihood(
    disparity_px: npt.ArrayLike,
    ray_norm: npt.ArrayLike,
    *,
    error_model: GaussianMixture,
    focal_baseline: float,
    doffs_px: float = 0.0,
    voxel_size_m: float = 0.1,
    near_m: float = 0.1,
    far_depth_m: float = 200.0,
    max_rays: int = 2000,
    seed: int = 0,
    bounds: tuple[float, float] = (1e-4, 0.9),
) -> float:
    """``p0`` maximising the measurements' likelihood under PRISM's forward model.

    Each measured disparity has density ``Z(d^; lambda_z)`` (the normaliser of section 5, a proper density
    in ``d^``); the estimate maximises ``sum_i log Z_i`` over ``p0`` (bounded scalar search in ``log p0``).
    Uses at most ``max_rays`` rays drawn with ``seed``. Rays are treated as independent, which they are
    not quite (neighbouring pixels see the same surface): fine for one number.

    Parameters
    ----------
    disparity_px : (R,) float64, pixels, finite
    ray_norm : (R,) float64, ``|r|`` of each ray
    error_model : GaussianMixture
    focal_baseline, doffs_px, voxel_size_m, near_m, far_depth_m
        As for :class:`PrismModel`.
    bounds : (float, float)
        Search interval of ``p0``.

    Returns
    -------
    float
        The maximum-likelihood ``p0`` for cells of ``voxel_size_m``.
    """
    disparity = as_float_array(disparity_px, "disparity_px", ndim=1, allow_nan=False)
    norm = as_float_array(ray_norm, "ray_norm", shape=(disparity.size,), allow_nan=False)
    if disparity.size == 0:
        raise PrismapInputError("`disparity_px` is empty: nothing to estimate p0 from")
    lo, hi = (check_probability(b, "bounds") for b in bounds)
    if lo >= hi:
        raise PrismapInputError(f"`bounds` must be increasing; got {bounds}")
    if disparity.size > max_rays:
        pick = np.random.default_rng(seed).choice(disparity.size, size=int(max_rays), replace=False)
        disparity, norm = disparity[pick], norm[pick]
    model = PrismModel(
        error_model=error_model,
        focal_baseline=focal_baseline,
        doffs_px=doffs_px,
        voxel_size_m=voxel_size_m,
        near_m=near_m,
        far_depth_m=far_depth_m,
    )
    shift = disparity + model.doffs_px
    log_far = model._log_far(disparity)
    geometry, mixture = model._geometry(), model._mixture()

    def negative_log_likelihood(log_p0):
        lam = -np.log1p(-np.exp(log_p0)) / model.voxel_size_m * norm
        log_z = _kernels_direct.prism_log_evidence(shift, lam, log_far, _QUAD_STEP, geometry, mixture)
        return -with_floor(log_z, error_model).sum()

    from scipy.optimize import minimize_scalar  # here, not above: slow to import, and few commands need it

    result = minimize_scalar(
        negative_log_likelihood, bounds=(np.log(lo), np.log(hi)), method="bounded", options={"xatol": 1e-3}
    )
    return float(np.exp(result.x))
