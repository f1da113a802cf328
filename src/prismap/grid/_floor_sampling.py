"""Ray mode's floor sampling: the cells at their ray's failure floor cast by a nested subsample of the rays, each
weighted by the inverse of its subsample's share, so that a voxel's sum and count of increments over the rays that
cross it keep their expectation (Horvitz-Thompson) from a few rays instead of all of them.

Near the camera a voxel subtends many pixels (a 0.2 m voxel at 5 m: 29 x 29 at f = 720 px), and every one of
those rays crosses it. Far in front of its own measurement a ray's increment is its floor's (the sensor model's
``floor_depth``: free space tempered by the matcher's failure chance, a function of the ray and the cell's length
alone), so a voxel there learns little from its thousandth ray that its tenth did not tell it. A ray's *level*
(:class:`RayLevels`) is the largest ``k <= MAX_BAND`` with its pixel's row and column in the ray grid multiples of
``2^k``: the rays of level ``>= k`` are every ``2^k``-th ray both ways, a share ``base^-k`` (``base`` 4; 2 for a
single line of rays). A floor cell (ending at or before its ray's floor depth) ending at depth
``z <= band_depth 2^-j`` is in *band* ``j``: a voxel there spans at least ``floor_rays 2^j`` ray spacings,
``floor_rays`` rays of level ``>= j`` each way. Only rays of level ``>= j`` cast it, and it counts ``base^j`` times
(``sum += base^j x``, ``count += base^j``). So a ray of level ``k`` starts its cast at
``min(floor depth, band_depth 2^-(k+1))`` (:func:`floor_plan`); its cells past its floor depth count once, as
without sampling. docs/SENSOR_MODELS.md, "Floor sampling".
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from prismap.errors import PrismapInputError

FLOOR_RAYS = 4
"""Rays of the subsample that cross a floor voxel each way, at least (``floor_rays`` of :func:`floor_plan`):
about ``FLOOR_RAYS^2`` rays a voxel where all rays would cross ``(FLOOR_RAYS 2^j)^2``. 0: every ray casts every
cell."""

MAX_BAND = 4
"""Deepest band: a floor cell counts at most ``base^MAX_BAND`` times (the rays of level ``MAX_BAND`` cast it all)."""


@dataclass(frozen=True)
class RayLevels:
    """The rays' places in the image's nested sampling (:func:`image_levels`).

    Attributes
    ----------
    level : (R,) int8, each ray's level: ``0..MAX_BAND``
    spacing_rad : float, radians, the angle between neighbouring rays at the image centre (``subsample / focal_px``)
    base : int, how many times more rays each level down holds: 4 for an image, 2 for a single line of rays
    """

    level: np.ndarray
    spacing_rad: float
    base: int = 4

    def subset(self, keep: np.ndarray) -> RayLevels:
        """The levels of the rays where ``keep`` ((R,) bool or indices) selects."""
        return RayLevels(self.level[keep], self.spacing_rad, self.base)


def image_levels(rows: int, cols: int, spacing_rad: float) -> RayLevels:
    """:class:`RayLevels` of a ray grid of ``rows x cols`` rays in row-major order, ``spacing_rad`` apart: a ray's
    level is the number of trailing zero bits of its row and of its column, the smaller, at most :data:`MAX_BAND`;
    of a single row or column, of its place along it (``base`` 2)."""
    if not (np.isfinite(spacing_rad) and spacing_rad > 0):
        raise PrismapInputError(f"`spacing_rad` must be finite and > 0; got {spacing_rad!r}")
    if min(rows, cols) == 1:
        return RayLevels(_trailing_zeros(rows * cols), float(spacing_rad), 2)
    return RayLevels(np.minimum.outer(_trailing_zeros(rows), _trailing_zeros(cols)).reshape(-1), float(spacing_rad))


def _trailing_zeros(n):
    """Trailing zero bits of ``0..n-1`` (int8), at most :data:`MAX_BAND` (0 has :data:`MAX_BAND`)."""
    index = np.arange(n)
    zeros = np.zeros(n, dtype=np.int8)
    for k in range(1, MAX_BAND + 1):
        zeros[index % (1 << k) == 0] = k
    return zeros


def check_floor_rays(floor_rays):
    """``floor_rays`` as an int >= 0 (:data:`FLOOR_RAYS`), else raise naming it."""
    if isinstance(floor_rays, bool) or not isinstance(floor_rays, (int, np.integer)) or floor_rays < 0:
        raise PrismapInputError(f"`floor_rays` must be an integer >= 0 (0: every ray); got {floor_rays!r}")
    return int(floor_rays)


def floor_plan(floor_end, levels, voxel_size, floor_rays):
    """Per ray, the depth its cast starts at and the band depth: ``(t_start (R,), band_depth)`` (the cells' weights
    are ``cell_weights(..., band_depth, levels.base)``).

    ``floor_end`` ((R,) depth metres): the model's floor depth of each ray, beyond which its cells count once;
    ``levels`` the rays' :class:`RayLevels`; ``voxel_size`` metres; ``floor_rays`` as :data:`FLOOR_RAYS`.
    """
    band_depth = voxel_size / (floor_rays * levels.spacing_rad)
    level = levels.level.astype(np.int64)
    start = np.minimum(floor_end, band_depth * 0.5 ** (level + 1))
    start[level >= MAX_BAND] = 0.0
    return np.maximum(start, 0.0), band_depth


@numba.njit(cache=True, nogil=True)
def cell_weights(ray_of_cell, t_out, floor_end, band_depth, base):
    """Each cell's weight (float32): ``base^j`` for a cell ending at or before its ray's ``floor_end`` in band ``j``
    (the largest ``j <= MAX_BAND`` with ``t_out <= band_depth 2^-j``), 1 past it."""
    weight = np.ones(t_out.size, dtype=np.float32)
    for i in range(t_out.size):
        z = t_out[i]
        if z <= floor_end[ray_of_cell[i]]:
            j = 0
            while j < MAX_BAND and z <= band_depth * 0.5 ** (j + 1):
                j += 1
            weight[i] = np.float32(float(base) ** j)
    return weight
