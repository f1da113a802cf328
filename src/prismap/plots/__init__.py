"""Figures (matplotlib, no pyplot state): each module draws the results of one part of prismap."""

from prismap.plots._characterise import plot_class_fits, plot_error_fits, plot_error_tails
from prismap.plots._evaluate import (
    plot_evidence_histograms,
    plot_probability_histograms,
    plot_reliability,
    plot_reliability_logit,
)
from prismap.plots._maps import plot_map_3d, plot_map_slices
from prismap.plots._models import plot_divergence, plot_influence, plot_prism_sweeps, plot_ray_profiles

__all__ = [
    "plot_class_fits",
    "plot_divergence",
    "plot_evidence_histograms",
    "plot_error_fits",
    "plot_error_tails",
    "plot_influence",
    "plot_map_3d",
    "plot_map_slices",
    "plot_prism_sweeps",
    "plot_probability_histograms",
    "plot_ray_profiles",
    "plot_reliability",
    "plot_reliability_logit",
]
