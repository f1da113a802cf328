"""Characterise a stereo matcher: its errors over frames with ground truth, fitted mixtures, files."""

from dataclasses import dataclass
from pathlib import Path

from prismap._files import write_text_atomic
from prismap._progress import progress
from prismap.characterise._histogram import DEFAULT_BIN_WIDTH, DEFAULT_LIMIT_PX, ErrorHistogram
from prismap.characterise._model import ErrorModel, format_table, write_error_model
from prismap.errors import PrismapInputError
from prismap.gmm import fit_mixtures, select_components


@dataclass(frozen=True)
class Characterisation:
    """Result of :func:`characterise_matcher`: the merged error histogram and the fitted error model."""

    histogram: ErrorHistogram
    model: ErrorModel

    @property
    def mixture(self):
        """The selected :class:`~prismap.gmm.GaussianMixture` (pixels)."""
        return self.model.mixture


def characterise_matcher(frames, matcher, *, max_components=4, bin_width=DEFAULT_BIN_WIDTH,
                         limit_px=DEFAULT_LIMIT_PX, dataset="", criterion="bic", tolerance=0.01, restarts=4,
                         seed=0):
    """Run ``matcher`` on ``frames``, histogram its errors and fit mixtures with G = 1..``max_components``.

    Each frame's errors ``e = d_true - d_computed`` are binned and dropped at once, so memory does not
    grow with the number of frames. Following the thesis (sec. 3.3.1), every error is fitted,
    outliers included, so wide components model the matcher's gross mistakes.

    Parameters
    ----------
    frames : iterable of StereoFrame
        Each with ``disparity_gt`` (pixels, NaN or infinity = unknown).
    matcher : prismap.stereo.StereoMatcher
    max_components : int
        Largest G fitted.
    bin_width : float, pixels
        Histogram bin width (at most 1/32 px keeps the binned fit close to a fit to the raw errors).
    limit_px : float, pixels
        Errors beyond ``+-limit_px`` are counted but not fitted (see :class:`ErrorHistogram`).
    dataset : str
        Name recorded in the error model.
    criterion, tolerance
        Selection of G, see :func:`prismap.gmm.select_components`.
    restarts, seed
        EM starts, see :func:`prismap.gmm.fit_mixture`.

    Returns
    -------
    Characterisation
    """
    histogram = ErrorHistogram.empty(bin_width=bin_width, limit_px=limit_px)
    total = len(frames) if hasattr(frames, "__len__") else None
    for index, frame in enumerate(progress(frames, total=total, desc=f"characterise {matcher.name}")):
        name = f"frame {index}" + (f" ({frame.name})" if frame.name else "")
        if frame.disparity_gt is None:
            raise PrismapInputError(f"{name}: has no ground-truth disparity; characterisation needs it")
        disparity = matcher.compute(frame.left, frame.right)
        histogram = histogram + ErrorHistogram.from_disparities(
            disparity, frame.disparity_gt, bin_width=bin_width, limit_px=limit_px, name=name
        )
    if histogram.n_frames == 0:
        raise PrismapInputError("no frames to characterise: the frame set is empty")
    if histogram.counts.sum() == 0:
        raise PrismapInputError(
            f"every one of the {histogram.n_errors} errors lies beyond +-{histogram.limit_px} px: nothing to fit"
        )
    fits = fit_mixtures(histogram.edges, histogram.counts, max_components=max_components, restarts=restarts, seed=seed)
    selected = select_components(fits, criterion=criterion, tolerance=tolerance)
    model = ErrorModel(
        matcher=matcher.name,
        matcher_params=matcher.params(),
        dataset=dataset,
        bin_width=histogram.bin_width,
        fits=tuple(fits),
        selected_components=selected,
        selection={"criterion": criterion, "tolerance_nats_per_error": float(tolerance)},
        statistics=histogram.statistics(),
    )
    return Characterisation(histogram, model)


def write_characterisation(result, out_dir):
    """Write ``error_model.json``, ``table.md``, ``errors.png`` and ``errors_wide.png`` into ``out_dir``.

    Returns
    -------
    dict of str -> Path: the written files by role (``model``, ``table``, ``figure``, ``figure_wide``).
    """
    from prismap.plots import plot_error_fits, plot_error_tails

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise PrismapInputError(f"output directory {out} exists and is not a directory")
    paths = {
        "model": out / "error_model.json",
        "table": out / "table.md",
        "figure": out / "errors.png",
        "figure_wide": out / "errors_wide.png",
    }
    write_error_model(result.model, paths["model"])
    write_text_atomic(paths["table"], format_table(result.model))
    plot_error_fits(result.histogram, result.model, path=paths["figure"])
    plot_error_tails(result.histogram, result.model, path=paths["figure_wide"])
    return paths
