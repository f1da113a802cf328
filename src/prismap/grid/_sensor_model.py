"""What the grid asks of a sensor model, as a type: the grid never imports :mod:`prismap.sensor_models`; it
calls any object with these members, and every :class:`prismap.sensor_models.InverseSensorModel` has them."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class SensorModel(Protocol):
    """An inverse sensor model as the integrators and :class:`~prismap.grid.OccupancyMap` use it.

    The grid also passes the keywords ``ray_class``, ``voxel_overhang_m`` and ``map_log_odds`` to
    :meth:`cell_posteriors` (and ``ray_class`` and ``voxel_overhang_m`` to :meth:`influence_depth`) when the frame has them and the
    model's flags ask for them; it reads ``measurement``, ``p0`` and ``voxel_size_m`` where a model has them.
    Ray mode calls ``influence_and_floor_depths(disparity_px, ray_norm, **keywords)`` instead of
    :meth:`influence_depth` where a model has it (the keywords of :meth:`cell_posteriors`): per ray the influence
    depth and the depth (metres) up to which a cell ending there gets the increment of its ray's failure floor, a
    function of the ray and the cell's length alone (or None for no floor), from one look-up; those cells it samples
    (:mod:`prismap.grid._floor_sampling`).
    """

    name: str
    default_policy: str
    takes_voxel_overhang: bool
    takes_map_prior: bool

    def cell_posteriors(
        self,
        disparity_px: np.ndarray,
        ray_norm: np.ndarray,
        ray_of_cell: np.ndarray,
        depth_start_m: np.ndarray,
        depth_end_m: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(C,) posterior and (C,) log-odds increment of each cell, as ``InverseSensorModel.cell_posteriors``."""
        ...

    def influence_depth(self, disparity_px: np.ndarray, ray_norm: np.ndarray) -> np.ndarray:
        """(R,) depth (metres) where each ray's cast stops, as ``InverseSensorModel.influence_depth``."""
        ...

    def with_extra_noise(self, sigma_px: float) -> SensorModel:
        """The model with its disparity noise widened by ``N(0, sigma_px^2)`` (pixels)."""
        ...

    def hit_miss_increments(self) -> tuple[float, float] | None:
        """``(l_hit, l_miss)`` of a hit/miss model, else None."""
        ...
