"""Where a PRISM ray's cells matter, ray by ray from its table: the floor depth up to which its cells take the
failure floor's increment (the grid samples those), and the influence depth beyond which no cell moves by
``influence_epsilon`` (the grid casts none of them), 0 for a silent ray, one that moves no cell by that much
(docs/SENSOR_MODELS.md, "The failure floor along a ray" and "Silent rays").

Functions of a :class:`~prismap.sensor_models.PrismModel` and its rays' ``terms`` (``PrismModel._ray_terms``: their
``tables``, ``log Z``, failure terms ``log(1 - rho)``, ``log(rho)`` (empty: no failures) and model rows ``ray_model``
of ``models``, a :class:`~prismap.sensor_models._kernel_args.MixtureSet`: one model's, or a conditioned model's
classes'), norms ``norm`` and overhangs ``voxel_overhang_m`` ((R,) metres along each ray, or None), shared by the
model and the fused look-up of a conditioned model's classes
(:class:`~prismap.sensor_models._prism_classes.PrismClasses`); one look-up of the terms serves both.
"""

import numpy as np

from prismap.sensor_models import _kernels_failure, _kernels_lookup
from prismap.sensor_models._kernels_influence import INFLUENCE_LEVEL_STEP, INFLUENCE_LEVELS
from prismap.sensor_models._kernels_pack import _SHIFT, _Z_INFL, _Z_TIGHT


def has_floor(model):
    """Whether a PRISM model's look-up has a failure floor (``method="table"``, ``prior="p0"``)."""
    return model.method == "table" and model.prior == "p0"


def floor_depths(model, terms, models, norm, voxel_overhang_m):
    """``PrismModel.floor_depth`` of the rays; None without a floor (:func:`has_floor`)."""
    if not has_floor(model):
        return None
    tables, log_z, (log_fail, _), ray_model = terms
    log_floor = model._floor_levels(log_fail) if log_fail.size else log_fail
    depth = _kernels_lookup.ray_floor_depths(tables, log_z, log_floor, ray_model, model._geometry(), models)
    return depth - model._stretch(norm, voxel_overhang_m)


def influence_depths(model, terms, models, norm, voxel_overhang_m):
    """``PrismModel.influence_depth`` of the rays (without failures, no silent ray)."""
    tables, log_z, (log_fail, log_ok), ray_model = terms
    table, _, meta, _ = tables
    blended = model.prior == "p0"  # cells blended with p0 by rho (1 without failures)
    depth = meta[table, _Z_INFL]
    if blended:
        # the longest cell: a voxel's diagonal, the solid depth and the ray's overhang share (metres along the ray)
        longest = (
            np.sqrt(3.0) * model.voxel_size_m + model.solid_depth_m + model._stretch(norm, voxel_overhang_m) * norm
        )
        rate = model.rate_per_m
        log_rho = log_ok if log_ok.size else np.zeros(table.size)
        depth = meta[table, _Z_INFL + _influence_level(log_rho, 0.0)]
        short = _influence_level(log_rho + rate * longest, 1.0)  # below 0: rho e^{lam L} > 4, no level holds
        depth = np.where(short >= 0, np.minimum(depth, meta[table, _Z_TIGHT + np.maximum(short, 0)]), depth)
    if model.solid_depth_m > 0:
        depth = np.minimum(depth + model.solid_depth_m / norm, model.far_depth_m)
    if not (blended and log_ok.size):
        return depth
    silent = _kernels_failure.silent_rays(
        meta[table, _SHIFT], rate * norm, rate * longest, log_z, log_fail, log_ok, ray_model,
        model.focal_baseline, model.near_m, models, model.influence_epsilon,
    )  # fmt: skip
    return np.where(silent, 0.0, depth)


def _influence_level(log_factor, shift):
    """Each ray's influence level of one bound (``_kernels_influence``): the largest ``k < INFLUENCE_LEVELS`` with
    ``log_factor <= (shift - k) log 4``, ``log_factor`` the log of what multiplies the bound (``rho``, or
    ``rho e^{lam L}``); negative where no level holds."""
    level = np.floor(shift - np.nan_to_num(log_factor, nan=0.0) / INFLUENCE_LEVEL_STEP)
    return np.minimum(level, INFLUENCE_LEVELS - 1).astype(np.int64)
