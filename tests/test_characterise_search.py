"""The class search: its bin-count ladder, its quantile edges, and its agreement with a brute-force search."""

import itertools

import numpy as np
import pytest

from prismap.characterise import ErrorClasses, ErrorHistogram, choose_classes
from prismap.characterise._select import (
    SEARCH_BIN_WIDTH_PX,
    SEARCH_FIT,
    bin_counts,
    candidate_classes,
    outlier_component,
    quantile_edges,
)
from prismap.gmm import fit_mixtures, fit_outlier_weight


def test_bin_counts_are_every_count_to_six_then_steps_of_at_most_a_third_up_to_the_bound():
    assert bin_counts(1) == []
    assert bin_counts(6) == [2, 3, 4, 5, 6]
    assert bin_counts(7) == [2, 3, 4, 5, 6, 7]  # the bound itself is always tried
    assert bin_counts(24) == [2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24]
    for bound in range(2, 100):
        counts = bin_counts(bound)
        assert counts[-1] == bound and counts == sorted(set(counts))
        assert all(b <= a * 4 / 3 + 1e-9 for a, b in itertools.pairwise(counts) if a >= 6)


def _numpy_quantile_edges(values, n_bins):
    """The definition: midway between each ``np.quantile(inverted_cdf)`` and the next smaller distinct value."""
    finite = np.unique(values[np.isfinite(values)])
    if finite.size < 2:
        return np.empty(0)
    quantiles = np.unique(
        np.quantile(values[np.isfinite(values)], np.arange(1, n_bins) / n_bins, method="inverted_cdf")
    )
    position = np.searchsorted(finite, quantiles)
    position = position[position > 0]
    return np.unique(0.5 * (finite[position - 1] + finite[position]))


def test_quantile_edges_agree_with_numpy_quantile_on_ties_infinities_and_tiny_samples():
    rng = np.random.default_rng(5)
    for trial in range(150):
        n = int(rng.integers(1, 200))
        values = rng.integers(0, int(rng.integers(1, 30)), n).astype(float) if trial % 2 else rng.normal(size=n)
        values[rng.random(n) < 0.1 * (trial % 3)] = np.inf
        for n_bins in (2, 3, 7, 12, 24, 37):
            np.testing.assert_array_equal(quantile_edges(values, n_bins), _numpy_quantile_edges(values, n_bins))


# --- the search against a brute-force one -----------------------------------------------------------

EDGE_SIGMAS = (2.0, 0.9, 0.4, 0.2)
"""Core sigma (pixels) of the errors at edge distance 0, 1, 2, 3 px."""


def _two_feature_samples(seed, n=24000):
    """Errors whose width depends on the edge distance (4 levels) and doubles on steep gradients (above 0.1)."""
    rng = np.random.default_rng(seed)
    distance = rng.integers(0, 4, n).astype(float)
    gradient = rng.exponential(0.1 / np.log(2), n)  # median 0.1
    texture = rng.uniform(0, 20, n)  # carries no information
    sigma = np.take(EDGE_SIGMAS, distance.astype(int)) * np.where(gradient > 0.1, 2.0, 1.0)
    errors = rng.normal(0.0, sigma) + np.where(rng.random(n) < 0.02, rng.normal(0, 8.0, n), 0.0)
    values = {"edge_distance_px": distance, "disparity_gradient": gradient, "texture": texture}
    return values, errors, rng.integers(0, 2, n)


