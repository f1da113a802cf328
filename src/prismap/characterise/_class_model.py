"""One class of pixels in an error model: its fitted mixtures over G and the one selected."""

from __future__ import annotations

from dataclasses import dataclass, field

from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit


def _find_fit(fits, n_components):
    for fit in fits:
        if fit.n_components == n_components:
            return fit
    raise PrismapInputError(
        f"error model has no {n_components}-component fit; it has G = {[f.n_components for f in fits]}"
    )


@dataclass(frozen=True)
class ClassModel:
    """The fitted mixtures of one class of pixels.

    Attributes
    ----------
    fits : tuple of MixtureFit
        One per G, ascending.
    selected_components : int
    share : float in (0, 1]
        Share of the characterised pixels (with a computed value and ground truth) in this class.
    statistics : dict
        As ``ErrorHistogram.statistics`` of the class's errors.
    outlier : dict or None
        ``{"weight", "mean", "sigma"}`` (pixels): a component mixed into the selected fit; None = none.
    """

    fits: tuple
    selected_components: int
    share: float = 1.0
    statistics: dict = field(default_factory=dict)
    outlier: dict | None = None

    def __post_init__(self):
        object.__setattr__(self, "fits", tuple(sorted(self.fits, key=lambda fit: fit.n_components)))
        self.fit(self.selected_components)
        if self.outlier is not None:
            _ = self.mixture  # a bad outlier component fails here, not at first use

    def fit(self, n_components: int) -> MixtureFit:
        """The :class:`MixtureFit` with ``n_components`` components."""
        return _find_fit(self.fits, n_components)

    @property
    def mixture(self) -> GaussianMixture:
        """The selected :class:`GaussianMixture` (pixels), with the outlier component if there is one."""
        fitted = self.fit(self.selected_components).mixture
        if self.outlier is None:
            return fitted
        return fitted.with_component(self.outlier["weight"], self.outlier["mean"], self.outlier["sigma"])


def _describe(classes, k):
    bounds = classes.bounds(k)
    return ", ".join(f"{name} in [{lo:g}, {hi:g})" for name, (lo, hi) in bounds.items()) or "all pixels"
