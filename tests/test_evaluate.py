"""Map scores against hand-computed values, scikit-learn, and the alignment of keys to ground truth."""

import json

import numpy as np
import pytest
from sklearn.metrics import brier_score_loss, log_loss, roc_auc_score

from prismap.errors import PrismapInputError
from prismap.evaluate import (
    LOG_LOSS_EPS,
    MapScores,
    align_to_ground_truth,
    roc_auc,
    safety_score,
    score_map,
)


def test_scores_by_hand():
    p = np.array([0.1, 0.4, 0.35, 0.8])
    y = np.array([False, False, True, True])
    s = score_map(p, y, n_bins=2, n_hist_bins=2)
    assert s.n_voxels == 4 and s.n_occupied == 2 and s.n_free == 2
    assert s.brier == pytest.approx((0.01 + 0.16 + 0.4225 + 0.04) / 4)
    assert s.log_loss == pytest.approx(-(np.log(0.9) + np.log(0.6) + np.log(0.35) + np.log(0.8)) / 4)
    # pairs (occupied, free): (0.35, 0.1) yes, (0.35, 0.4) no, (0.8, 0.1) yes, (0.8, 0.4) yes -> 3/4
    assert s.roc_auc == pytest.approx(0.75)
    # bin [0, 0.5): p 0.1, 0.4, 0.35 -> mean 0.2833, 1 of 3 occupied; bin [0.5, 1]: 0.8, 1 of 1
    np.testing.assert_array_equal(s.bin_counts, [3, 1])
    np.testing.assert_allclose(s.bin_mean_probability, [0.85 / 3, 0.8])
    np.testing.assert_allclose(s.bin_occupied_fraction, [1 / 3, 1.0])
    assert s.ece == pytest.approx((3 * abs(0.85 / 3 - 1 / 3) + 1 * 0.2) / 4)
    assert s.occupied_called_free == 0.5 and s.free_called_occupied == 0.0
    np.testing.assert_array_equal(s.hist_free, [2, 0])
    np.testing.assert_array_equal(s.hist_occupied, [1, 1])


def test_auc_ties_count_half():
    assert roc_auc([0.5, 0.5, 0.5], [True, False, False]) == 0.5
    # occupied 0.7 vs free {0.7, 0.2}: one tie (1/2) and one win -> 0.75
    assert roc_auc([0.7, 0.7, 0.2], [True, False, False]) == pytest.approx(0.75)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_scores_match_sklearn(seed):
    rng = np.random.default_rng(seed)
    y = rng.random(500) < 0.3
    # informative but noisy, rounded so that ties occur; away from the log-loss clip
    p = np.clip(np.round(0.3 + 0.4 * y + rng.normal(0, 0.2, 500), 2), 0.01, 0.99)
    s = score_map(p, y)
    assert s.brier == pytest.approx(brier_score_loss(y, p), rel=1e-12)
    assert s.log_loss == pytest.approx(log_loss(y, p), rel=1e-12)
    assert s.roc_auc == pytest.approx(roc_auc_score(y, p), rel=1e-12)


def test_ece_brute_force():
    rng = np.random.default_rng(5)
    p = rng.random(300)
    y = rng.random(300) < p**2
    s = score_map(p, y, n_bins=7)
    total = 0.0
    for b in range(7):
        lo, hi = b / 7, (b + 1) / 7
        inside = (p >= lo) & ((p < hi) if b < 6 else (p <= hi))
        if inside.any():
            total += inside.sum() * abs(p[inside].mean() - y[inside].mean())
    assert s.ece == pytest.approx(total / 300)
    assert s.bin_counts.sum() == 300 and s.hist_free.sum() + s.hist_occupied.sum() == 300


def test_perfect_and_constant_predictors():
    y = np.array([0, 1, 1, 0, 1], dtype=bool)
    perfect = score_map(y.astype(float), y)
    assert perfect.brier == 0 and perfect.ece == 0 and perfect.roc_auc == 1
    assert perfect.log_loss == pytest.approx(-np.log1p(-LOG_LOSS_EPS))  # clipped, not exactly 0
    assert perfect.occupied_called_free == 0 and perfect.free_called_occupied == 0
    worst = score_map(1.0 - y, y)
    assert worst.brier == 1 and worst.roc_auc == 0
    assert worst.log_loss == pytest.approx(-np.log(LOG_LOSS_EPS))  # bounded by the clip
    constant = score_map(np.full(5, 0.5), y)
    assert constant.brier == 0.25 and constant.roc_auc == 0.5
    assert constant.log_loss == pytest.approx(np.log(2))
    # P = 0.5 is neither called free (< 0.5) nor occupied (> 0.5)
    assert constant.occupied_called_free == 0 and constant.free_called_occupied == 0
    assert constant.ece == pytest.approx(abs(0.5 - 0.6))


def test_one_class_truth_gives_nan_auc_and_rate():
    s = score_map([0.2, 0.9], [True, True])
    assert np.isnan(s.roc_auc) and np.isnan(s.free_called_occupied)
    assert s.occupied_called_free == 0.5
    d = s.to_dict()
    assert d["roc_auc"] is None and d["free_called_occupied"] is None
    assert d["bin_mean_probability"][0] is None  # empty bin
    json.dumps(d, allow_nan=False)


