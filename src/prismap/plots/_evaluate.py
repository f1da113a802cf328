"""Figures of map scores: reliability diagrams (equal-width and logit-spaced), the P histograms of free and occupied
voxels, and the histograms of the evidence frames gave the voxels."""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np
from matplotlib.figure import Figure

from prismap._files import atomic_path
from prismap.errors import PrismapInputError
from prismap.evaluate import MapScores


def plot_reliability(
    scores_by_model: Mapping[str, MapScores], *, path: str | os.PathLike[str] | None = None, title: str = "Reliability"
) -> Figure:
    """Reliability diagram of several maps in one figure.

    Parameters
    ----------
    scores_by_model : dict of str -> prismap.evaluate.MapScores
        One curve per model, labelled by its key with its ECE.
    path : str or Path or None, keyword-only
        Where to save the figure (format from the suffix), written atomically.
    title : str, keyword-only

    Returns
    -------
    matplotlib.figure.Figure
        Mean predicted ``P`` per bin (x) against the occupied fraction (y); empty bins are left
        out, the diagonal is perfect calibration, and a lower panel shows the voxels per bin.
    """
    scores_by_model = _check_scores(scores_by_model)
    fig, (ax, ax_count) = _figure(2, sharex=True, height_ratios=(3, 1))
    ax.plot([0, 1], [0, 1], color="0.6", linestyle="--", linewidth=1, label="perfectly calibrated")
    for name, scores in scores_by_model.items():
        filled = scores.bin_counts > 0
        (line,) = ax.plot(
            scores.bin_mean_probability[filled],
            scores.bin_occupied_fraction[filled],
            marker="o",
            label=f"{name} (ECE {scores.ece:.3f})",
        )
        centres = 0.5 * (scores.bin_edges[:-1] + scores.bin_edges[1:])
        ax_count.step(centres, scores.bin_counts, where="mid", color=line.get_color())
    ax.set(xlim=(0, 1), ylim=(0, 1), ylabel="occupied fraction", title=title)
    ax.legend(loc="upper left", fontsize="small")
    ax_count.set(xlabel="predicted P(occupied)", ylabel="voxels", yscale="log")
    return _finish(fig, path)


def plot_reliability_logit(
    scores_by_model: Mapping[str, MapScores],
    *,
    path: str | os.PathLike[str] | None = None,
    title: str = "Reliability at the extremes",
) -> Figure:
    """Reliability diagram on log-odds axes, from the logit-spaced bins (:data:`prismap.evaluate.LOGIT_BIN_EDGES`).

    Equal-width bins put every ``P`` below 0.1 in one bin; these reach ``P`` of 1e-4 and 1 - 1e-4, where a
    map that is "confident and wrong" shows as points far from the diagonal.

    Parameters
    ----------
    scores_by_model : dict of str -> prismap.evaluate.MapScores
    path : str or Path or None, keyword-only
        Where to save the figure, written atomically.
    title : str, keyword-only

    Returns
    -------
    matplotlib.figure.Figure
        ``logit`` of the mean predicted ``P`` per bin (x) against ``logit`` of the occupied fraction (y; bins
        with no occupied or no free voxel are drawn at the axis's end, +-10), the diagonal perfect calibration;
        a lower panel shows the voxels per bin. Each label carries the "confident and wrong" rates.
    """
    scores_by_model = _check_scores(scores_by_model)
    fig, (ax, ax_count) = _figure(2, sharex=True, height_ratios=(3, 1))
    limit = 10.0
    ax.plot([-limit, limit], [-limit, limit], color="0.6", linestyle="--", linewidth=1, label="perfectly calibrated")
    for name, scores in scores_by_model.items():
        filled = scores.logit_bin_counts > 0
        x = _logit(scores.logit_bin_mean_probability[filled], limit)
        y = _logit(scores.logit_bin_occupied_fraction[filled], limit)
        (line,) = ax.plot(
            x,
            y,
            marker="o",
            label=f"{name} (free at P>=0.99 {scores.free_confident_occupied:.2%}, "
            f"occupied at P<=0.01 {scores.occupied_confident_free:.2%})",
        )
        ax_count.plot(x, scores.logit_bin_counts[filled], marker=".", color=line.get_color())
    ax.set(xlim=(-limit, limit), ylim=(-limit - 0.5, limit + 0.5), ylabel="logit of the occupied fraction", title=title)
    ax.legend(loc="upper left", fontsize="x-small")
    ax_count.set(xlabel="logit of the predicted P(occupied)", ylabel="voxels", yscale="log")
    return _finish(fig, path)


