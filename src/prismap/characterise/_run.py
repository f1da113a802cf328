"""Characterise a stereo matcher: its errors over frames with ground truth, fitted mixtures, files.

Conditioned characterisation streams: memory is bounded by one frame and the class-search sample,
whatever the number of frames. Work runs in chunks of frame positions whose results add up exactly
(integer counts, :class:`PixelSample` merges), so any chunking, here or on Dask workers, gives the same
model.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prismap._files import remove_stale_temporaries, write_text_atomic
from prismap._progress import progress as progress_bar
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
from prismap.characterise._model import HELD_OUT, ErrorModel, load_error_model, write_error_model
from prismap.characterise._model_table import format_table
from prismap.characterise._rig import describe_rig
from prismap.characterise._sample import DEFAULT_MAX_SAMPLES, PixelSample, characterised_pixels
from prismap.characterise._select import (
    choose_classes,
    class_histograms,
    fit_class_histograms,
    outlier_component,
)
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, fit_mixtures, select_components
from prismap.io._frame import StereoFrame
from prismap.stereo import StereoMatcher
from prismap.stereo._base import to_grey

DEFAULT_MAX_CLASSES = 24
"""Most error classes of a conditioned model (the held-out log-likelihood still chooses fewer where they predict better)."""
DEFAULT_SEARCH_FRAMES = 16
"""Frames, evenly spread over the selection, whose pixels the class search samples."""


@dataclasses.dataclass(frozen=True)
class Characterisation:
    """Result of :func:`characterise_matcher`: the merged error histograms and the fitted error model.

    Attributes
    ----------
    histogram : ErrorHistogram
        Every error of every frame.
    model : ErrorModel
    class_histograms : tuple of ErrorHistogram
        The errors of each class of ``model`` over every frame (one, ``histogram``, for a plain model).
    """

    histogram: ErrorHistogram
    model: ErrorModel
    class_histograms: tuple = ()

    @property
    def mixture(self) -> GaussianMixture:
        """The selected whole-image :class:`~prismap.gmm.GaussianMixture` (pixels)."""
        return self.model.mixture


@dataclasses.dataclass(frozen=True)
class FrameSettings:
    """How each frame is characterised: histogram bins, features, the class-search sample (picklable).

    Attributes
    ----------
    bin_width, limit_px : float, pixels
        See :class:`ErrorHistogram`.
    feature_settings : dict or None
        ``edge_threshold_px`` and ``texture_window_px`` of :func:`compute_features`; None = no features
        (a plain characterisation).
    max_samples : int
        Capacity of the class-search sample (:class:`PixelSample`).
    seed : int
        Seeds the sample's priorities.
    """

    bin_width: float = DEFAULT_BIN_WIDTH
    limit_px: float = DEFAULT_LIMIT_PX
    feature_settings: dict | None = None
    max_samples: int = DEFAULT_MAX_SAMPLES
    seed: int = 0


def frame_errors(frame, matcher, position, settings):
    """One frame's error histogram, its :class:`PixelFeatures` (None without ``feature_settings``) and its name.

    Parameters
    ----------
    frame : StereoFrame
        With ``disparity_gt`` (pixels).
    matcher : prismap.stereo.StereoMatcher
    position : int
        The frame's position in the selection.
    settings : FrameSettings
    """
    name = f"frame {position}" + (f" ({frame.name})" if frame.name else "")
    if frame.disparity_gt is None:
        raise PrismapInputError(f"{name}: has no ground-truth disparity; characterisation needs it")
    disparity, lr_disagreement = matcher.compute_with_confidence(frame.left, frame.right)
    histogram = ErrorHistogram.from_disparities(
        disparity, frame.disparity_gt, bin_width=settings.bin_width, limit_px=settings.limit_px, name=name
    )
    features = None
    if settings.feature_settings is not None:
        features = compute_features(
            to_grey(frame.left), to_grey(frame.right), disparity, lr_disagreement, **settings.feature_settings
        )
    return histogram, features, name


def histogram_chunk(frames, matcher, positions, settings):
    """The whole-image :class:`ErrorHistogram` of the frames at ``positions`` of ``frames`` (no features)."""
    settings = dataclasses.replace(settings, feature_settings=None)
    histogram = ErrorHistogram.empty(bin_width=settings.bin_width, limit_px=settings.limit_px)
    for position in positions:
        histogram = histogram + frame_errors(frames[position], matcher, position, settings)[0]
    return histogram


def sample_chunk(frames, matcher, positions, settings):
    """The whole-image histogram and the class-search :class:`PixelSample` of the frames at ``positions``."""
    histogram, sample = ErrorHistogram.empty(bin_width=settings.bin_width, limit_px=settings.limit_px), None
    for position in positions:
        frame = frames[position]
        part, features, name = frame_errors(frame, matcher, position, settings)
        part_sample = PixelSample.from_frame(
            features, frame.disparity_gt, position, capacity=settings.max_samples, seed=settings.seed, name=name
        )
        histogram, sample = histogram + part, part_sample if sample is None else sample + part_sample
    return histogram, sample


def class_histogram_chunk(frames, matcher, positions, settings, classes):
    """The whole-image histogram and one histogram per class of ``classes`` of the frames at ``positions``."""
    histogram = ErrorHistogram.empty(bin_width=settings.bin_width, limit_px=settings.limit_px)
    parts = [histogram] * classes.n_classes
    for position in positions:
        frame = frames[position]
        part, features, _ = frame_errors(frame, matcher, position, settings)
        truth = np.asarray(frame.disparity_gt, dtype=np.float64)
        keep = characterised_pixels(features, truth)
        frame_parts = class_histograms(
            classes,
            {name: array[keep] for name, array in features.values.items()},
            truth[keep] - features.values["disparity_px"][keep],
            bin_width=settings.bin_width,
            limit_px=settings.limit_px,
        )
        histogram = histogram + part
        parts = [a + b for a, b in zip(parts, frame_parts)]
    return histogram, tuple(parts)


def characterise_matcher(
    frames: Sequence[StereoFrame],
    matcher: StereoMatcher,
    *,
    max_components: int = 4,
    bin_width: float = DEFAULT_BIN_WIDTH,
    limit_px: float = DEFAULT_LIMIT_PX,
    dataset: str = "",
    criterion: str = "bic",
    tolerance: float = 0.01,
    restarts: int = 4,
    seed: int = 0,
    conditioned: bool = True,
    max_classes: int = DEFAULT_MAX_CLASSES,
    edge_threshold_px: float = DEFAULT_EDGE_THRESHOLD_PX,
    texture_window_px: int = DEFAULT_TEXTURE_WINDOW_PX,
    max_samples: int = DEFAULT_MAX_SAMPLES,
    search_frames: int = DEFAULT_SEARCH_FRAMES,
    progress: bool = True,
    map_chunks: Callable[..., Iterable[Any]] | None = None,
    chunk_frames: int = 1,
    source: str = "ground-truth",
    failures: bool = True,
) -> Characterisation:
    """Run ``matcher`` on ``frames``, histogram its errors and fit mixtures with G = 1..``max_components``.

    Each frame's errors ``e = d_true - d_computed`` are binned at once into the whole-image histogram.
    Following the thesis (sec. 3.3.1), every error is fitted, outliers included, so wide components
    model the matcher's gross mistakes. With ``conditioned=True`` the pixels' confidence features
    (:func:`prismap.characterise.compute_features`) are computed too, and memory stays bounded
    whatever the number of frames:

    1. A first pass over ``search_frames`` frames evenly spread over the selection keeps a seeded
       uniform sample of at most ``max_samples`` of their pixels (:class:`PixelSample`).
    2. Classes are chosen among quantile bins of the sampled features by held-out log-likelihood
       (:func:`choose_classes`: two-fold over frames of even and odd position, or over the left and
       right image halves when the sample holds one frame). The plain model is one of the candidates,
       so a model is conditioned only where that predicts held-out errors better.
    3. A second pass over every frame fills one :class:`ErrorHistogram` per class, and one mixture is
       fitted per class by EM. When the first pass covered every frame and kept every pixel, its
       sample is every error and the second pass is skipped (the same histograms, half the work).

    Parameters
    ----------
    frames : sequence of StereoFrame
        Each with ``disparity_gt`` (pixels, NaN or infinity = unknown). A lazy frame set
        (:func:`prismap.io.open_ground_truth`) holds one frame at a time; another iterable is read into
        a list first.
    matcher : prismap.stereo.StereoMatcher
        Deterministic: each frame may be matched twice.
    max_components : int
        Largest G fitted.
    bin_width : float, pixels
        Histogram bin width (at most 1/32 px keeps the binned fit close to a fit to the raw errors).
    limit_px : float, pixels
        Errors beyond ``+-limit_px`` are counted but not fitted (see :class:`ErrorHistogram`).
    dataset : str
        Name recorded in the error model.
    criterion, tolerance
        Selection of G of a plain characterisation (``conditioned=False``), see
        :func:`prismap.gmm.select_components`. A conditioned one chooses every G, the whole image's and each
        class's, by the held-out log-likelihood that chooses the classes (:func:`choose_classes`).
    restarts, seed
        EM starts, see :func:`prismap.gmm.fit_mixture`; ``seed`` also seeds the class-search sample.
    conditioned : bool
        Choose classes of pixels and fit one mixture per class (False: the plain whole-image model).
    max_classes : int, >= 1
        Most classes a candidate may have.
    edge_threshold_px, texture_window_px
        Feature settings (see :func:`prismap.characterise.compute_features`), stored in the model.
    max_samples : int, >= 1
        Most pixels (about 50 bytes each) the class search keeps.
    search_frames : int, >= 1
        Frames the class search samples from.
    progress : bool
        Show the frames done and the class-search and fitting steps on stderr (see :mod:`prismap._progress`).
    map_chunks : callable or None
        ``map_chunks(function, chunks)`` returns ``function(chunk)`` for each list of frame positions in
        ``chunks``, in order (e.g. on Dask workers: :func:`prismap.pipeline.characterise_sequence`);
        ``function`` pickles when ``frames`` and ``matcher`` do. None = here.
    chunk_frames : int, >= 1
        Frames per chunk. Results do not depend on it: histograms and samples merge exactly.
    source : str
        What ``disparity_gt`` is (``"ground-truth"``, ``"lidar"``, ``"self"``), recorded in the model with the
        rig of the first frame (its camera, image size and the matcher's parameters).
    failures : bool
        Give every mixture (whole-image and per class) the matcher-failure component uniform over the
        matcher's search range (:meth:`~prismap.stereo.StereoMatcher.search_range_px`), its weight fitted by
        MAP-EM with the Gaussians (:func:`prismap.gmm.fit_mixture`). False: Gaussians only, the classes
        with the whole image's widest component as their outlier floor (the format-2 model).

    Returns
    -------
    Characterisation
    """
    if not hasattr(frames, "__getitem__") or not hasattr(frames, "__len__"):
        frames = list(frames)
    for name, value in (("search_frames", search_frames), ("chunk_frames", chunk_frames)):
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise PrismapInputError(f"`{name}` must be an integer >= 1; got {value!r}")
    if len(frames) == 0:
        raise PrismapInputError("no frames to characterise: the frame set is empty")
    ErrorHistogram.empty(bin_width=bin_width, limit_px=limit_px)  # bad bins fail before any frame is matched
    feature_settings = (
        {"edge_threshold_px": float(edge_threshold_px), "texture_window_px": int(texture_window_px)}
        if conditioned
        else None
    )
    settings = FrameSettings(float(bin_width), float(limit_px), feature_settings, max_samples, int(seed))
    passes = _Passes(frames, matcher, settings, map_chunks or map, int(chunk_frames), progress)
    search_range = matcher.search_range_px() if failures and hasattr(matcher, "search_range_px") else None
    fit_options = {
        "max_components": max_components,
        "criterion": criterion,
        "tolerance": tolerance,
        "restarts": restarts,
        "seed": seed,
        "search_range_px": search_range,
    }
    every = list(range(len(frames)))
    first = frames[0]
    recorded = {
        "source": source,
        "rig": describe_rig(first.camera, np.shape(first.left)[:2], matcher.name, matcher.params()),
    }
    if not conditioned:
        histogram = passes.run(histogram_chunk, every, "histogram")
        return _fit(histogram, (histogram,), dict(recorded), matcher, dataset, fit_options, passes)
    searched = sorted({round(x) for x in np.linspace(0, len(frames) - 1, min(int(search_frames), len(frames)))})
    histogram, sample = passes.run(sample_chunk, searched, "sample for the class search")
    _check_fittable(histogram)
    values, errors, fold, held_out = sample.arrays()
    with passes.step(f"choose error classes on {sample.n_samples} of {sample.n_seen} pixels"):
        classes, record = choose_classes(
            values,
            errors,
            fold,
            bin_edges=histogram.edges,
            max_classes=max_classes,
            max_components=max_components,
            seed=seed,
            search_range_px=search_range,
        )
    record = {
        "held_out": held_out,
        "n_search_frames": len(searched),
        "n_samples": sample.n_samples,
        "n_search_pixels": sample.n_seen,
        **record,
    }
    conditioning = {"class_selection": record, **recorded}
    if not classes.features:  # the plain model predicts held-out errors best
        if len(searched) < len(frames):
            histogram = passes.run(histogram_chunk, every, "histogram")
        return _fit(histogram, (histogram,), conditioning, matcher, dataset, fit_options, passes)
    conditioning.update(classes=classes, feature_settings=feature_settings)
    if len(searched) == len(frames) and sample.exhaustive:  # the sample is every error: no second pass
        parts = class_histograms(
            classes,
            values,
            errors,
            bin_width=settings.bin_width,
            limit_px=settings.limit_px,
            n_frames=histogram.n_frames,
        )
    else:
        histogram, parts = passes.run(
            functools.partial(class_histogram_chunk, classes=classes), every, "class histograms"
        )
        parts = tuple(dataclasses.replace(part, n_frames=histogram.n_frames) for part in parts)
    return _fit(histogram, parts, conditioning, matcher, dataset, fit_options, passes)


def _check_fittable(histogram):
    if histogram.counts.sum() == 0:
        raise PrismapInputError(
            f"every one of the {histogram.n_errors} errors lies beyond +-{histogram.limit_px} px: nothing to fit"
        )


def _fit(histogram, parts, conditioning, matcher, dataset, fit_options, passes):
    """Fit the whole-image mixtures and, for a conditioned model, one per class; the :class:`Characterisation`."""
    _check_fittable(histogram)
    criterion, tolerance = fit_options["criterion"], fit_options["tolerance"]
    classes, record = conditioning.get("classes"), conditioning.get("class_selection")
    n_fits = 1 + (classes.n_classes if classes is not None else 0)
    with passes.step(f"fit {n_fits} mixture(s) by EM, G = 1..{fit_options['max_components']}"):
        fits = fit_mixtures(
            histogram.edges,
            histogram.counts,
            max_components=fit_options["max_components"],
            restarts=fit_options["restarts"],
            seed=fit_options["seed"],
            search_range_px=fit_options["search_range_px"],
        )
        if record is None:
            selected = select_components(fits, criterion=criterion, tolerance=tolerance)
            selection = {"criterion": criterion, "tolerance_nats_per_error": float(tolerance)}
        else:  # the class search chose G by held-out log-likelihood: the whole image's and each class's alike
            selected = min(record["plain_components"], len(fits))
            selection = {"criterion": HELD_OUT, "held_out": record["held_out"]}
        if classes is not None:
            conditioning["class_models"] = fit_class_histograms(
                classes,
                parts,
                components=record["components"],
                outlier=outlier_component(fits[selected - 1].mixture),
                **fit_options,
            )
    model = ErrorModel(
        matcher=matcher.name,
        matcher_params=matcher.params(),
        dataset=dataset,
        bin_width=histogram.bin_width,
        fits=tuple(fits),
        selected_components=selected,
        selection=selection,
        statistics=histogram.statistics(),
        **conditioning,
    )
    return Characterisation(histogram, model, tuple(parts))


def _add(a, b):
    """Merge two chunk results: histograms and samples add, tuples element-wise."""
    if isinstance(a, tuple):
        return tuple(_add(x, y) for x, y in zip(a, b))
    return a + b


class _Passes:
    """Runs chunk tasks over frame positions (here or through ``map_chunks``), merges them, shows progress."""

    def __init__(self, frames, matcher, settings, map_chunks, chunk_frames, enabled):
        self.frames, self.matcher, self.settings = frames, matcher, settings
        self.map_chunks, self.chunk_frames = map_chunks, chunk_frames
        self.enabled = None if enabled else False
        self.desc = f"characterise {matcher.name}"

    def run(self, task, positions, what):
        """``task(frames, matcher, chunk, settings)`` over chunks of ``positions``, merged."""
        chunks = [positions[i : i + self.chunk_frames] for i in range(0, len(positions), self.chunk_frames)]
        function = functools.partial(task, self.frames, self.matcher, settings=self.settings)
        total = None
        with progress_bar(total=len(positions), desc=f"{self.desc}: {what}", unit="frame", enabled=self.enabled) as bar:
            for chunk, result in zip(chunks, self.map_chunks(function, chunks)):
                total = result if total is None else _add(total, result)
                bar.update(len(chunk))
        return total

    @contextlib.contextmanager
    def step(self, what):
        """Announce one step of work (a one-item bar, or a line when it is done)."""
        with progress_bar(total=1, desc=f"{self.desc}: {what}", unit="step", enabled=self.enabled) as bar:
            yield
            bar.update(1)


CHARACTERISATION_FILES = {
    "model": "error_model.json",
    "table": "table.md",
    "figure": "errors.png",
    "figure_wide": "errors_wide.png",
}
"""What :func:`write_characterisation` writes, by role, in this order; a conditioned model adds
``figure_classes``: ``errors_classes.png``, last."""


def characterisation_paths(out_dir, *, conditioned):
    """The files of a characterisation in ``out_dir`` by role (:data:`CHARACTERISATION_FILES`)."""
    out = Path(out_dir)
    paths = {role: out / name for role, name in CHARACTERISATION_FILES.items()}
    if conditioned:
        paths["figure_classes"] = out / "errors_classes.png"
    return paths


def written_characterisation(out_dir):
    """The paths of a complete characterisation in ``out_dir``, or None when it must be written (again).

    Complete means every file of :func:`characterisation_paths` is there, the classes figure included when
    the model is conditioned (a run killed while drawing it left the rest). Temporaries of saves killed
    mid-write are removed either way.
    """
    paths = characterisation_paths(out_dir, conditioned=True)
    for path in paths.values():
        remove_stale_temporaries(path)
    if not paths["model"].is_file():
        return None
    try:
        conditioned = load_error_model(paths["model"]).conditioned
    except PrismapInputError:
        return None
    paths = characterisation_paths(out_dir, conditioned=conditioned)
    return paths if all(path.is_file() for path in paths.values()) else None


def write_characterisation(result: Characterisation, out_dir: str | os.PathLike[str]) -> dict[str, Path]:
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
    paths = characterisation_paths(out, conditioned=result.model.conditioned)
    write_error_model(result.model, paths["model"])
    write_text_atomic(paths["table"], format_table(result.model))
    plot_error_fits(result.histogram, result.model, path=paths["figure"])
    plot_error_tails(result.histogram, result.model, path=paths["figure_wide"])
    if result.model.conditioned:
        plot_class_fits(result.class_histograms, result.model, path=paths["figure_classes"])
    return paths
