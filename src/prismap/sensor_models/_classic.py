"""The classic inverse sensor models: ideal (Thrun), OctoMap hit/miss, convolution, Andert.

Ideal and convolution state literal posteriors, with the prior ``p0`` beyond the measurement (Thrun's
table 9.2). OctoMap and Andert state their probabilities against an even prior (1/2 = no information):
their increment is ``logit(P_model)``, and the posterior reported is the one a cell with prior ``p0``
reaches after that one increment.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.special import logit, ndtri

from prismap._validate import check_positive, check_probability
from prismap.errors import PrismapInputError
from prismap.sensor_models import _kernels_classic
from prismap.sensor_models._base import register_model
from prismap.sensor_models._failure import blend_increments
from prismap.sensor_models._params import RayModel

INFLUENCE_EPSILON = 1e-3
"""Log-odds change below which a cell counts as untouched (``influence_depth`` of every model)."""


def _odds_shifted(p0, p_even):
    """The posterior that the increment ``logit(p_even)`` gives a cell of prior ``p0``."""
    return float(1.0 / (1.0 + np.exp(-(logit(p0) + logit(p_even)))))


def _check_failure_floor(model):
    """Store ``model.failure_floor`` as a float in [0, 1)."""
    value = float(model.failure_floor)
    if not 0.0 <= value < 1.0:
        raise PrismapInputError(f"{model.name}: `failure_floor` must lie in [0, 1); got {model.failure_floor!r}")
    object.__setattr__(model, "failure_floor", value)


def _with_failures(model, posterior, increment, no_information):
    """``(1 - eps) P + eps p_n`` of each cell, ``eps = model.failure_floor`` and ``p_n = no_information`` (the
    model's "nothing learnt" value): a failed measurement carries no information (docs/SENSOR_MODELS.md,
    "Matcher failures"). Increments stay on the model's scale (against ``p_n``); posteriors are for ``p0``."""
    if model.failure_floor == 0.0:
        return posterior, increment
    eps = model.failure_floor
    _, increment = blend_increments(increment, logit(no_information), np.log(eps), np.log1p(-eps))
    return 1.0 / (1.0 + np.exp(-(logit(model.p0) + increment))), increment


@dataclass(frozen=True, kw_only=True)
class _ProfileModel(RayModel):
    """Ideal-profile parameters shared by ``ideal`` and ``convolution``.

    Parameters
    ----------
    alpha_m : float or None, metres along the ray
        Width of the occupied band around the measurement; None = ``voxel_size_m``.
    p_free, p_occ : float or None
        Posteriors in front of / at the measurement, ``p_free < p0 < p_occ``. None = the posteriors that
        OctoMap's increments ``logit(0.4)`` and ``logit(0.7)`` give a cell of prior ``p0``.
    """

    alpha_m: float | None = None
    p_free: float | None = None
    p_occ: float | None = None

    def __post_init__(self):
        super().__post_init__()
        alpha = self.voxel_size_m if self.alpha_m is None else check_positive(self.alpha_m, "alpha_m")
        p_free = _odds_shifted(self.p0, 0.4) if self.p_free is None else check_probability(self.p_free, "p_free")
        p_occ = _odds_shifted(self.p0, 0.7) if self.p_occ is None else check_probability(self.p_occ, "p_occ")
        if not p_free < self.p0 < p_occ:
            raise PrismapInputError(
                f"{self.name}: need p_free < p0 < p_occ; got p_free={p_free}, p0={self.p0}, p_occ={p_occ}"
            )
        object.__setattr__(self, "alpha_m", alpha)
        object.__setattr__(self, "p_free", p_free)
        object.__setattr__(self, "p_occ", p_occ)


