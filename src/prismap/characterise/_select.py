"""Choosing error classes by the log-likelihood of held-out errors.

Candidates are the plain model (one class) and quantile bins of one feature (2 .. ``max_classes`` bins);
then grids of quantile bins of the best single feature and each other one (at most ``max_classes``
cells), a greedy small tree. Each is scored by two-fold
cross-validation: fit one mixture per class and G (EM) on one fold, mix in the outlier floor
(:func:`outlier_component` of the fold's whole-image fit), add up the log-density of the other fold's
errors under its class's mixture, swap the folds; each class's G is the one scoring best over both
folds. The score is nats per
held-out error; the candidate with the highest score wins, the plain model included, so conditioning
is only chosen where it predicts unseen errors better. Quantile edges come from the features of all
samples (no error enters them). Errors beyond the histogram's ``+-limit_px`` are left out of every
score, as they are of every fit. Scoring fits histograms of :data:`SEARCH_BIN_WIDTH_PX` bins (EM costs
O(bins)); the held-out log-densities are those of bin centres, the same for every candidate.
"""

import dataclasses

import numpy as np

from prismap._validate import check_integer
from prismap.characterise._classes import ErrorClasses
from prismap.characterise._histogram import ErrorHistogram
from prismap.characterise._model import ClassModel
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, fit_mixtures, fit_outlier_weight, select_components

MIN_CLASS_ERRORS = 1000
"""Fewest errors a class may hold in a training fold (fewer: the candidate is not tried)."""
SEARCH_FIT = {"restarts": 2, "tol": 1e-7, "max_iter": 300}
"""EM options while scoring candidates (the final fits use the caller's)."""
SEARCH_BIN_WIDTH_PX = 0.125
"""Bins of the held-out scoring (a whole multiple of the histogram's bins); the final fits use the histogram's."""


def quantile_edges(values, n_bins):
    """Interior edges of ``n_bins`` quantile bins of the finite ``values`` (duplicates merged).

    Each edge lies midway between the quantile (a value of the data) and the next smaller value, so
    no sample sits on an edge and float32 / float64 copies of one feature fall in the same bin.
    """
    finite = np.unique(values[np.isfinite(values)])
    if finite.size < 2:
        return np.empty(0)
    quantiles = np.unique(np.quantile(values[np.isfinite(values)], np.arange(1, n_bins) / n_bins,
                                      method="inverted_cdf"))
    position = np.searchsorted(finite, quantiles)
    position = position[position > 0]
    return np.unique(0.5 * (finite[position - 1] + finite[position]))


