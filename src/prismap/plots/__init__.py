"""Figures (matplotlib, no pyplot state): each module draws the results of one part of prismap."""

from prismap.plots._characterise import plot_error_fits, plot_error_tails
from prismap.plots._evaluate import plot_probability_histograms, plot_reliability

__all__ = ["plot_error_fits", "plot_error_tails", "plot_probability_histograms", "plot_reliability"]
