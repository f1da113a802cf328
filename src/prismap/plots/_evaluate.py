"""Figures of map scores: reliability diagrams and the P histograms of free and occupied voxels."""

import numpy as np

from prismap._files import atomic_path
from prismap.errors import PrismapInputError
from prismap.evaluate import MapScores


def plot_reliability(scores_by_model, *, path=None, title="Reliability"):
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


def plot_probability_histograms(scores_by_model, *, path=None, density=True):
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
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 2.2 + 2.2 * rows), layout="constrained")
    axes = fig.subplots(rows, 1, sharex=sharex, squeeze=False, gridspec_kw={"height_ratios": height_ratios})[:, 0]
    return fig, axes if rows > 1 else axes[0]


def _finish(fig, path):
    if path is not None:
        with atomic_path(path) as tmp:
            fig.savefig(tmp)
    return fig