def candidate_classes(values, *, max_classes, pair_with=None):
    """Candidate :class:`ErrorClasses` (duplicates and empty splits dropped).

    ``pair_with=None``: the plain model and quantile bins of each feature (2 .. ``max_classes`` bins).
    ``pair_with=name``: grids of quantile bins of ``name`` and each other feature, at most
    ``max_classes`` cells.
    """
    names = list(values)
    edges = {(name, n): tuple(quantile_edges(values[name], n)) for name in names for n in range(2, max_classes + 1)}
    if pair_with is None:
        specs = [((), ())] + [((name,), (edges[name, n],)) for name in names for n in range(2, max_classes + 1)]
    else:
        specs = [((pair_with, other), (edges[pair_with, n1], edges[other, n2]))
                 for other in names if other != pair_with
                 for n1 in range(2, max_classes // 2 + 1) for n2 in range(2, max_classes // n1 + 1)]
    seen, candidates = set(), []
    for features, feature_edges in specs:
        key = (features, feature_edges)
        if key in seen or any(len(e) == 0 for e in feature_edges):
            continue
        seen.add(key)
        candidates.append(ErrorClasses.from_edges(features, feature_edges))
    return candidates


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
    return tuple(dataclasses.replace(ErrorHistogram.from_errors(errors[label == k], bin_width=bin_width,
                                                                limit_px=limit_px), n_frames=n_frames)
                 for k in range(classes.n_classes))


def fit_class_histograms(classes, histograms, *, max_components, criterion, tolerance, restarts=4, seed=0,
                         components=None, outlier=None):
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
        fits, selected = fit_class(part.counts.astype(np.float64), part.edges, max_components=max_components,
                                   criterion=criterion, tolerance=tolerance, restarts=restarts, seed=seed)
        if components is not None:
            selected = min(int(components[k]), len(fits))
        floor = None
        if outlier is not None:
            weight = fit_outlier_weight(fits[selected - 1].mixture, outlier, part.edges, part.counts)
            floor = {"weight": weight, "mean": float(outlier.means[0]), "sigma": float(outlier.sigmas[0])}
        models.append(ClassModel(tuple(fits), selected, part.n_errors / n_classified, part.statistics(), floor))
    return tuple(models)


def fit_classes(classes, values, errors, *, bin_width, limit_px, n_frames=1, max_components, criterion, tolerance,
                restarts=4, seed=0, components=None, outlier=None):
    """:func:`class_histograms` of the samples, then :func:`fit_class_histograms`: ``(class_models, histograms)``."""
    histograms = class_histograms(classes, values, errors, bin_width=bin_width, limit_px=limit_px, n_frames=n_frames)
    return fit_class_histograms(classes, histograms, max_components=max_components, criterion=criterion,
                                tolerance=tolerance, restarts=restarts, seed=seed, components=components,
                                outlier=outlier), histograms


def choose_classes(values, errors, fold, *, bin_edges, max_classes, max_components, seed=0,
                   min_class_errors=MIN_CLASS_ERRORS):
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

    Returns
    -------
    classes : ErrorClasses
    record : dict
        ``plain_nats_per_error``, ``conditioned_nats_per_error`` (the winner's), ``plain_components`` (the
        whole-image G), ``components`` (the winner's G per class), ``n_held_out_errors`` and every
        candidate's features, edges, number of classes, score (None when a class of it had fewer than
        ``min_class_errors`` training errors) and G per class.
    """
    if isinstance(max_classes, bool) or int(max_classes) != max_classes or max_classes < 1:
        raise PrismapInputError(f"`max_classes` must be an integer >= 1; got {max_classes!r}")
    width = bin_edges[1] - bin_edges[0]
    index = np.floor((errors - bin_edges[0]) / width).astype(np.int64)
    binned = (index >= 0) & (index < bin_edges.size - 1)
    factor = max(1, round(SEARCH_BIN_WIDTH_PX / width))
    while (bin_edges.size - 1) % factor:
        factor -= 1
    index //= factor
    bin_edges = bin_edges[::factor]
    centres = 0.5 * (bin_edges[:-1] + bin_edges[1:])
    fold = np.asarray(fold)
    options = {"max_components": check_integer(max_components, "max_components", expected="an integer >= 1",
                                                      condition=lambda n: n >= 1), "seed": seed, **SEARCH_FIT}
    too_few = f"too few errors to compare error classes: each fold needs at least {min_class_errors} errors"
    _, plain_components = _held_out_score(np.zeros(errors.shape, np.int32), 1, index, binned, fold, bin_edges,
                                          centres, min_class_errors, options, None)
    if plain_components is None:
        raise PrismapInputError(too_few)
    outliers = {}
    for test_fold in (0, 1):
        train = np.bincount(index[binned & (fold != test_fold)], minlength=centres.size).astype(np.float64)
        fits = fit_mixtures(bin_edges, train, max_components=plain_components[0], seed=seed, **SEARCH_FIT)
        outliers[test_fold] = outlier_component(fits[-1].mixture)
    record = []
    best, best_score, best_components = None, -np.inf, None
    for stage in ("single", "pairs"):
        pair_with = None
        if stage == "pairs":
            if best is None or not best.features:
                break
            pair_with = best.features[0]
        for classes in candidate_classes(values, max_classes=int(max_classes), pair_with=pair_with):
            label = classes.assign(values, np.ones(errors.shape, bool))
            score, components = _held_out_score(label, classes.n_classes, index, binned, fold, bin_edges, centres,
                                                min_class_errors, options, outliers)
            record.append({"features": list(classes.features),
                           "edges": [sorted({b for b in classes.upper[:, f] if np.isfinite(b)})
                                     for f in range(len(classes.features))],
                           "n_classes": classes.n_classes, "nats_per_error": score, "components": components})
            if score is not None and score > best_score + 1e-12:
                best, best_score, best_components = classes, score, components
    if best is None:
        raise PrismapInputError(too_few)
    n_held_out = int(binned.sum())
    plain_components = record[0]["components"]
    return best, {"plain_nats_per_error": record[0]["nats_per_error"], "conditioned_nats_per_error": best_score,
                  "plain_components": None if plain_components is None else plain_components[0],
                  "components": best_components, "n_held_out_errors": n_held_out,
                  "min_class_errors": int(min_class_errors), "candidates": record}


def outlier_component(mixture):
    """The widest component of ``mixture`` as a one-component :class:`~prismap.gmm.GaussianMixture` (pixels)."""
    j = int(np.argmax(mixture.sigmas))
    return GaussianMixture.gaussian(mixture.sigmas[j], mixture.means[j])


def _held_out_score(label, n_classes, index, binned, fold, bin_edges, centres, min_class_errors, options, outliers):
    """Nats per held-out error of one candidate and each class's G, or ``(None, None)``.

    Per class, G = 1 .. ``max_components`` are fitted on each fold and scored on the other (with
    ``outliers[test_fold]`` mixed in, unless ``outliers`` is None); the class's G is the one with the
    highest held-out log-likelihood summed over both folds, and that sum is its score.
    """
    n_bins, max_components = centres.size, options["max_components"]
    total, count, components = 0.0, 0, []
    for k in range(n_classes):
        in_class = binned & (label == k)
        scores = np.zeros(max_components)
        for test_fold in (0, 1):
            train = np.bincount(index[in_class & (fold != test_fold)], minlength=n_bins).astype(np.float64)
            test = np.bincount(index[in_class & (fold == test_fold)], minlength=n_bins)
            if train.sum() < min_class_errors:
                return None, None
            occupied = np.flatnonzero(test)
            fits = fit_mixtures(bin_edges, train, max_components=int(min(max_components, np.count_nonzero(train))),
                                seed=options["seed"], **SEARCH_FIT)
            mixtures = [fit.mixture for fit in fits]
            if outliers is not None:
                mixtures = [_with_outlier(m, outliers[test_fold], bin_edges, train) for m in mixtures]
            per_g = [float(test[occupied] @ m.logpdf(centres[occupied])) for m in mixtures]
            scores += np.pad(per_g, (0, max_components - len(per_g)), constant_values=-np.inf)
        components.append(int(np.argmax(scores)) + 1)
        total += float(scores.max())
        count += int(in_class.sum())
    return (total / count, components) if count else (None, None)


def _with_outlier(mixture, outlier, bin_edges, counts):
    weight = fit_outlier_weight(mixture, outlier, bin_edges, counts)
    return mixture.with_component(weight, outlier.means[0], outlier.sigmas[0])
