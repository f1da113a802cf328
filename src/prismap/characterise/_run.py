"""Characterise a stereo matcher: its errors over frames with ground truth, fitted mixtures, files."""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prismap._files import write_text_atomic
from prismap._progress import progress
from prismap.characterise._features import (
    DEFAULT_EDGE_THRESHOLD_PX,
    DEFAULT_TEXTURE_WINDOW_PX,
    compute_features,
)
from prismap.characterise._histogram import (
    DEFAULT_BIN_WIDTH,
    DEFAULT_LIMIT_PX,
    ErrorHistogram,
)
from prismap.characterise._model import ErrorModel, format_table, write_error_model
from prismap.characterise._select import choose_classes, fit_classes
from prismap.errors import PrismapInputError
from prismap.gmm import fit_mixtures, select_components
from prismap.stereo._base import to_grey

DEFAULT_MAX_CLASSES = 6
DEFAULT_MAX_PIXELS = 30_000_000


@dataclass(frozen=True)
class Characterisation:
    """Result of :func:`characterise_matcher`: the merged error histograms and the fitted error model.

    Attributes
    ----------
    histogram : ErrorHistogram
        Every error of every frame.
    model : ErrorModel
    class_histograms : tuple of ErrorHistogram
        The errors of each class of ``model`` (one, equal to ``histogram``'s binned errors, for a plain model).
    """

    histogram: ErrorHistogram
    model: ErrorModel
    class_histograms: tuple = ()

    @property
    def mixture(self):
        """The selected whole-image :class:`~prismap.gmm.GaussianMixture` (pixels)."""
        return self.model.mixture


def characterise_matcher(frames, matcher, *, max_components=4, bin_width=DEFAULT_BIN_WIDTH,
                         limit_px=DEFAULT_LIMIT_PX, dataset="", criterion="bic", tolerance=0.01, restarts=4,
                         seed=0, conditioned=True, max_classes=DEFAULT_MAX_CLASSES,
                         edge_threshold_px=DEFAULT_EDGE_THRESHOLD_PX, texture_window_px=DEFAULT_TEXTURE_WINDOW_PX,
                         max_pixels=DEFAULT_MAX_PIXELS):
    """Run ``matcher`` on ``frames``, histogram its errors and fit mixtures with G = 1..``max_components``.

    Each frame's errors ``e = d_true - d_computed`` are binned at once into the whole-image histogram.
    Following the thesis (sec. 3.3.1), every error is fitted, outliers included, so wide components
    model the matcher's gross mistakes. With ``conditioned=True`` the pixels' confidence features
    (:func:`prismap.characterise.compute_features`) are kept too, classes are chosen among quantile
    bins of them by held-out log-likelihood (:func:`choose_classes`: two-fold over frames of even and
    odd index, or over the left and right image halves when there is one frame), and one mixture is
    fitted per class. The plain model is one of the candidates, so a model is conditioned only where
    that predicts held-out errors better.

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
    conditioned : bool
        Choose classes of pixels and fit one mixture per class (False: the plain whole-image model).
    max_classes : int, >= 1
        Most classes a candidate may have.
    edge_threshold_px, texture_window_px
        Feature settings (see :func:`prismap.characterise.compute_features`), stored in the model.
    max_pixels : int
        Most characterised pixels whose features are kept (about 30 bytes each) with ``conditioned``.

    Returns
    -------
    Characterisation
    """
    histogram = ErrorHistogram.empty(bin_width=bin_width, limit_px=limit_px)
    settings = {"edge_threshold_px": edge_threshold_px, "texture_window_px": texture_window_px}
    samples = _Samples(max_pixels) if conditioned else None
    total = len(frames) if hasattr(frames, "__len__") else None
    for index, frame in enumerate(progress(frames, total=total, desc=f"characterise {matcher.name}")):
        name = f"frame {index}" + (f" ({frame.name})" if frame.name else "")
        if frame.disparity_gt is None:
            raise PrismapInputError(f"{name}: has no ground-truth disparity; characterisation needs it")
        disparity, lr_disagreement = matcher.compute_with_confidence(frame.left, frame.right)
        histogram = histogram + ErrorHistogram.from_disparities(
            disparity, frame.disparity_gt, bin_width=bin_width, limit_px=limit_px, name=name
        )
        if samples is not None:
            features = compute_features(to_grey(frame.left), to_grey(frame.right), disparity, lr_disagreement,
                                        **settings)
            samples.add(features, np.asarray(frame.disparity_gt, dtype=np.float64), index, name)
    if histogram.n_frames == 0:
        raise PrismapInputError("no frames to characterise: the frame set is empty")
    if histogram.counts.sum() == 0:
        raise PrismapInputError(
            f"every one of the {histogram.n_errors} errors lies beyond +-{histogram.limit_px} px: nothing to fit"
        )
    fit_options = {"restarts": restarts, "seed": seed}
    fits = fit_mixtures(histogram.edges, histogram.counts, max_components=max_components, **fit_options)
    selected = select_components(fits, criterion=criterion, tolerance=tolerance)
    conditioning, class_histograms = {}, (histogram,)
    if samples is not None:
        conditioning, class_histograms = _conditioning(samples, histogram, max_classes=max_classes,
                                                       max_components=max_components, criterion=criterion,
                                                       tolerance=tolerance, fit_options=fit_options,
                                                       feature_settings=features.settings)
    model = ErrorModel(
        matcher=matcher.name,
        matcher_params=matcher.params(),
        dataset=dataset,
        bin_width=histogram.bin_width,
        fits=tuple(fits),
        selected_components=selected,
        selection={"criterion": criterion, "tolerance_nats_per_error": float(tolerance)},
        statistics=histogram.statistics(),
        **conditioning,
    )
    return Characterisation(histogram, model, class_histograms)


