"""PRISM with the map as prior (``prior="map"``): each cell's prior from its voxel's log-odds before the frame, the
exact discrete posterior of the cells of whole rays (``_kernels_map_prior.prism_map_prior_cells``;
docs/SENSOR_MODELS.md, "The map as prior")."""

import numpy as np

from prismap._validate import as_float_array
from prismap.errors import PrismapInputError
from prismap.sensor_models import _kernels_map_prior

_TAIL_STEP = 1.0  # x-width of the panels of a ray's tail beyond its last cell
_TAIL_REST = -20.0  # the tail's march stops where the rest is below e^-20 of the evidence before


def map_prior_cells(model, lam, disparity, norm, rays, start, end, stretch, map_log_odds):
    """``PrismModel.cell_posteriors`` of ``model`` with the map as prior (``_kernels_map_prior.prism_map_prior_cells``),
    and each cell's prior surface rate (per metre of depth) that it took from the map.

    A voxel of probability ``P_v`` has surface rate ``-log(1 - P_v) / voxel_size_m`` per metre of ray
    (``log1p(e^l)``, softplus of its log-odds ``l``), so a ray's stretch of length ``s`` in it has prior
    ``1 - (1 - P_v)^(s / voxel_size_m)``: the voxel's own probability across a whole voxel, and the
    ``p0`` model's rate in an unknown voxel.
    """
    if map_log_odds is None:
        log_odds = np.full(start.size, float(np.log(model.p0) - np.log1p(-model.p0)))
    else:
        log_odds = as_float_array(map_log_odds, "map_log_odds", shape=(start.size,), allow_nan=False)
    order = np.lexsort((start, rays))
    ray_start = np.searchsorted(rays[order], np.arange(disparity.size + 1))
    _check_tiling(rays[order], start[order], end[order], ray_start, model.near_m)
    cell_rate = np.logaddexp(0.0, log_odds) / model.voxel_size_m * norm[rays]  # per metre of depth
    per_ray = (disparity + model.doffs_px, lam, model._log_far(disparity))
    cells = (order, ray_start, start, end, stretch, cell_rate)
    tail = (_TAIL_STEP, _TAIL_REST, model.pass_through, np.log(model.error_model.weights))
    result = _kernels_map_prior.prism_map_prior_cells(*per_ray, *cells, *tail, model._geometry(), model._mixture())
    return result, cell_rate


def _check_tiling(rays, start, end, ray_start, near_m):
    """Refuse cells (sorted by ray, then start) that do not tile each ray from at most ``near_m`` without gaps."""
    first = ray_start[:-1][np.diff(ray_start) > 0]
    if first.size and start[first].max() > near_m:
        raise PrismapInputError(
            f"prism prior='map': each ray's cells must start at or before near_m = {near_m:g} m (ray casting from "
            f"the camera); a ray's first cell starts at {start[first].max():.6g} m"
        )
    same = rays[1:] == rays[:-1]
    gap = np.abs(start[1:] - end[:-1])[same]
    if gap.size and gap.max() > 1e-9 * max(1.0, float(np.abs(end).max())):
        raise PrismapInputError(
            "prism prior='map': each ray's cells must follow one another without gaps or overlaps (ray casting "
            f"gives such cells, projective integration does not); found a gap of {gap.max():.3g} m"
        )
