"""Projectors: where a frame's sensor sees the world, for projective integration.

As wavemap and Voxblox keep them, the projector, the measurement model and the integrator are separate objects,
each made by its own factory, so another sensor geometry is a new projector, not a new integrator.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from prismap.errors import PrismapInputError


@dataclass(frozen=True)
class ImageProjection:
    """The pinhole projector: where the frame's image sees the world, for projective integration (made by
    :func:`make_projector`).

    Attributes
    ----------
    R_cam_world : (3, 3) float64, rotation world -> camera
    focal_px, cx_px, cy_px : float, pixels, of the full-resolution image
    subsample : int >= 1, pixel step of the rays
    ray_index : (rows, cols) int32, ray of each subsampled pixel, -1 = none
    """

    R_cam_world: np.ndarray
    focal_px: float
    cx_px: float
    cy_px: float
    subsample: int
    ray_index: np.ndarray


_PROJECTORS = {"pinhole": ImageProjection}
PROJECTOR_NAMES = tuple(_PROJECTORS)
"""Names accepted by :func:`make_projector`."""


def make_projector(name: str, **params: Any) -> ImageProjection:
    """The projector called ``name`` (``"pinhole"``: :class:`ImageProjection`), built from ``params``.

    The projective integrator maps voxel centres to the frame's pixels through it; as with the integrators
    (:func:`make_integrator`) and the sensor models (:func:`prismap.sensor_models.make_sensor_model`), the three
    are separate objects, so another sensor geometry is a new projector, not a new integrator.
    """
    try:
        cls = _PROJECTORS[name]
    except (KeyError, TypeError):
        raise PrismapInputError(f"`projector` must be one of {list(_PROJECTORS)}; got {name!r}") from None
    return cls(**params)
