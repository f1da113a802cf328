"""The 1-D Gaussian mixture used as a stereo matcher's disparity-error model (thesis eq. 3.9-3.10), with an
optional matcher-failure component uniform over the matcher's disparity search range (SENSOR_MODELS.md 8)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.special import log_ndtr, ndtr

from prismap.errors import PrismapInputError

_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)


@dataclass(frozen=True)
class GaussianMixture:
    """``p(e) = (1 - w_f) sum_j w_j N(e; mu_j, sigma_j^2) + w_f / W`` over a disparity error ``e`` in pixels.

    The last term is the matcher's gross failures: a matcher that fails returns a disparity roughly uniform
    over its search range ``[lo, hi)`` of width ``W = hi - lo`` pixels, so the error ``e = d_true - d^`` of a
    returned disparity ``d^`` has failure density ``1 / W`` whatever ``d_true`` is (every returned ``d^`` lies
    in the range). Without it (``failure_weight = 0``, the default) this is a plain Gaussian mixture.

    Parameters
    ----------
    weights : (G,) float64
        Weights of the Gaussians among themselves, non-negative, summing to 1 (renormalised if off by rounding).
    means : (G,) float64, pixels
    sigmas : (G,) float64, pixels, > 0
    failure_weight : float in [0, 1)
        ``w_f``: the share of errors that are matcher failures.
    search_range_px : (lo, hi) floats, pixels, or None
        The matcher's disparity search interval; needed when ``failure_weight > 0``.
    """

    weights: np.ndarray
    means: np.ndarray
    sigmas: np.ndarray
    failure_weight: float = 0.0
    search_range_px: tuple | None = None

    def __post_init__(self):
        arrays = []
        for name in ("weights", "means", "sigmas"):
            value = np.atleast_1d(np.asarray(getattr(self, name), dtype=np.float64)).copy()
            if value.ndim != 1:
                raise PrismapInputError(f"GaussianMixture `{name}` must be 1-D; got shape {value.shape}")
            if not np.all(np.isfinite(value)):
                raise PrismapInputError(f"GaussianMixture `{name}` must be finite; got {value.tolist()}")
            value.setflags(write=False)
            arrays.append(value)
        weights, means, sigmas = arrays
        if not (weights.shape == means.shape == sigmas.shape) or weights.size == 0:
            raise PrismapInputError(
                "GaussianMixture needs weights, means and sigmas of one equal, non-zero length; got "
                f"{weights.shape}, {means.shape}, {sigmas.shape}"
            )
        if np.any(weights < 0) or abs(weights.sum() - 1.0) > 1e-6:
            raise PrismapInputError(f"GaussianMixture weights must be >= 0 and sum to 1; got {weights.tolist()}")
        if np.any(sigmas <= 0):
            raise PrismapInputError(f"GaussianMixture sigmas must be > 0; got {sigmas.tolist()}")
        weights = weights / weights.sum()
        weights.setflags(write=False)
        object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "means", means)
        object.__setattr__(self, "sigmas", sigmas)
        failure = self.failure_weight
        if (
            isinstance(failure, bool)
            or not isinstance(failure, (int, float, np.floating, np.integer))
            or not 0.0 <= float(failure) < 1.0
        ):
            raise PrismapInputError(f"GaussianMixture `failure_weight` must be a number in [0, 1); got {failure!r}")
        object.__setattr__(self, "failure_weight", float(failure))
        if self.search_range_px is not None:
            bounds = check_search_range(self.search_range_px, "GaussianMixture `search_range_px`")
            object.__setattr__(self, "search_range_px", bounds)
        elif self.failure_weight > 0:
            raise PrismapInputError("GaussianMixture with `failure_weight` > 0 needs `search_range_px` (lo, hi)")

    @property
    def failure_width(self) -> float:
        """``W``: width of the search range (pixels); infinity without one."""
        if self.search_range_px is None:
            return math.inf
        return self.search_range_px[1] - self.search_range_px[0]

    @property
    def failure_density(self) -> float:
        """``w_f / W``: the failure component's density (1/pixel), the floor of :meth:`pdf`."""
        return self.failure_weight / self.failure_width

    def peak_density(self) -> float:
        """An upper bound (1/pixel) of the Gaussian part's density: ``sum_j w_j / (sqrt(2 pi) sigma_j)``.

        It bounds the likelihood any measurement can have under the Gaussians, and with it the evidence
        one measurement can carry (:func:`prismap.sensor_models.evidence_bound`).
        """
        return float(np.sum(self.weights / self.sigmas) / np.sqrt(2.0 * np.pi))

    def gaussian_part(self) -> GaussianMixture:
        """The Gaussians alone (no failure component), same weights, means and sigmas."""
        return GaussianMixture(self.weights, self.means, self.sigmas)

    def with_failure(self, failure_weight: float, search_range_px: tuple[float, float]) -> GaussianMixture:
        """The Gaussians of this mixture with the failure component ``w_f`` over ``search_range_px`` (pixels)."""
        return GaussianMixture(self.weights, self.means, self.sigmas, failure_weight, search_range_px)

    @property
    def n_components(self) -> int:
        """Number of components G."""
        return self.weights.size

    def _standardised(self, errors):
        e = np.asarray(errors, dtype=np.float64)
        return e, (e[..., None] - self.means) / self.sigmas

    def logpdf(self, errors: npt.ArrayLike) -> npt.NDArray[np.float64] | float:
        """Log density at ``errors`` (pixels), any shape; computed stably with log-sum-exp.

        With a failure component the density is that of an error whose disparity the matcher returned (inside
        its search range): the Gaussians' density scaled by ``1 - w_f`` plus the floor ``w_f / W``.
        """
        _, z = self._standardised(errors)
        terms = np.log(self.weights) - np.log(self.sigmas) - _LOG_SQRT_2PI - 0.5 * z * z
        peak = terms.max(axis=-1)
        gaussian = peak + np.log(np.exp(terms - peak[..., None]).sum(axis=-1))
        if self.failure_weight == 0.0:
            return gaussian
        return np.logaddexp(np.log1p(-self.failure_weight) + gaussian, np.log(self.failure_density))

    def pdf(self, errors: npt.ArrayLike) -> npt.NDArray[np.float64] | float:
        """Density at ``errors`` (1/pixel), same shape as ``errors`` (see :meth:`logpdf`)."""
        _, z = self._standardised(errors)
        gaussian = (self.weights / self.sigmas * np.exp(-0.5 * z * z)).sum(axis=-1) / np.sqrt(2.0 * np.pi)
        if self.failure_weight == 0.0:
            return gaussian
        return (1.0 - self.failure_weight) * gaussian + self.failure_density

    def cdf(self, errors: npt.ArrayLike) -> npt.NDArray[np.float64] | float:
        """``P(e <= errors)`` of the Gaussians, same shape as ``errors`` (the failure part needs ``d_true``)."""
        _, z = self._standardised(errors)
        return (self.weights * ndtr(z)).sum(axis=-1)

    def logcdf(self, errors: npt.ArrayLike) -> npt.NDArray[np.float64] | float:
        """``log P(e <= errors)`` of the Gaussians, accurate far in the left tail."""
        _, z = self._standardised(errors)
        terms = np.log(self.weights) + log_ndtr(z)
        peak = terms.max(axis=-1)
        return peak + np.log(np.exp(terms - peak[..., None]).sum(axis=-1))

    def sample(
        self, n: int, rng: np.random.Generator | int | None, *, truth_px: npt.ArrayLike | None = None
    ) -> npt.NDArray[np.float64]:
        """Draw ``n`` errors (pixels) with the generator ``rng`` (``np.random.Generator`` or a seed).

        With a failure component, a failed pixel's error is ``truth_px - U(lo, hi)``: the matcher returned a
        disparity uniform over its search range. ``truth_px`` (scalar or ``(n,)``, pixels, the true
        disparities) is then required.
        """
        rng = np.random.default_rng(rng)
        n = int(n)
        component = rng.choice(self.n_components, size=n, p=self.weights)
        errors = self.means[component] + self.sigmas[component] * rng.standard_normal(n)
        if self.failure_weight == 0.0:
            return errors
        if truth_px is None:
            raise PrismapInputError("sampling a mixture with a failure component needs `truth_px` (true disparities)")
        truth = np.broadcast_to(np.asarray(truth_px, dtype=np.float64), (n,))
        failed = rng.random(n) < self.failure_weight
        lo, hi = self.search_range_px
        return np.where(failed, truth - rng.uniform(lo, hi, n), errors)

    def mean(self) -> float:
        """Mixture mean (pixels)."""
        return float(self.weights @ self.means)

    def std(self) -> float:
        """Mixture standard deviation (pixels)."""
        second = self.weights @ (self.sigmas**2 + self.means**2)
        return float(np.sqrt(second - self.mean() ** 2))

    def dominant_sigma(self) -> float:
        """Standard deviation (pixels) of the heaviest component: the core most pixels follow.

        Models with one Gaussian disparity noise (convolution, Andert) take it; the mixture's overall std
        would be inflated by the gross-error components.
        """
        return float(self.sigmas[int(np.argmax(self.weights))])

    def widened(self, extra_sigma: float) -> GaussianMixture:
        """The mixture convolved with ``N(0, extra_sigma^2)`` (pixels): every sigma grows in quadrature."""
        extra = float(extra_sigma)
        return GaussianMixture(
            self.weights, self.means, np.sqrt(self.sigmas**2 + extra**2), self.failure_weight, self.search_range_px
        )

    def with_component(self, weight: float, mean: float, sigma: float) -> GaussianMixture:
        """``(1 - weight) * self + weight * N(mean, sigma^2)`` (pixels): one more component, the others scaled."""
        weight = float(weight)
        if not 0.0 <= weight < 1.0:
            raise PrismapInputError(f"`weight` of the added component must lie in [0, 1); got {weight!r}")
        return GaussianMixture(
            np.append((1.0 - weight) * self.weights, weight),
            np.append(self.means, mean),
            np.append(self.sigmas, sigma),
            self.failure_weight,
            self.search_range_px,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form: ``{"weights": [...], "means": [...], "sigmas": [...]}``, plus ``failure_weight`` and
        ``search_range_px`` when there is a search range."""
        data = {"weights": self.weights.tolist(), "means": self.means.tolist(), "sigmas": self.sigmas.tolist()}
        if self.search_range_px is not None:
            data.update(failure_weight=self.failure_weight, search_range_px=list(self.search_range_px))
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "mixture") -> GaussianMixture:
        """Inverse of :meth:`to_dict`; ``source`` names the file or field in error messages."""
        if not isinstance(data, dict):
            raise PrismapInputError(f"{source}: a Gaussian mixture must be a JSON object; got {type(data).__name__}")
        missing = [key for key in ("weights", "means", "sigmas") if key not in data]
        if missing:
            raise PrismapInputError(f"{source}: Gaussian mixture is missing field(s) {missing}")
        try:
            return cls(
                data["weights"],
                data["means"],
                data["sigmas"],
                data.get("failure_weight", 0.0),
                data.get("search_range_px"),
            )
        except PrismapInputError as exc:
            raise PrismapInputError(f"{source}: {exc}") from None
        except (TypeError, ValueError) as exc:
            raise PrismapInputError(f"{source}: Gaussian mixture fields must be lists of numbers ({exc})") from None

    @classmethod
    def gaussian(cls, sigma: float, mean: float = 0.0) -> GaussianMixture:
        """A single Gaussian ``N(mean, sigma^2)`` (pixels)."""
        return cls([1.0], [mean], [sigma])


def check_search_range(value, name):
    """``(lo, hi)`` floats (pixels) with ``lo < hi``, both finite, else an error naming ``name``."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise PrismapInputError(f"{name} must be two numbers (lo, hi) in pixels; got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise PrismapInputError(f"{name} must be finite with lo < hi (pixels); got {value!r}")
    return (lo, hi)
