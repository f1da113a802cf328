"""Figures of the sensor-model study along one ray: profiles, PRISM sweeps, influence, divergences."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt
from matplotlib.figure import Figure

from prismap.errors import PrismapInputError
from prismap.plots._evaluate import _finish
from prismap.study import ModelComparison, RayProfile


def _figure(n_panels, *, ncols=2, sharey=True):

    ncols = min(ncols, n_panels)
    nrows = -(-n_panels // ncols)
    fig = Figure(figsize=(5.0 * ncols, 3.2 * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False, sharey=sharey).ravel()
    for ax in axes[n_panels:]:
        ax.set_visible(False)
    return fig, axes[:n_panels]


def _window(profile, pad_m):
    """x-range around the measurement: from 0 to past the measurement by ``pad_m`` or the influence."""
    return 0.0, max(profile.measured_m + pad_m, min(max(profile.influence_m.values()), 2.0 * profile.measured_m))


def plot_ray_profiles(comparison: ModelComparison, *, path: str | os.PathLike[str] | None = None) -> Figure:
    """Every model's ``P`` along the ray, one panel per measured distance (thesis figs 5.2-5.7, 6.1, 6.2).

    Parameters
    ----------
    comparison : prismap.study.ModelComparison
    path : str or Path or None, keyword-only
        Where to save the figure (format from the suffix), written atomically.

    Returns
    -------
    matplotlib.figure.Figure
        ``P`` per cell (steps) against distance along the ray (metres); the prior is dashed and the
        measured distance dotted.
    """
    if not comparison.profiles:
        raise PrismapInputError("the comparison has no profiles to plot")
    fig, axes = _figure(len(comparison.profiles))
    for ax, profile in zip(axes, comparison.profiles):
        for name, posterior in profile.posterior.items():
            ax.stairs(posterior, profile.edges_m, baseline=None, label=name, linewidth=2.0 if name == "prism" else 1.2)
        ax.axhline(profile.prior, color="0.5", linestyle="--", linewidth=1, label="prior p0")
        ax.axvline(profile.measured_m, color="0.3", linestyle=":", linewidth=1)
        ax.set(
            xlim=_window(profile, 2.0),
            title=f"measured {profile.measured_m:.2f} m (d = {profile.disparity_px:g} px)",
            xlabel="distance along the ray (m)",
            ylabel="P(occupied)",
        )
    axes[0].legend(fontsize="small")
    return _finish(fig, path)


def plot_prism_sweeps(
    sweeps: Mapping[str, Sequence[tuple[str, RayProfile]]], *, path: str | os.PathLike[str] | None = None
) -> Figure:
    """PRISM's profile as one parameter varies: one panel per sweep (thesis figs 5.11-5.15).

    Parameters
    ----------
    sweeps : dict of str -> list of (label, RayProfile)
        As returned by :func:`prismap.study.prism_sweeps`.
    path : str or Path or None, keyword-only

    Returns
    -------
    matplotlib.figure.Figure
        ``P`` per cell against distance along the ray; each curve's prior is a dashed line
        of its colour (the cell-size sweep changes the cell prior).
    """
    if not sweeps:
        raise PrismapInputError("no sweeps to plot")
    fig, axes = _figure(len(sweeps), sharey=False)
    for ax, (title, curves) in zip(axes, sweeps.items()):
        right = 0.0
        for label, profile in curves:
            patch = ax.stairs(profile.posterior["prism"], profile.edges_m, baseline=None, label=label)
            ax.axhline(profile.prior, color=patch.get_edgecolor(), linestyle="--", linewidth=0.8)
            right = max(right, _window(profile, 2.0)[1])
        ax.set(xlim=(0.0, right), title=f"PRISM: {title}", xlabel="distance along the ray (m)", ylabel="P(occupied)")
        ax.legend(fontsize="small")
    return _finish(fig, path)


def plot_influence(
    measured_m: npt.ArrayLike,
    bound_m: npt.ArrayLike,
    observed_m: npt.ArrayLike,
    *,
    path: str | os.PathLike[str] | None = None,
) -> Figure:
    """PRISM's maximum influence distance behind the measurement against the measured distance.

    Parameters
    ----------
    measured_m, bound_m, observed_m : (D,) float64, metres
        As returned by :func:`prismap.study.influence_distances`.
    path : str or Path or None, keyword-only

    Returns
    -------
    matplotlib.figure.Figure
    """
    measured_m, bound_m, observed_m = (np.asarray(a, dtype=np.float64) for a in (measured_m, bound_m, observed_m))
    if not measured_m.size or not (measured_m.shape == bound_m.shape == observed_m.shape):
        raise PrismapInputError("`measured_m`, `bound_m` and `observed_m` must be non-empty and of one shape")
    fig, (ax,) = _figure(1)
    ax.plot(measured_m, bound_m, marker="o", label="bound used by ray casting (influence_depth)")
    ax.plot(measured_m, observed_m, marker="s", label="last cell with |increment| >= epsilon")
    ax.axhline(0.0, color="0.5", linewidth=0.8)
    ax.set(
        xlabel="measured distance (m)",
        ylabel="influence behind the measurement (m)",
        title="PRISM: maximum influence distance",
    )
    ax.legend(fontsize="small")
    return _finish(fig, path)


def plot_divergence(comparison: ModelComparison, *, path: str | os.PathLike[str] | None = None) -> Figure:
    """Each model's divergence from PRISM against the measured distance: MAD, KL and cleared occupancy.

    Parameters
    ----------
    comparison : prismap.study.ModelComparison
    path : str or Path or None, keyword-only

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not comparison.divergences:
        raise PrismapInputError("the comparison has no model besides PRISM")
    measured = [p.measured_m for p in comparison.profiles]
    metrics = (
        ("mad", "mean |P - P_prism| per cell"),
        ("kl", "mean KL(PRISM || model) per cell (nats)"),
        ("cleared", "PRISM occupancy the model clears (cells)"),
    )
    fig, axes = _figure(len(metrics), ncols=3, sharey=False)
    for ax, (key, label) in zip(axes, metrics):
        for name, values in comparison.divergences.items():
            ax.plot(measured, values[key], marker="o", label=name)
        ax.set(xlabel="measured distance (m)", ylabel=label)
    axes[0].legend(fontsize="small")
    return _finish(fig, path)