@register_model
@dataclass(frozen=True, kw_only=True)
class IdealModel(_ProfileModel):
    """Thrun's ideal model on one ray (Probabilistic Robotics, table 9.2), evaluated at the cell centre.

    ``p_free`` where ``s < s^ - alpha/2``, ``p_occ`` where ``|s - s^| <= alpha/2``, ``p0`` beyond
    (``s`` = distance along the ray).
    """

    name = "ideal"
    default_policy = "mean"
    MEASUREMENTS = ("disparity", "range")

    def cell_posteriors(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        ray_of_cell: npt.ArrayLike,
        depth_start_m: npt.ArrayLike,
        depth_end_m: npt.ArrayLike,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        _, norm, rays, start, end, z_hat = self._prepare(
            disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m
        )
        return _kernels_classic.ideal_cells(
            z_hat, norm, rays, start, end, 0.5 * self.alpha_m, self.p_free, self.p_occ, self.p0
        )

    def influence_depth(self, disparity_px: npt.ArrayLike, ray_norm: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """End of the occupied band: ``z^ + alpha / (2 |r|)`` (metres)."""
        z_hat = self._depth_hat(np.asarray(disparity_px, dtype=np.float64), np.asarray(ray_norm, dtype=np.float64))
        return z_hat + 0.5 * self.alpha_m / np.asarray(ray_norm, dtype=np.float64)

    def with_extra_noise(self, sigma_px: float) -> IdealModel:
        """The ideal model has no noise to widen: returns itself."""
        check_positive(sigma_px, "sigma_px")
        return self


@register_model
@dataclass(frozen=True, kw_only=True)
class HitMissModel(RayModel):
    """OctoMap's model (``insertPointCloud``): ``p_hit`` at the end cell, ``p_miss`` before it, nothing after.

    The end cell is the one whose depth interval ``[a, c)`` holds the measured depth. Increments are
    exactly ``logit(p_hit)`` and ``logit(p_miss)``, as in OctoMap.

    Parameters
    ----------
    p_hit : float in (0.5, 1), default 0.7
    p_miss : float in (0, 0.5), default 0.4
    """

    name = "hitmiss"
    default_policy = "occupied-wins"
    MEASUREMENTS = ("disparity", "range")
    p_hit: float = 0.7
    p_miss: float = 0.4

    def __post_init__(self):
        super().__post_init__()
        _set_probabilities_around_half(self, "p_miss", "p_hit")

    def cell_posteriors(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        ray_of_cell: npt.ArrayLike,
        depth_start_m: npt.ArrayLike,
        depth_end_m: npt.ArrayLike,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        _, _, rays, start, end, z_hat = self._prepare(disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m)
        return _kernels_classic.hitmiss_cells(z_hat, rays, start, end, logit(self.p_hit), logit(self.p_miss), self.p0)

    def influence_depth(self, disparity_px: npt.ArrayLike, ray_norm: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The measured depth itself (the grid includes the cell that contains it)."""
        return self._depth_hat(np.asarray(disparity_px, dtype=np.float64), np.asarray(ray_norm, dtype=np.float64))

    def with_extra_noise(self, sigma_px: float) -> HitMissModel:
        """Hit/miss has no noise to widen: returns itself."""
        check_positive(sigma_px, "sigma_px")
        return self

    def hit_miss_increments(self) -> tuple[float, float]:
        """``(logit(p_hit), logit(p_miss))``: the grid adds them while casting (see the base class)."""
        return float(logit(self.p_hit)), float(logit(self.p_miss))


@register_model
@dataclass(frozen=True, kw_only=True)
class ConvolutionModel(_ProfileModel):
    """The ideal profile convolved with Gaussian range noise ``N(0, sigma_s^2)``, at the cell centre.

    ``P(s) = p_free Phi((s^ - alpha/2 - s)/sigma_s) + p_occ [Phi((s^ + alpha/2 - s)/sigma_s) -
    Phi((s^ - alpha/2 - s)/sigma_s)] + p0 [1 - Phi((s^ + alpha/2 - s)/sigma_s)]``, with
    ``sigma_s = |r| z^2 sigma_px / (f b)``. Tends to the ideal model as ``sigma_px -> 0``.

    Parameters
    ----------
    sigma_px : float, pixels, default 0.5
        Disparity noise.
    failure_floor : float in [0, 1), default 0
        ``eps``: the share of a cell's posterior that falls back to ``p0`` because the measurement may be a
        matcher failure, ``P = (1 - eps) P_conv + eps p0`` (:func:`prismap.sensor_models.failure_floor` of
        the error mixture sets it).
    """

    name = "convolution"
    error_model_use = "sigma"
    default_policy = "mean"
    sigma_px: float = 0.5
    failure_floor: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "sigma_px", check_positive(self.sigma_px, "sigma_px"))
        _check_failure_floor(self)

    def cell_posteriors(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        ray_of_cell: npt.ArrayLike,
        depth_start_m: npt.ArrayLike,
        depth_end_m: npt.ArrayLike,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        _, norm, rays, start, end, z_hat = self._prepare(
            disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m
        )
        posterior, increment = _kernels_classic.convolution_cells(
            z_hat,
            self._sigma_depth(z_hat, self.sigma_px),
            norm,
            rays,
            start,
            end,
            0.5 * self.alpha_m,
            self.p_free,
            self.p_occ,
            self.p0,
        )
        return _with_failures(self, posterior, increment, self.p0)

    def influence_depth(self, disparity_px: npt.ArrayLike, ray_norm: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Depth where ``|P - p0|`` falls below ``INFLUENCE_EPSILON * p0 (1 - p0) / 2`` (log-odds change ~epsilon)."""
        z_hat = self._depth_hat(np.asarray(disparity_px, dtype=np.float64), np.asarray(ray_norm, dtype=np.float64))
        norm = np.asarray(ray_norm, dtype=np.float64)
        spread = max(abs(self.p_occ - self.p0), abs(self.p_free - self.p0))
        k = -ndtri(INFLUENCE_EPSILON * self.p0 * (1 - self.p0) / (2 * spread))
        return z_hat + (0.5 * self.alpha_m + k * norm * self._sigma_depth(z_hat, self.sigma_px)) / norm

    def with_extra_noise(self, sigma_px: float) -> ConvolutionModel:
        """A copy whose ``sigma_px`` grows in quadrature by ``sigma_px``."""
        extra = check_positive(sigma_px, "sigma_px")
        return dataclasses.replace(self, sigma_px=float(np.hypot(self.sigma_px, extra)))


@register_model
@dataclass(frozen=True, kw_only=True)
class AndertModel(RayModel):
    """F. Andert, "Drawing stereo disparity images into occupancy grids", IROS 2009.

    ``P(s) = P_base(s) + (min(eta / (sqrt(2 pi) sigma_s) + 1/2, p_max) - P_base(s)) exp(-(s - s^)^2 / (2 sigma_s^2))``
    with ``P_base = p_min`` for ``s <= s^`` and 1/2 beyond; a cell takes ``P(clip(s^, a, c))``, the
    maximum over its interval. ``sigma_s = |r| z^2 sigma_px / (f b)``. Increments are ``logit(P)``
    (1/2 is "no information" here); the peak is capped at ``p_max`` because the formula exceeds 1
    when ``sigma_s < 0.8 eta``.

    Parameters
    ----------
    sigma_px : float, pixels, default 0.5
    eta : float, metres, default 0.1
        Significance of one measurement.
    p_min : float in (0, 0.5), default 0.35
        Free-space probability.
    p_max : float in (0.5, 1), default 0.97
        Cap of the peak.
    failure_floor : float in [0, 1), default 0
        ``eps``: Andert's ``P`` becomes ``(1 - eps) P + eps / 2`` (1/2 is "no information" here), as for
        :class:`ConvolutionModel`.
    """

    name = "andert"
    error_model_use = "sigma"
    default_policy = "max"
    sigma_px: float = 0.5
    eta: float = 0.1
    p_min: float = 0.35
    p_max: float = 0.97
    failure_floor: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "sigma_px", check_positive(self.sigma_px, "sigma_px"))
        object.__setattr__(self, "eta", check_positive(self.eta, "eta"))
        _set_probabilities_around_half(self, "p_min", "p_max")
        _check_failure_floor(self)

    def cell_posteriors(
        self,
        disparity_px: npt.ArrayLike,
        ray_norm: npt.ArrayLike,
        ray_of_cell: npt.ArrayLike,
        depth_start_m: npt.ArrayLike,
        depth_end_m: npt.ArrayLike,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        _, norm, rays, start, end, z_hat = self._prepare(
            disparity_px, ray_norm, ray_of_cell, depth_start_m, depth_end_m
        )
        posterior, increment = _kernels_classic.andert_cells(
            z_hat,
            self._sigma_depth(z_hat, self.sigma_px),
            norm,
            rays,
            start,
            end,
            self.eta,
            self.p_min,
            self.p_max,
            self.p0,
        )
        return _with_failures(self, posterior, increment, 0.5)

    def influence_depth(self, disparity_px: npt.ArrayLike, ray_norm: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Depth behind ``z^`` where ``|logit P|`` falls below ``INFLUENCE_EPSILON``."""
        z_hat = self._depth_hat(np.asarray(disparity_px, dtype=np.float64), np.asarray(ray_norm, dtype=np.float64))
        sigma_z = self._sigma_depth(z_hat, self.sigma_px)
        excess = np.minimum(0.5 + self.eta / (np.sqrt(2 * np.pi) * sigma_z * np.asarray(ray_norm)), self.p_max) - 0.5
        k = np.sqrt(2.0 * np.log(np.maximum(4.0 * excess / INFLUENCE_EPSILON, 1.0)))
        return z_hat + k * sigma_z

    def with_extra_noise(self, sigma_px: float) -> AndertModel:
        """A copy whose ``sigma_px`` grows in quadrature by ``sigma_px``."""
        extra = check_positive(sigma_px, "sigma_px")
        return dataclasses.replace(self, sigma_px=float(np.hypot(self.sigma_px, extra)))


def _set_probabilities_around_half(model, low, high):
    """Check that fields ``low`` < 0.5 < ``high`` of ``model`` are probabilities, and store them as floats."""
    p_low = check_probability(getattr(model, low), low)
    p_high = check_probability(getattr(model, high), high)
    if not p_low < 0.5 < p_high:
        raise PrismapInputError(f"{model.name}: need {low} < 0.5 < {high}; got {low}={p_low}, {high}={p_high}")
    object.__setattr__(model, low, p_low)
    object.__setattr__(model, high, p_high)
