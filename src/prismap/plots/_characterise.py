"""Figures of a matcher's disparity errors with the fitted mixtures (after thesis figs. 3.8-3.10), whole and per class."""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from prismap._files import atomic_path
from prismap.characterise import ErrorHistogram, ErrorModel
from prismap.errors import PrismapInputError


def plot_error_fits(
    histogram: ErrorHistogram,
    model: ErrorModel,
    *,
    path: str | os.PathLike[str] | None = None,
    half_width_px: float | None = None,
) -> Figure:
    """Error histogram as a density with the fitted mixtures for G = 1, 2, 3 and the selected G.

    One panel per G over a narrow range around the peak, where the dominant components live.

    Parameters
    ----------
    histogram : prismap.characterise.ErrorHistogram
    model : prismap.characterise.ErrorModel
    path : str or Path or None, keyword-only
        Where to save the figure (format from the suffix), written atomically.
    half_width_px : float, pixels, keyword-only
        Half-width of the range shown; default ``max(4, 5 sigma)`` of the selected model's heaviest
        component, like the thesis's -4..4 px.

    Returns
    -------
    matplotlib.figure.Figure
    """
    density_edges, density, total = _display_density(histogram)
    dominant = model.mixture
    centre = float(dominant.means[0])
    half = float(half_width_px) if half_width_px is not None else max(4.0, float(np.ceil(5 * dominant.sigmas[0])))
    available = {fit.n_components for fit in model.fits}
    panels = sorted(({1, 2, 3} & available) | {model.selected_components})
    columns = 2 if len(panels) == 4 else len(panels)
    rows = -(-len(panels) // columns)
    fig = Figure(figsize=(4.2 * columns, 3.2 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, columns, squeeze=False).ravel())
    low, high = centre - half, centre + half
    factor = max(1, round(2 * half / histogram.bin_width / 256))
    edges, values = _rebin(density_edges, density, factor, low, high)
    x = np.linspace(low, high, 2001)
    for ax, g in zip(axes, panels):
        fit = model.fit(g)
        ax.stairs(values, edges, fill=True, alpha=0.45, color="0.45", label="error hist")
        ax.plot(x, fit.mixture.pdf(x), color="C3", lw=1.6, label="GMM")
        title = f"G = {g}" + (" (selected)" if g == model.selected_components else "") + _failure_label(fit.mixture)
        ax.set_title(f"{title}: ln L / N = {fit.mean_log_likelihood:.3f}", fontsize=10)
        ax.set_xlim(low, high)
        ax.set_ylim(bottom=0)
        ax.set_xlabel("error e = d_true - d_computed (px)")
        ax.set_ylabel("probability density")
        ax.legend(fontsize=8, loc="upper right")
    for ax in axes[len(panels) :]:
        ax.set_visible(False)
    fig.suptitle(f"{model.matcher} on {model.dataset or 'data'}: {total} errors", fontsize=11)
    return _finish(fig, path)


def plot_error_tails(
    histogram: ErrorHistogram, model: ErrorModel, *, path: str | os.PathLike[str] | None = None
) -> Figure:
    """The whole error range on a log density axis, so the wide outlier components show.

    The histogram is shown in bins of about 1/4 px with the selected mixture and the single Gaussian.

    Parameters
    ----------
    histogram : prismap.characterise.ErrorHistogram
    model : prismap.characterise.ErrorModel
    path : str or Path or None, keyword-only

    Returns
    -------
    matplotlib.figure.Figure
    """
    edges, density, total = _display_density(histogram)
    occupied = np.flatnonzero(histogram.counts)
    low = float(edges[occupied[0]]) - 1.0
    high = float(edges[occupied[-1] + 1]) + 1.0
    factor = max(1, round(0.25 / histogram.bin_width))
    edges, values = _rebin(edges, density, factor, low, high)
    fig = Figure(figsize=(8, 3.6), layout="constrained")
    ax = fig.subplots()
    shown = np.where(values > 0, values, np.nan)
    ax.stairs(np.nan_to_num(shown, nan=0.0), edges, fill=True, alpha=0.45, color="0.45", label="error hist")
    x = np.linspace(low, high, 4001)
    selected = model.selected_components
    ax.plot(
        x,
        model.mixture.pdf(x),
        color="C3",
        lw=1.4,
        label=f"GMM, G = {selected} (selected)" + _failure_label(model.mixture),
    )
    if model.mixture.failure_weight > 0:
        ax.axhline(model.mixture.failure_density, color="C2", lw=0.9, ls=":", label="failure floor w_f / W")
    if selected != 1 and any(fit.n_components == 1 for fit in model.fits):
        ax.plot(x, model.fit(1).mixture.pdf(x), color="C0", lw=1.0, ls="--", label="GMM, G = 1")
    floor = 1.0 / (total * histogram.bin_width * factor)
    ax.set_yscale("log")
    ax.set_ylim(0.3 * floor, 2.0 * np.nanmax(shown))
    ax.set_xlim(low, high)
    ax.set_xlabel("error e = d_true - d_computed (px)")
    ax.set_ylabel("probability density")
    outside = histogram.n_below + histogram.n_above
    ax.set_title(
        f"{model.matcher} on {model.dataset or 'data'}: all {total} binned errors"
        + (f" ({outside} beyond +-{histogram.limit_px:g} px not shown)" if outside else ""),
        fontsize=10,
    )
    ax.legend(fontsize=8)
    return _finish(fig, path)


def plot_class_fits(
    class_histograms: Sequence[ErrorHistogram],
    model: ErrorModel,
    *,
    path: str | os.PathLike[str] | None = None,
    half_width_px: float = 8.0,
) -> Figure:
    """One panel per error class: its errors as a log density with its selected mixture and the plain one.

    The per-class view of a conditioned error model: how the error spreads from the class nearest the
    failures to the most reliable one, against the whole-image mixture every pixel would get otherwise.

    Parameters
    ----------
    class_histograms : sequence of prismap.characterise.ErrorHistogram
        The errors of each class, in class order (``Characterisation.class_histograms``).
    model : prismap.characterise.ErrorModel
    path : str or Path or None, keyword-only
        Where to save the figure, written atomically.
    half_width_px : float, pixels, keyword-only
        Half-width of the error range shown, around 0.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if len(class_histograms) != model.n_classes:
        raise PrismapInputError(f"{model.n_classes} class(es) need as many histograms; got {len(class_histograms)}")
    columns = min(3, model.n_classes)
    rows = -(-model.n_classes // columns)
    fig = Figure(figsize=(4.2 * columns, 3.2 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, columns, squeeze=False).ravel())
    half = float(half_width_px)
    x = np.linspace(-half, half, 2001)
    factor = max(1, round(0.125 / class_histograms[0].bin_width))
    for k, (ax, histogram, class_model) in enumerate(zip(axes, class_histograms, model.class_models)):
        density_edges, density, total = _display_density(histogram)
        edges, values = _rebin(density_edges, density, factor, -half, half)
        ax.stairs(values, edges, fill=True, alpha=0.45, color="0.45", label="error hist")
        ax.plot(
            x,
            class_model.mixture.pdf(x),
            color="C3",
            lw=1.4,
            label=f"class GMM, G = {class_model.selected_components}" + _failure_label(class_model.mixture),
        )
        ax.plot(x, model.mixture.pdf(x), color="C0", lw=1.0, ls="--", label="plain GMM")
        ax.set_yscale("log")
        positive = values[values > 0]
        ax.set_ylim(0.3 * (positive.min() if positive.size else 1e-6), 2.0 * max(values.max(), 1e-6))
        ax.set_xlim(-half, half)
        bounds = "; ".join(f"{name} [{lo:.3g}, {hi:.3g})" for name, (lo, hi) in model.classes.bounds(k).items())
        ax.set_title(f"class {k}: {bounds}\n{100 * class_model.share:.1f} % of pixels, {total} errors", fontsize=9)
        ax.set_xlabel("error e = d_true - d_computed (px)")
        ax.set_ylabel("probability density")
        ax.legend(fontsize=7, loc="upper right")
    for ax in axes[model.n_classes :]:
        ax.set_visible(False)
    fig.suptitle(f"{model.matcher} on {model.dataset or 'data'}: errors by class", fontsize=11)
    return _finish(fig, path)


def _display_density(histogram):
    if histogram.counts.sum() == 0:
        raise PrismapInputError("the error histogram is empty: nothing to plot")
    return histogram.edges, histogram.density(), int(histogram.counts.sum())


def _rebin(edges, density, factor, low, high):
    """Average ``factor`` neighbouring bins and keep those overlapping ``[low, high]``."""
    usable = (density.size // factor) * factor
    merged = density[:usable].reshape(-1, factor).mean(axis=1)
    merged_edges = edges[: usable + 1 : factor]
    keep = (merged_edges[1:] > low) & (merged_edges[:-1] < high)
    index = np.flatnonzero(keep)
    return merged_edges[index[0] : index[-1] + 2], merged[index]


def _finish(fig, path):
    if path is not None:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
    return fig


def _failure_label(mixture):
    """``", w_f 1.2e-03 over W 96 px"`` for a mixture with a matcher-failure component, else ``""``."""
    if mixture.search_range_px is None:
        return ""
    return f", w_f {mixture.failure_weight:.1e} over W {mixture.failure_width:g} px"
