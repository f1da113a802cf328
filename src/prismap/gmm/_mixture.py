"""The 1-D Gaussian mixture used as a stereo matcher's disparity-error model (thesis eq. 3.9-3.10)."""

from dataclasses import dataclass

import numpy as np
from scipy.special import log_ndtr, ndtr

from prismap.errors import PrismapInputError

_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)


@dataclass(frozen=True)
class GaussianMixture:
    """``p(e) = sum_j w_j N(e; mu_j, sigma_j^2)`` over a disparity error ``e`` in pixels.

    Parameters
    ----------
    weights : (G,) float64
        Component weights, non-negative, summing to 1 (renormalised if off by rounding).
    means : (G,) float64, pixels
    sigmas : (G,) float64, pixels, > 0
    """

    weights: np.ndarray
    means: np.ndarray
    sigmas: np.ndarray

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

    @property
    def n_components(self):
        """Number of components G."""
        return self.weights.size

    def _standardised(self, errors):
        e = np.asarray(errors, dtype=np.float64)
        return e, (e[..., None] - self.means) / self.sigmas

    def logpdf(self, errors):
        """Log density at ``errors`` (pixels), any shape; computed stably with log-sum-exp."""
        _, z = self._standardised(errors)
        terms = np.log(self.weights) - np.log(self.sigmas) - _LOG_SQRT_2PI - 0.5 * z * z
        peak = terms.max(axis=-1)
        return peak + np.log(np.exp(terms - peak[..., None]).sum(axis=-1))

    def pdf(self, errors):
        """Density at ``errors`` (1/pixel), same shape as ``errors``."""
        _, z = self._standardised(errors)
        return (self.weights / self.sigmas * np.exp(-0.5 * z * z)).sum(axis=-1) / np.sqrt(2.0 * np.pi)

    def cdf(self, errors):
        """``P(e <= errors)``, same shape as ``errors``."""
        _, z = self._standardised(errors)
        return (self.weights * ndtr(z)).sum(axis=-1)

    def logcdf(self, errors):
        """``log P(e <= errors)``, accurate far in the left tail."""
        _, z = self._standardised(errors)
        terms = np.log(self.weights) + log_ndtr(z)
        peak = terms.max(axis=-1)
        return peak + np.log(np.exp(terms - peak[..., None]).sum(axis=-1))

    def sample(self, n, rng):
        """Draw ``n`` errors (pixels) with the generator ``rng`` (``np.random.Generator`` or a seed)."""
        rng = np.random.default_rng(rng)
        component = rng.choice(self.n_components, size=int(n), p=self.weights)
        return self.means[component] + self.sigmas[component] * rng.standard_normal(int(n))

    def mean(self):
        """Mixture mean (pixels)."""
        return float(self.weights @ self.means)

    def std(self):
        """Mixture standard deviation (pixels)."""
        second = self.weights @ (self.sigmas**2 + self.means**2)
        return float(np.sqrt(second - self.mean() ** 2))

    def dominant_sigma(self):
        """Standard deviation (pixels) of the heaviest component: the core most pixels follow.

        Models with one Gaussian disparity noise (convolution, Andert) take it; the mixture's overall std
        would be inflated by the gross-error components.
        """
        return float(self.sigmas[int(np.argmax(self.weights))])

    def widened(self, extra_sigma):
        """The mixture convolved with ``N(0, extra_sigma^2)`` (pixels): every sigma grows in quadrature."""
        extra = float(extra_sigma)
        return GaussianMixture(self.weights, self.means, np.sqrt(self.sigmas**2 + extra**2))

    def with_component(self, weight, mean, sigma):
        """``(1 - weight) * self + weight * N(mean, sigma^2)`` (pixels): one more component, the others scaled."""
        weight = float(weight)
        if not 0.0 <= weight < 1.0:
            raise PrismapInputError(f"`weight` of the added component must lie in [0, 1); got {weight!r}")
        return GaussianMixture(np.append((1.0 - weight) * self.weights, weight), np.append(self.means, mean),
                               np.append(self.sigmas, sigma))

    def to_dict(self):
        """Plain-JSON form: ``{"weights": [...], "means": [...], "sigmas": [...]}``."""
        return {"weights": self.weights.tolist(), "means": self.means.tolist(), "sigmas": self.sigmas.tolist()}

    @classmethod
    def from_dict(cls, data, *, source="mixture"):
        """Inverse of :meth:`to_dict`; ``source`` names the file or field in error messages."""
        if not isinstance(data, dict):
            raise PrismapInputError(f"{source}: a Gaussian mixture must be a JSON object; got {type(data).__name__}")
        missing = [key for key in ("weights", "means", "sigmas") if key not in data]
        if missing:
            raise PrismapInputError(f"{source}: Gaussian mixture is missing field(s) {missing}")
        try:
            return cls(data["weights"], data["means"], data["sigmas"])
        except PrismapInputError as exc:
            raise PrismapInputError(f"{source}: {exc}") from None
        except (TypeError, ValueError) as exc:
            raise PrismapInputError(f"{source}: Gaussian mixture fields must be lists of numbers ({exc})") from None

    @classmethod
    def gaussian(cls, sigma, mean=0.0):
        """A single Gaussian ``N(mean, sigma^2)`` (pixels)."""
        return cls([1.0], [mean], [sigma])
