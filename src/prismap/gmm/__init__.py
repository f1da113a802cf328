"""1-D Gaussian mixtures: the disparity-error model of a stereo matcher (SENSOR_MODELS.md section 2)."""

from prismap.gmm._em import (
    DEFAULT_FAILURE_PRIOR,
    MixtureFit,
    failure_prior_bound,
    fit_histogram,
    fit_mixture,
    fit_mixtures,
    fit_outlier_weight,
    n_parameters,
    select_components,
)
from prismap.gmm._mixture import GaussianMixture

__all__ = [
    "DEFAULT_FAILURE_PRIOR",
    "GaussianMixture",
    "MixtureFit",
    "failure_prior_bound",
    "fit_histogram",
    "fit_mixture",
    "fit_mixtures",
    "fit_outlier_weight",
    "n_parameters",
    "select_components",
]
