"""1-D Gaussian mixtures: the disparity-error model of a stereo matcher (SENSOR_MODELS.md section 2)."""

from prismap.gmm._em import (
    MixtureFit,
    fit_histogram,
    fit_mixture,
    fit_mixtures,
    fit_outlier_weight,
    select_components,
)
from prismap.gmm._mixture import GaussianMixture

__all__ = ["GaussianMixture", "MixtureFit", "fit_histogram", "fit_mixture", "fit_mixtures", "fit_outlier_weight",
           "select_components"]