def test_to_dict_round_trips_values():
    s = score_map([0.1, 0.9, 0.6], [False, True, False])
    d = s.to_dict()
    assert set(d) == set(MapScores.__dataclass_fields__)
    assert d["brier"] == s.brier and d["bin_counts"] == s.bin_counts.tolist()


@pytest.mark.parametrize(
    "p, y, match",
    [
        ([0.1, 0.2], [True], "shape of `probability`"),
        ([], [], "empty"),
        ([0.1, 1.2], [True, False], r"\[0, 1\]"),
        ([-0.1, 0.5], [True, False], r"\[0, 1\]"),
        ([np.nan, 0.5], [True, False], "finite"),
        ([0.1, 0.5], [2, 0], "boolean"),
        ([[0.1, 0.5]], [[True, False]], "1-D"),
    ],
)
def test_score_errors(p, y, match):
    with pytest.raises(PrismapInputError, match=match):
        score_map(p, y)


def test_bin_count_errors():
    with pytest.raises(PrismapInputError, match="n_bins"):
        score_map([0.5], [True], n_bins=0)
    with pytest.raises(PrismapInputError, match="n_hist_bins"):
        score_map([0.5], [True], n_hist_bins=2.5)


def test_align_3d_by_hand():
    keys = np.array([[0, 0, 0], [1, 0, 0], [-1, 2, 5]])
    prob = np.array([0.9, 0.2, 0.7])
    occupied = np.array([[0, 0, 0], [-1, 2, 5], [9, 9, 9], [0, 0, 0]])  # one outside region, one repeat
    region = np.array([[-1, 2, 5], [1, 0, 0], [3, 3, 3], [0, 0, 0]])
    p, y = align_to_ground_truth(keys, prob, occupied, region, p0=0.05)
    np.testing.assert_array_equal(p, [0.7, 0.2, 0.05, 0.9])
    np.testing.assert_array_equal(y, [True, False, False, True])


def test_align_matches_dict_lookup_2d():
    rng = np.random.default_rng(3)
    keys = np.unique(rng.integers(-50, 50, size=(400, 2)), axis=0)
    prob = rng.random(len(keys))
    region = np.unique(rng.integers(-60, 60, size=(500, 2)), axis=0)
    occupied = rng.integers(-60, 60, size=(200, 2))
    p, y = align_to_ground_truth(keys, prob, occupied, region, p0=0.1)
    lookup = {tuple(k): v for k, v in zip(keys.tolist(), prob)}
    occ = {tuple(k) for k in occupied.tolist()}
    np.testing.assert_array_equal(p, [lookup.get(tuple(k), 0.1) for k in region.tolist()])
    np.testing.assert_array_equal(y, [tuple(k) in occ for k in region.tolist()])


def test_align_empty_map_scores_prior():
    p, y = align_to_ground_truth(np.zeros((0, 3), int), [], [[1, 1, 1]], [[1, 1, 1], [0, 0, 0]], p0=0.2)
    np.testing.assert_array_equal(p, [0.2, 0.2])
    np.testing.assert_array_equal(y, [True, False])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"keys": [[0, 0, 0]], "probability": [0.5, 0.5]}, "one value per key"),
        ({"keys": [[0.5, 0, 0]]}, "integer"),
        ({"region_keys": [[0, 0]]}, "3 columns"),
        ({"keys": [[0, 0, 0], [0, 0, 0]], "probability": [0.1, 0.2]}, "`keys` must not repeat"),
        ({"region_keys": [[1, 1, 1], [1, 1, 1]]}, "`region_keys` must not repeat"),
        ({"probability": [1.5]}, r"\[0, 1\]"),
        ({"p0": 0.0}, "p0"),
        ({"region_keys": [[-(2**62), 0, 0], [2**62, 0, 0]]}, "too far apart"),
    ],
)
def test_align_errors(kwargs, match):
    args = {
        "keys": [[0, 0, 0]],
        "probability": [0.5],
        "occupied_keys": [[0, 0, 0]],
        "region_keys": [[0, 0, 0]],
        "p0": 0.1,
    }
    args.update(kwargs)
    p0 = args.pop("p0")
    with pytest.raises(PrismapInputError, match=match):
        align_to_ground_truth(*args.values(), p0=p0)


def _safety_brute_force(p, y, share=0.9):
    """Sweep every threshold t of the grid {P values} (called free: P <= t); the first one calling at least
    ``share`` of the free voxels free, and the occupied share it calls free."""
    for t in np.unique(p):
        if np.count_nonzero(p[~y] <= t) >= share * np.count_nonzero(~y) - 1e-9:
            return np.mean(p[y] <= t) if y.any() else np.nan, t
    return np.nan, np.nan


