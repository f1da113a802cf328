"""Choosing error classes by the log-likelihood of held-out errors.

Candidates are the plain model (one class) and quantile bins of one feature; then grids of quantile
bins of the best single feature and each other one (at most ``max_classes`` cells), a greedy small
tree. The bin counts per feature are those of :func:`bin_counts`: every count up to 6, then steps of
at most a third up to ``max_classes`` (8, 10, 12, 16, 20, 24, ...), so a bound of 24 costs about
twice the candidates of every count up to 12, not five times. Each candidate is scored by two-fold
cross-validation: fit one mixture per class and G (EM) on one fold, mix in the outlier floor
(:func:`outlier_component` of the fold's whole-image fit), add up the log-density of the other fold's
errors under its class's mixture, swap the folds; each class's G is the one scoring best over both
folds. The score is nats per
held-out error; the candidate with the highest score wins, the plain model included, so conditioning
is only chosen where it predicts unseen errors better. Quantile edges come from the features of all
samples (no error enters them). Errors beyond the histogram's ``+-limit_px`` are left out of every
score, as they are of every fit. Scoring fits histograms of :data:`SEARCH_BIN_WIDTH_PX` bins (EM costs
O(bins)) from one start (:data:`SEARCH_FIT`); the held-out log-densities are those of bin centres, the
same for every candidate.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from prismap._validate import check_integer
from prismap.characterise._class_model import ClassModel
from prismap.characterise._classes import ErrorClasses
from prismap.characterise._histogram import ErrorHistogram
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, fit_mixtures, fit_outlier_weight, select_components

MIN_CLASS_ERRORS = 1000
"""Fewest errors a class may hold in a training fold (fewer: the candidate is not tried)."""
SEARCH_FIT = {"restarts": 1, "tol": 1e-7, "max_iter": 300}
"""EM options while scoring candidates (the final fits use the caller's)."""
SEARCH_BIN_WIDTH_PX = 0.125
"""Bins of the held-out scoring (a whole multiple of the histogram's bins); the final fits use the histogram's."""


def quantile_edges(values, n_bins):
    """Interior edges of ``n_bins`` quantile bins of the finite ``values`` (duplicates merged).

    Each edge lies midway between the quantile (a value of the data) and the next smaller value, so
    no sample sits on an edge and float32 / float64 copies of one feature fall in the same bin.
    """
    return _SortedFeature(values).edges(n_bins)


class _SortedFeature:
    """One feature's finite values sorted once, so that the quantile edges of any bin count cost O(bins)."""

    def __init__(self, values):
        values = np.asarray(values)
        self.sorted = np.sort(values[np.isfinite(values)])
        self.distinct = (
            self.sorted[np.r_[True, self.sorted[1:] != self.sorted[:-1]]] if self.sorted.size else self.sorted
        )

    def edges(self, n_bins):
        """As :func:`quantile_edges` (``np.quantile(method="inverted_cdf")`` picks ``sorted[ceil(p N) - 1]``)."""
        if self.distinct.size < 2:
            return np.empty(0)
        n = self.sorted.size
        probabilities = np.arange(1, n_bins) / n_bins
        index = np.clip(np.ceil(probabilities * n).astype(np.int64) - 1, 0, n - 1)
        quantiles = np.unique(self.sorted[index])
        position = np.searchsorted(self.distinct, quantiles)
        position = position[position > 0]
        return np.unique(0.5 * (self.distinct[position - 1] + self.distinct[position]))


def bin_counts(max_classes):
    """Quantile bin counts the search tries per feature: every count up to 6, then 4, 5 or 6 times a power of two
    (8, 10, 12, 16, 20, 24, 32, ...: steps of at most a third), and ``max_classes`` itself."""
    ladder = {n for n in range(2, 7)} | {m << k for m in (4, 5, 6) for k in range(1, max(1, max_classes).bit_length())}
    return sorted(n for n in ladder | {max_classes} if 2 <= n <= max_classes)


def candidate_classes(values, *, max_classes, pair_with=None):
    """Candidate :class:`ErrorClasses` (duplicates and empty splits dropped).

    ``pair_with=None``: the plain model and quantile bins of each feature (each of :func:`bin_counts`).
    ``pair_with=name``: grids of quantile bins of ``name`` and each other feature (both counts of
    :func:`bin_counts`), at most ``max_classes`` cells.
    """
    return [
        ErrorClasses.from_edges(features, edges)
        for features, edges in _candidate_specs(
            {name: _SortedFeature(v) for name, v in values.items()}, max_classes, pair_with
        )
    ]


def _candidate_specs(features, max_classes, pair_with):
    """``(features, edges)`` of each candidate of :func:`candidate_classes` from :class:`_SortedFeature` s."""
    names, counts = list(features), bin_counts(max_classes)
    edges = {(name, n): tuple(float(x) for x in features[name].edges(n)) for name in names for n in counts}
    if pair_with is None:
        specs = [((), ())] + [((name,), (edges[name, n],)) for name in names for n in counts]
    else:
        specs = [
            ((pair_with, other), (edges[pair_with, n1], edges[other, n2]))
            for other in names
            if other != pair_with
            for n1 in counts
            for n2 in counts
            if n1 * n2 <= max_classes
        ]
    seen, unique = set(), []
    for spec in specs:
        if spec in seen or any(len(e) == 0 for e in spec[1]):
            continue
        seen.add(spec)
        unique.append(spec)
    return unique


def fit_class(counts, edges, *, max_components, criterion, tolerance, **em_options):
    """Fits for G = 1 .. min(max_components, occupied bins) of one class's histogram, and the selected G."""
    largest = int(min(max_components, np.count_nonzero(counts)))
    fits = fit_mixtures(edges, counts, max_components=largest, **em_options)
    return fits, select_components(fits, criterion=criterion, tolerance=tolerance)


def class_histograms(classes, values, errors, *, bin_width, limit_px, n_frames=1):
    """The errors of each class of ``classes`` in one :class:`ErrorHistogram` per class.

    Parameters
    ----------
    classes : ErrorClasses
    values : dict of str -> (N,) float, units of each feature
    errors : (N,) float64, pixels
    bin_width, limit_px : float, pixels
        The histogram bins (see :class:`~prismap.characterise.ErrorHistogram`).
    n_frames : int
        Frames the samples came from (recorded in each class's histogram).

    Returns
    -------
    tuple of ErrorHistogram
        One per class, in class order.
    """
    label = classes.assign(values, np.ones(np.shape(errors), bool))
    return tuple(
        dataclasses.replace(
            ErrorHistogram.from_errors(errors[label == k], bin_width=bin_width, limit_px=limit_px), n_frames=n_frames
        )
        for k in range(classes.n_classes)
    )


def fit_class_histograms(
    classes,
    histograms,
    *,
    max_components,
    criterion,
    tolerance,
    restarts=4,
    seed=0,
    components=None,
    outlier=None,
    search_range_px=None,
):
    """One mixture per class: EM on each class's histogram, G given or by the criterion.

    Parameters
    ----------
    classes : ErrorClasses
        Names a class without errors in the error message.
    histograms : sequence of ErrorHistogram
        One per class (:func:`class_histograms`, or merged over frames).
    max_components, criterion, tolerance, restarts, seed
        As in :func:`prismap.characterise.characterise_matcher`.
    components : sequence of int or None
        Each class's G (as :func:`choose_classes` chose it: at most the class's occupied bins); None = the
        smallest G within ``tolerance`` of the best ``criterion`` (:func:`prismap.gmm.select_components`).
    outlier : GaussianMixture or None
        One Gaussian (pixels) mixed into every class's mixture with the weight its errors give it
        (:func:`prismap.gmm.fit_outlier_weight`, one pseudo-error): the whole-image mixture's widest
        component (:func:`outlier_component`). None = none.
    search_range_px : (lo, hi), pixels, or None
        The matcher's search range: every class's mixture then has its own matcher-failure component,
        fitted with its Gaussians (:func:`prismap.gmm.fit_mixture`), in place of ``outlier``.

    Returns
    -------
    tuple of ClassModel
        Shares are of the errors that fall in a class.
    """
    n_classified = sum(part.n_errors for part in histograms)
    models = []
    for k, part in enumerate(histograms):
        if part.counts.sum() == 0:
            raise PrismapInputError(f"error class {k} ({classes.bounds(k)}) has no error to fit")
        fits, selected = fit_class(
            part.counts.astype(np.float64),
            part.edges,
            max_components=max_components,
            criterion=criterion,
            tolerance=tolerance,
            restarts=restarts,
            seed=seed,
            search_range_px=search_range_px,
        )
        if components is not None:
            selected = min(int(components[k]), len(fits))
        floor = None
        if outlier is not None and search_range_px is None:
            weight = fit_outlier_weight(fits[selected - 1].mixture, outlier, part.edges, part.counts)
            floor = {"weight": weight, "mean": float(outlier.means[0]), "sigma": float(outlier.sigmas[0])}
        models.append(ClassModel(tuple(fits), selected, part.n_errors / n_classified, part.statistics(), floor))
    return tuple(models)


def fit_classes(
    classes,
    values,
    errors,
    *,
    bin_width,
    limit_px,
    n_frames=1,
    max_components,
    criterion,
    tolerance,
    restarts=4,
    seed=0,
    components=None,
    outlier=None,
    search_range_px=None,
):
    """:func:`class_histograms` of the samples, then :func:`fit_class_histograms`: ``(class_models, histograms)``."""
    histograms = class_histograms(classes, values, errors, bin_width=bin_width, limit_px=limit_px, n_frames=n_frames)
    return fit_class_histograms(
        classes,
        histograms,
        max_components=max_components,
        criterion=criterion,
        tolerance=tolerance,
        restarts=restarts,
        seed=seed,
        components=components,
        outlier=outlier,
        search_range_px=search_range_px,
    ), histograms


def choose_classes(
    values: Mapping[str, np.ndarray],
    errors: np.ndarray,
    fold: np.ndarray,
    *,
    bin_edges: np.ndarray,
    max_classes: int,
    max_components: int,
    seed: int = 0,
    min_class_errors: int = MIN_CLASS_ERRORS,
    search_range_px: tuple[float, float] | None = None,
) -> tuple[ErrorClasses, dict[str, Any]]:
    """The candidate classes with the highest held-out log-likelihood, each class's G, and the record of the search.

    Each class's G (1 .. ``max_components``) is chosen by the same held-out log-likelihood as the classes,
    not by a criterion on the data it was fitted to. Every class's mixture is scored with the outlier
    component of the final fits mixed in (:func:`outlier_component` of the whole-image mixture fitted
    to the training fold): a class whose training errors hold no gross error would otherwise give the
    other fold's few gross errors log-densities of hundreds of nats, and the search would refuse fine
    classes for the tails they lack rather than for what they predict.

    Parameters
    ----------
    values : dict of str -> (N,) float, units of each feature
        Features of the characterised pixels (no NaN).
    errors : (N,) float64, pixels
        Their errors ``e = d_true - d_computed``.
    fold : (N,) int, 0 or 1
        Which held-out fold each pixel belongs to.
    bin_edges : (B + 1,) float64, pixels
        Histogram bins (as :attr:`ErrorHistogram.edges`).
    max_classes : int, >= 1
    max_components : int, >= 1
        Largest G tried per class.
    search_range_px : (lo, hi), pixels, or None
        The matcher's search range: every mixture scored then carries its own fitted matcher-failure
        component (as the final fits do) instead of the whole image's outlier component.

    Returns
    -------
    classes : ErrorClasses
    record : dict
        ``plain_nats_per_error``, ``conditioned_nats_per_error`` (the winner's), ``plain_components`` (the
        whole-image G), ``components`` (the winner's G per class), ``n_held_out_errors`` and every
        candidate's features, edges, number of classes, score (None when a class of it had fewer than
        ``min_class_errors`` training errors) and G per class.
    """
    check_integer(max_classes, "max_classes", expected="an integer >= 1", condition=lambda n: n >= 1)
    width = bin_edges[1] - bin_edges[0]
    index = np.floor((errors - bin_edges[0]) / width).astype(np.int64)
    binned = (index >= 0) & (index < bin_edges.size - 1)
    factor = max(1, round(SEARCH_BIN_WIDTH_PX / width))
    while (bin_edges.size - 1) % factor:
        factor -= 1
    bin_edges = bin_edges[::factor]
    fold = np.asarray(fold)
    options = {
        "max_components": check_integer(
            max_components, "max_components", expected="an integer >= 1", condition=lambda n: n >= 1
        ),
        "seed": seed,
        **SEARCH_FIT,
        "search_range_px": search_range_px,
    }
    search = _Search(
        values,
        binned,
        (fold[binned] != 0) * (bin_edges.size - 1) + index[binned] // factor,
        bin_edges,
        int(max_classes),
        int(min_class_errors),
        options,
    )
    too_few = f"too few errors to compare error classes: each fold needs at least {min_class_errors} errors"
    plain = search.histograms((), ())
    _, plain_components = search.score(plain, None)
    if plain_components is None:
        raise PrismapInputError(too_few)
    outliers = None if search_range_px is not None else {}
    for test_fold in (0, 1) if outliers is not None else ():
        fits = fit_mixtures(
            bin_edges, plain[0, 1 - test_fold], max_components=plain_components[0], seed=seed, **SEARCH_FIT
        )
        outliers[test_fold] = outlier_component(fits[-1].mixture)
    record = []
    best, best_score, best_components = None, -np.inf, None
    for stage in ("single", "pairs"):
        pair_with = None
        if stage == "pairs":
            if best is None or not best[0]:
                break
            pair_with = best[0][0]
        for features, edges in _candidate_specs(search.features, int(max_classes), pair_with):
            score, components = search.score(search.histograms(features, edges), outliers)
            record.append(
                {
                    "features": list(features),
                    "edges": [list(e) for e in edges],
                    "n_classes": int(np.prod([len(e) + 1 for e in edges])),
                    "nats_per_error": score,
                    "components": components,
                }
            )
            if score is not None and score > best_score + 1e-12:
                best, best_score, best_components = (features, edges), score, components
    if best is None:
        raise PrismapInputError(too_few)
    plain_components = record[0]["components"]
    return ErrorClasses.from_edges(*best), {
        "plain_nats_per_error": record[0]["nats_per_error"],
        "conditioned_nats_per_error": best_score,
        "plain_components": None if plain_components is None else plain_components[0],
        "components": best_components,
        "n_held_out_errors": int(binned.sum()),
        "min_class_errors": int(min_class_errors),
        "candidates": record,
    }


def outlier_component(mixture):
    """The widest component of ``mixture`` as a one-component :class:`~prismap.gmm.GaussianMixture` (pixels)."""
    j = int(np.argmax(mixture.sigmas))
    return GaussianMixture.gaussian(mixture.sigmas[j], mixture.means[j])


class _Search:
    """The binned held-out errors of the class search and the candidates' class histograms and scores.

    Each feature's values are sorted once (:class:`_SortedFeature`) and each pixel's interval between all
    of the feature's candidate edges found once, so a candidate's class of every pixel is one table look-up
    per feature and its histograms one ``bincount``.
    """

    def __init__(self, values, binned, fold_bin, bin_edges, max_classes, min_class_errors, options):
        self.features = {name: _SortedFeature(v) for name, v in values.items()}
        self.cuts, self.interval = {}, {}
        for name, feature in self.features.items():
            # every edge any candidate puts on this feature; a pixel's interval between them, found once
            self.cuts[name] = np.unique(np.concatenate([feature.edges(n) for n in bin_counts(max_classes)] + [[]]))
            self.interval[name] = np.searchsorted(
                self.cuts[name], np.asarray(values[name])[binned], side="right"
            ).astype(np.min_scalar_type(self.cuts[name].size))
        self.fold_bin = fold_bin  # (fold != 0) * bins + search bin, of each binned error
        self.bin_edges, self.centres = bin_edges, 0.5 * (bin_edges[:-1] + bin_edges[1:])
        self.min_class_errors, self.options = min_class_errors, options

    def histograms(self, features, edges):
        """(K, 2, bins) float64: each class's (row-major, as :meth:`ErrorClasses.from_edges`) errors per fold."""
        label = np.zeros(self.fold_bin.shape, np.int64)
        for name, interior in zip(features, edges):
            # the bin of the interval below cut i is the number of edges <= cut i - 1 (-inf for interval 0)
            lookup = np.searchsorted(np.asarray(interior), np.concatenate(([-np.inf], self.cuts[name])), side="right")
            label = label * (len(interior) + 1) + lookup[self.interval[name]]
        n_classes, n_bins = int(np.prod([len(e) + 1 for e in edges])), self.centres.size
        counts = np.bincount(label * (2 * n_bins) + self.fold_bin, minlength=n_classes * 2 * n_bins)
        return counts.reshape(n_classes, 2, n_bins).astype(np.float64)

    def score(self, histograms, outliers):
        """Nats per held-out error of one candidate and each class's G, or ``(None, None)``.

        Per class, G = 1 .. ``max_components`` are fitted on each fold and scored on the other (with
        ``outliers[test_fold]`` mixed in, unless ``outliers`` is None); the class's G is the one with the
        highest held-out log-likelihood summed over both folds, and that sum is its score.
        """
        max_components = self.options["max_components"]
        if (histograms.sum(axis=2) < self.min_class_errors).any():
            return None, None
        total, components = 0.0, []
        for k in range(histograms.shape[0]):
            scores = np.zeros(max_components)
            for test_fold in (0, 1):
                train, test = histograms[k, 1 - test_fold], histograms[k, test_fold]
                occupied = np.flatnonzero(test)
                fits = fit_mixtures(
                    self.bin_edges,
                    train,
                    max_components=int(min(max_components, np.count_nonzero(train))),
                    seed=self.options["seed"],
                    search_range_px=self.options["search_range_px"],
                    **SEARCH_FIT,
                )
                mixtures = [fit.mixture for fit in fits]
                if outliers is not None:
                    mixtures = [_with_outlier(m, outliers[test_fold], self.bin_edges, train) for m in mixtures]
                per_g = [float(test[occupied] @ m.logpdf(self.centres[occupied])) for m in mixtures]
                scores += np.pad(per_g, (0, max_components - len(per_g)), constant_values=-np.inf)
            components.append(int(np.argmax(scores)) + 1)
            total += float(scores.max())
        count = histograms.sum()
        return (float(total / count), components) if count else (None, None)


def _with_outlier(mixture, outlier, bin_edges, counts):
    weight = fit_outlier_weight(mixture, outlier, bin_edges, counts)
    return mixture.with_component(weight, outlier.means[0], outlier.sigmas[0])