def _brute_force_search(values, errors, fold, bin_edges, max_classes, max_components, min_class_errors=1000):
    """Every bin count 2 .. max_classes (singles, then grids with the best single feature), class by mask."""
    factor = round(SEARCH_BIN_WIDTH_PX / (bin_edges[1] - bin_edges[0]))
    edges = bin_edges[::factor]
    centres = 0.5 * (edges[1:] + edges[:-1])
    index = np.floor((errors - edges[0]) / (edges[1] - edges[0])).astype(np.int64)
    binned = (index >= 0) & (index < centres.size)

    def histogram(mask):
        return np.bincount(index[mask & binned], minlength=centres.size).astype(np.float64)

    plain = {f: histogram(fold == f) for f in (0, 1)}
    outliers = {}
    for test_fold in (0, 1):
        fits = fit_mixtures(edges, plain[1 - test_fold], max_components=max_components, **SEARCH_FIT)
        outliers[test_fold] = outlier_component(fits[-1].mixture)

    def score(classes):
        label = classes.assign(values, np.ones(errors.size, bool))
        total = 0.0
        for k in range(classes.n_classes):
            per_g = np.zeros(max_components)
            for test_fold in (0, 1):
                train, test = (
                    histogram((label == k) & (fold != test_fold)),
                    histogram((label == k) & (fold == test_fold)),
                )
                if train.sum() < min_class_errors:
                    return None
                for g, fit in enumerate(fit_mixtures(edges, train, max_components=max_components, **SEARCH_FIT)):
                    weight = fit_outlier_weight(fit.mixture, outliers[test_fold], edges, train)
                    mixture = fit.mixture.with_component(
                        weight, outliers[test_fold].means[0], outliers[test_fold].sigmas[0]
                    )
                    per_g[g] += test @ np.where(test > 0, mixture.logpdf(centres), 0.0)
            total += per_g.max()
        return total / binned.sum()

    def grid(features, counts):
        cuts = [tuple(quantile_edges(values[f], n)) for f, n in zip(features, counts)]
        return None if any(len(c) == 0 for c in cuts) else ErrorClasses.from_edges(features, cuts)

    singles = [ErrorClasses.single()] + [grid((f,), (n,)) for f in values for n in range(2, max_classes + 1)]
    scored = {}
    for classes in singles:
        if classes is not None:
            scored.setdefault((classes.features, classes.upper.tobytes()), (score(classes), classes))
    best = max((s for s in scored.values() if s[0] is not None), key=lambda s: s[0])
    if best[1].features:
        first = best[1].features[0]
        for other in (f for f in values if f != first):
            for n1 in range(2, max_classes + 1):
                for n2 in range(2, max_classes // n1 + 1):
                    classes = grid((first, other), (n1, n2))
                    if classes is not None:
                        scored.setdefault((classes.features, classes.upper.tobytes()), (score(classes), classes))
    return scored


def test_the_search_chooses_what_a_brute_force_search_over_every_bin_count_chooses():
    values, errors, fold = _two_feature_samples(11)
    bin_edges = ErrorHistogram.empty().edges
    classes, record = choose_classes(values, errors, fold, bin_edges=bin_edges, max_classes=8, max_components=2)
    brute = _brute_force_search(values, errors, fold, bin_edges, max_classes=8, max_components=2)
    score, best = max((s for s in brute.values() if s[0] is not None), key=lambda s: s[0])
    assert classes.features == best.features == ("edge_distance_px", "disparity_gradient")
    np.testing.assert_array_equal(classes.lower, best.lower)
    np.testing.assert_array_equal(classes.upper, best.upper)
    assert record["conditioned_nats_per_error"] == pytest.approx(score, rel=1e-9)
    # every candidate the search scored is scored alike by the brute force (same classes, same EM)
    for candidate in record["candidates"]:
        tried = ErrorClasses.from_edges(candidate["features"], candidate["edges"])
        reference = brute[(tried.features, tried.upper.tobytes())][0]
        if reference is None:
            assert candidate["nats_per_error"] is None
        else:
            assert candidate["nats_per_error"] == pytest.approx(reference, rel=1e-9)
    # the ladder skips 7 bins only: the brute force tried more candidates, the search no class it did not
    assert len(record["candidates"]) < len(brute)
    assert max(c["n_classes"] for c in record["candidates"]) <= 8


def test_candidate_classes_of_a_larger_bound_use_the_ladder_and_never_exceed_the_bound():
    values, _, _ = _two_feature_samples(2, n=5000)
    values = {"disparity_gradient": values["disparity_gradient"], "texture": values["texture"]}
    singles = candidate_classes(values, max_classes=24)
    assert singles[0].features == () and len(singles) == 1 + 2 * len(bin_counts(24))
    assert sorted({c.n_classes for c in singles[1:]}) == bin_counts(24)
    pairs = candidate_classes(values, max_classes=24, pair_with="texture")
    shapes = {tuple(np.unique(c.upper[:, f]).size for f in range(2)) for c in pairs}
    assert shapes == {(a, b) for a in bin_counts(24) for b in bin_counts(24) if a * b <= 24}
    assert all(c.features == ("texture", "disparity_gradient") for c in pairs)