def test_safety_score_by_hand():
    # 10 free voxels at P = 0.05 ... 0.50; 9 of them must be called free -> t = 0.45 (the 9th smallest)
    free = np.arange(1, 11) / 20.0
    occupied = np.array([0.3, 0.45, 0.46, 0.9])  # 0.3 and the tie 0.45 are called free, 0.46 is not
    p = np.concatenate([free, occupied])
    y = np.r_[np.zeros(10, bool), np.ones(4, bool)]
    score, threshold = safety_score(p, y)
    assert threshold == pytest.approx(0.45) and score == 0.5
    s = score_map(p, y)
    assert s.safety_threshold == threshold and s.safety_occupied_called_free == 0.5
    assert s.occupied_called_free == 0.75  # the old score: P < 0.5, kept beside it


def test_safety_score_ignores_the_prior_but_the_old_score_does_not():
    rng = np.random.default_rng(3)
    y = rng.random(400) < 0.2
    p = np.clip(0.2 + 0.5 * y + rng.normal(0, 0.15, 400), 0.001, 0.999)
    low = p**3  # strictly increasing: the same ranking with a lower "prior"
    assert safety_score(low, y)[0] == safety_score(p, y)[0]
    assert score_map(low, y).occupied_called_free > score_map(p, y).occupied_called_free


@pytest.mark.parametrize("seed", range(6))
def test_safety_score_matches_a_brute_force_threshold_sweep(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 200))
    y = rng.random(n) < rng.uniform(0.05, 0.6)
    p = np.round(np.clip(0.3 + 0.3 * y + rng.normal(0, 0.25, n), 0, 1), int(rng.integers(1, 4)))  # ties
    score, threshold = safety_score(p, y)
    expected_score, expected_threshold = _safety_brute_force(p, y)
    np.testing.assert_equal([score, threshold], [expected_score, expected_threshold])
    if (~y).any():
        assert np.mean(p[~y] <= threshold) >= 0.9 and np.mean(p[~y] < threshold) < 0.9


def test_safety_score_empty_classes_and_exact_counts():
    assert np.isnan(safety_score([0.2, 0.9], [True, True])).all()  # no free voxel: no threshold
    score, threshold = safety_score([0.1, 0.2], [False, False])  # no occupied voxel: threshold only
    assert np.isnan(score) and threshold == 0.2
    # 70 free voxels: 0.9 * 70 = 63 exactly (not 64 from float rounding): t is the 63rd smallest
    p = np.arange(70) / 100.0
    assert safety_score(p, np.zeros(70, bool))[1] == 0.62
    with pytest.raises(PrismapInputError, match=r"`free_share` must lie in \(0, 1\]"):
        safety_score([0.1], [False], free_share=0.0)
    with pytest.raises(PrismapInputError, match="must have the shape"):
        safety_score([0.1, 0.2], [False])


def test_log_loss_sources_by_hand_add_up_to_the_log_loss():
    """Observed: a 4 x 3 block of layer 0 (12 voxels), truly occupied: its x = 3 column. The map knows four of them:
    (0, 0) free at P 0.1 (with evidence), (1, 0) free at P 0.26 (near the prior 0.25), (3, 0) occupied at 0.9 and
    (3, 1) occupied at 0.2 (near the prior: |logit 0.2 - logit 0.25| = 0.288); the other eight are never observed."""
    from prismap.evaluate import NEAR_PRIOR_LOG_ODDS, log_loss_sources, score_grid, score_grid_with_sources
    from prismap.grid import OccupancyMap
    from prismap.io import GroundTruthOccupancy

    observed = np.array([(x, y, 0) for x in range(4) for y in range(3)])
    truth = GroundTruthOccupancy(0.5, np.array([(3, y, 0) for y in range(3)]), observed)
    grid = OccupancyMap(0.5, p0=0.25)
    p = np.array([0.1, 0.26, 0.9, 0.2])
    grid.set_voxels(np.array([(0, 0, 0), (1, 0, 0), (3, 0, 0), (3, 1, 0)]), np.log(p / (1 - p)), np.ones(4, np.int64))
    assert abs(np.log(0.2 / 0.8) - np.log(0.25 / 0.75)) < NEAR_PRIOR_LOG_ODDS < abs(np.log(0.1 / 0.9 * 3))
    got = log_loss_sources(grid, truth)
    n = 12
    want = {
        "never observed": {"occupied": (1, -np.log(0.25) / n), "free": (7, -7 * np.log(0.75) / n)},
        "near the prior": {"occupied": (1, -np.log(0.2) / n), "free": (1, -np.log(0.74) / n)},
        "with evidence": {"occupied": (1, -np.log(0.9) / n), "free": (1, -np.log(0.9) / n)},
    }
    assert list(got) == list(want)
    for level, parts in want.items():
        for state, (voxels, loss) in parts.items():
            assert got[level][state]["voxels"] == voxels
            assert got[level][state]["log_loss"] == pytest.approx(loss, rel=1e-6)  # fixed-point log-odds
    total = sum(part["log_loss"] for parts in got.values() for part in parts.values())
    assert total == pytest.approx(score_grid(grid, truth).log_loss, rel=1e-12)
    scores, sources = score_grid_with_sources(grid, truth)  # prismap evaluate's one alignment
    assert sources == got and scores.to_dict() == score_grid(grid, truth).to_dict()