def plot_evidence_histograms(
    scores_by_model: Mapping[str, MapScores],
    *,
    path: str | os.PathLike[str] | None = None,
    title: str = "Evidence per frame",
) -> Figure:
    """Histograms of the log-odds increments frames gave the voxels, one panel per model.

    Parameters
    ----------
    scores_by_model : dict of str -> prismap.evaluate.MapScores
        Scores made with ``evidence`` (:func:`prismap.evaluate.score_map`); models without it are skipped.
    path : str or Path or None, keyword-only
        Where to save the figure, written atomically.
    title : str, keyword-only

    Returns
    -------
    matplotlib.figure.Figure
        Voxels per bin of the symmetric-log edges (:data:`prismap.evaluate.EVIDENCE_EDGES`) on a log scale:
        the increments of voxels one frame observed, and every voxel's mean increment per frame. Mass far
        out (beyond +-20 nats, a likelihood ratio of 5e8) is evidence no stereo frame can justify.
    """
    scores_by_model = {name: s for name, s in _check_scores(scores_by_model).items() if s.evidence_per_view.any()}
    if not scores_by_model:
        raise PrismapInputError("no model's scores carry evidence histograms (score_map(..., evidence=...))")
    fig, axes = _figure(len(scores_by_model), sharex=True)
    for ax, (name, scores) in zip(np.atleast_1d(axes), scores_by_model.items()):
        edges = scores.evidence_edges
        position = np.arange(len(edges) - 1)
        ax.bar(position - 0.2, scores.evidence_one_view, width=0.4, color="tab:purple", label="voxels seen once")
        ax.bar(position + 0.2, scores.evidence_per_view, width=0.4, color="tab:gray", label="mean per frame, all")
        ax.set(title=name, ylabel="voxels", yscale="log")
        ax.legend(fontsize="small")
    last = np.atleast_1d(axes)[-1]
    ticks = np.arange(0, len(edges), 3)
    last.set_xticks(ticks - 0.5, [f"{edges[t]:.3g}" for t in ticks], rotation=45, fontsize="small")
    last.set_xlabel("log-odds increment (nats)")
    fig.suptitle(title)
    return _finish(fig, path)


def _logit(p, limit):
    """``logit(p)`` clipped to ``+-limit`` (0 and 1 land on the ends)."""
    with np.errstate(divide="ignore"):
        return np.clip(np.log(p) - np.log1p(-p), -limit, limit)


def plot_probability_histograms(
    scores_by_model: Mapping[str, MapScores], *, path: str | os.PathLike[str] | None = None, density: bool = True
) -> Figure:
    """Histograms of ``P`` for truly free and truly occupied voxels, one panel per model.

    Parameters
    ----------
    scores_by_model : dict of str -> prismap.evaluate.MapScores
    path : str or Path or None, keyword-only
        Where to save the figure, written atomically.
    density : bool, keyword-only
        Normalise each class to unit area, so a rare class stays visible (thesis fig. 6.7).

    Returns
    -------
    matplotlib.figure.Figure
        A good map puts free voxels left of 0.5 and occupied voxels right of it.
    """
    scores_by_model = _check_scores(scores_by_model)
    fig, axes = _figure(len(scores_by_model), sharex=True)
    for ax, (name, scores) in zip(np.atleast_1d(axes), scores_by_model.items()):
        widths = np.diff(scores.hist_edges)
        classes = ((scores.hist_free, "free", "tab:blue"), (scores.hist_occupied, "occupied", "tab:red"))
        for counts, label, color in classes:
            total = counts.sum()
            heights = counts / (total * widths) if density and total else counts
            ax.bar(scores.hist_edges[:-1], heights, width=widths, align="edge", alpha=0.5, color=color, label=label)
        ax.axvline(0.5, color="0.4", linewidth=1)
        ax.set(title=name, ylabel="density" if density else "voxels")
        ax.legend(fontsize="small")
    np.atleast_1d(axes)[-1].set_xlabel("predicted P(occupied)")
    return _finish(fig, path)


def _check_scores(scores_by_model):
    if not isinstance(scores_by_model, dict) or not scores_by_model:
        raise PrismapInputError(
            f"`scores_by_model` must be a non-empty dict of name -> MapScores; got {scores_by_model!r:.80}"
        )
    for name, scores in scores_by_model.items():
        if not isinstance(scores, MapScores):
            raise PrismapInputError(f"`scores_by_model[{name!r}]` must be a MapScores; got {type(scores).__name__}")
    return scores_by_model


def _figure(rows, *, sharex, height_ratios=None):

    fig = Figure(figsize=(6, 2.2 + 2.2 * rows), layout="constrained")
    axes = fig.subplots(rows, 1, sharex=sharex, squeeze=False, gridspec_kw={"height_ratios": height_ratios})[:, 0]
    return fig, axes if rows > 1 else axes[0]


def _finish(fig, path):
    if path is not None:
        with atomic_path(path) as tmp:
            fig.savefig(tmp)
    return fig