class _Samples:
    """Features and errors of every characterised pixel, with the frame and image half (columns) it came from."""

    def __init__(self, max_pixels):
        self.max_pixels = int(max_pixels)
        self.n_pixels = 0
        self.values, self.errors, self.frame, self.right_half = {}, [], [], []

    def add(self, features, disparity_gt, index, name):
        computed = features.values["disparity_px"]
        if disparity_gt.shape != computed.shape:
            raise PrismapInputError(f"{name}: disparity and ground truth differ in shape: "
                                    f"{computed.shape} vs {disparity_gt.shape}")
        keep = features.valid & np.isfinite(disparity_gt)
        for array in features.values.values():
            keep &= ~np.isnan(array)
        self.n_pixels += int(keep.sum())
        if self.n_pixels > self.max_pixels:
            raise PrismapInputError(
                f"{name}: conditioned characterisation keeps the features of every characterised pixel and the "
                f"frames so far hold {self.n_pixels} > max_pixels = {self.max_pixels}; use fewer frames "
                "(or every K-th) or the plain model"
            )
        if self.values and set(self.values) != set(features.names):
            raise PrismapInputError(f"{name}: has features {features.names}; earlier frames had {tuple(self.values)}")
        for feature, array in features.values.items():
            self.values.setdefault(feature, []).append(array[keep].astype(np.float32))
        self.errors.append((disparity_gt - computed)[keep])
        self.frame.append(np.full(int(keep.sum()), index, dtype=np.int32))
        columns = np.broadcast_to(np.arange(keep.shape[1])[None, :], keep.shape)
        self.right_half.append(columns[keep] >= keep.shape[1] / 2)

    def arrays(self):
        values = {name: np.concatenate(parts).astype(np.float64) for name, parts in self.values.items()}
        frame = np.concatenate(self.frame)
        if np.unique(frame).size >= 2:
            return values, np.concatenate(self.errors), frame % 2, "two folds: frames of even / odd index"
        return values, np.concatenate(self.errors), np.concatenate(self.right_half).astype(np.int64), (
            "two folds: left / right image halves (one frame)")


def _conditioning(samples, histogram, *, max_classes, max_components, criterion, tolerance, fit_options,
                  feature_settings):
    """Classes chosen by held-out likelihood, one mixture per class on all errors, and the class histograms."""
    values, errors, fold, held_out = samples.arrays()
    classes, record = choose_classes(values, errors, fold, bin_edges=histogram.edges, max_classes=max_classes,
                                     max_components=max_components, criterion=criterion, tolerance=tolerance,
                                     seed=fit_options["seed"])
    record = {"held_out": held_out, **record}
    if not classes.features:  # the plain model predicts held-out errors best
        return {"class_selection": record}, (histogram,)
    models, histograms = fit_classes(classes, values, errors, bin_width=histogram.bin_width,
                                     limit_px=histogram.limit_px, n_frames=histogram.n_frames,
                                     max_components=max_components, criterion=criterion, tolerance=tolerance,
                                     **fit_options)
    return {"classes": classes, "class_models": models, "class_selection": record,
            "feature_settings": feature_settings}, histograms


def write_characterisation(result, out_dir):
    """Write ``error_model.json``, ``table.md``, ``errors.png``, ``errors_wide.png`` into ``out_dir``.

    A conditioned model adds ``errors_classes.png`` (one panel per class).

    Returns
    -------
    dict of str -> Path: the written files by role (``model``, ``table``, ``figure``, ``figure_wide``,
    and ``figure_classes`` for a conditioned model).
    """
    from prismap.plots import plot_class_fits, plot_error_fits, plot_error_tails

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise PrismapInputError(f"output directory {out} exists and is not a directory")
    paths = {
        "model": out / "error_model.json",
        "table": out / "table.md",
        "figure": out / "errors.png",
        "figure_wide": out / "errors_wide.png",
    }
    if result.model.conditioned:
        paths["figure_classes"] = out / "errors_classes.png"
    write_error_model(result.model, paths["model"])
    write_text_atomic(paths["table"], format_table(result.model))
    plot_error_fits(result.histogram, result.model, path=paths["figure"])
    plot_error_tails(result.histogram, result.model, path=paths["figure_wide"])
    if result.model.conditioned:
        plot_class_fits(result.class_histograms, result.model, path=paths["figure_classes"])
    return paths
