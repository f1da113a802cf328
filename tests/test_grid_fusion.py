"""The persistent-failure reading of a voxel's stored sums against brute force over every failure pattern."""

import itertools

import numpy as np
import pytest
from scipy.special import expit, logit
from scipy.stats import binom

from prismap.errors import PrismapInputError
from prismap.grid._fusion import MAX_VIEWS, FailureClamp, FailureMixture, PersistentFailure


def _pattern_probability(pattern, rate, persistence):
    """P(failure pattern) of the stationary two-state chain, by its definition."""
    into_failure = rate * (1 - persistence) / (1 - rate)
    p = rate if pattern[0] else 1 - rate
    for before, now in zip(pattern, pattern[1:]):
        step = persistence if before else into_failure
        p *= step if now else 1 - step
    return p


@pytest.mark.parametrize("rate, persistence", [(0.05, 0.6), (0.2, 0.9), (0.1, 1.0)])
def test_failure_counts_match_enumeration(rate, persistence):
    model = PersistentFailure(rate, persistence)
    for n in (1, 2, 5):
        expected = np.zeros(n + 1)
        for pattern in itertools.product((0, 1), repeat=n):
            expected[sum(pattern)] += _pattern_probability(pattern, rate, persistence)
        np.testing.assert_allclose(model.failure_counts(n), expected, atol=1e-15)


def test_independent_failures_are_binomial():
    np.testing.assert_allclose(PersistentFailure(0.3, 0.3).failure_counts(6), binom.pmf(np.arange(7), 6, 0.3))


def test_probability_equals_the_average_over_failure_patterns():
    """Views of equal evidence: every pattern with k failed views leaves (n - k) / n of the sum."""
    rate, persistence, p0 = 0.1, 0.7, 0.04
    model = PersistentFailure(rate, persistence)
    rng = np.random.default_rng(5)
    count = rng.integers(1, 6, 40)
    evidence = rng.normal(0, 30, 40)
    got = model.probability(logit(p0) + evidence, count, p0)
    for value, n, s in zip(got, count, evidence):
        expected = sum(
            _pattern_probability(f, rate, persistence) * expit(logit(p0) + s * (n - sum(f)) / n)
            for f in itertools.product((0, 1), repeat=int(n))
        )
        assert value == pytest.approx(expected, rel=1e-12)


def test_no_failures_is_todays_sum_and_unknown_voxels_keep_the_prior():
    log = np.array([-40.0, -1.0, 3.0, 900.0])
    np.testing.assert_array_equal(PersistentFailure(0.0, 0.0).probability(log, np.array([1, 2, 3, 9]), 0.2), expit(log))
    assert PersistentFailure(0.1, 0.5).probability(np.array([logit(0.2)]), np.array([0]), 0.2)[0] == pytest.approx(0.2)


def test_a_frame_of_gross_failures_stays_within_the_bound():
    model, p0 = PersistentFailure(0.04, 0.6), 0.039
    lo, hi = model.bounds(p0)
    assert lo == pytest.approx(0.04 * p0) and hi == pytest.approx(1 - 0.04 * (1 - p0))
    extreme = model.probability(np.array([-2048.0, 2048.0]), np.array([1, 1]), p0)  # the fixed point's ends
    assert lo <= extreme[0] <= lo * (1 + 1e-9) and hi * (1 - 1e-9) <= extreme[1] <= hi
    lo_5, hi_5 = model.bounds(p0, 5)
    assert lo_5 == pytest.approx(0.04 * 0.6**4 * p0) and lo_5 < lo and hi_5 > hi  # repeated views earn more
    many = model.probability(np.array([-2048.0]), np.array([5000]), p0)  # counts above MAX_VIEWS read as MAX_VIEWS
    assert many[0] == pytest.approx(model.bounds(p0, MAX_VIEWS)[0], rel=1e-9)


def test_monotone_in_the_evidence():
    log = np.linspace(-200, 200, 401)
    p = PersistentFailure(0.05, 0.8).probability(log, np.full(log.size, 4), 0.3)
    assert np.all(np.diff(p) >= 0)
    assert np.all(np.diff(p[(log > -20) & (log < 20)]) > 0)  # beyond, float64 saturates every share but the last


def test_bad_parameters_are_named():
    with pytest.raises(PrismapInputError, match="persistence"):
        PersistentFailure(0.2, 0.1)
    with pytest.raises(PrismapInputError, match="rate"):
        PersistentFailure(1.0, 1.0)
    with pytest.raises(PrismapInputError, match="rate"):
        PersistentFailure(-0.1, 0.5)
    with pytest.raises(PrismapInputError, match="one shape"):
        PersistentFailure(0.1, 0.5).probability(np.zeros(3), np.ones(2, int), 0.2)


def test_the_map_reads_its_sums_with_its_fusion_and_keeps_it_in_files_and_merges(tmp_path):
    from prismap.grid import OccupancyMap
    from prismap.io import load_map, save_map

    failure = PersistentFailure(0.05, 0.5)
    keys = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=np.int64)
    log = logit(0.1) + np.array([-50.0, 0.5, 30.0])
    counts = np.array([1, 2, 3])
    plain, fused = OccupancyMap(0.2, p0=0.1), OccupancyMap(0.2, p0=0.1, fusion=failure)
    for grid in (plain, fused):
        grid.set_voxels(keys, log, counts)
    np.testing.assert_allclose(plain.probability_at_keys(keys), expit(log))
    expected = failure.probability(log, counts, 0.1)
    np.testing.assert_allclose(fused.probability_at_keys(keys), expected)
    assert fused.probability_at_keys(np.array([[5, 5, 5]]))[0] == pytest.approx(0.1)  # unknown: the prior
    np.testing.assert_allclose(fused.occupied_voxels()[2], expected[expected >= 0.5])
    save_map(fused, tmp_path / "m.npz")
    back = load_map(tmp_path / "m.npz")
    assert back.fusion == failure and load_map(save_map(plain, tmp_path / "p.npz") or tmp_path / "p.npz").fusion is None
    np.testing.assert_array_equal(back.probability_at_keys(keys), fused.probability_at_keys(keys))
    assert fused.copy().fusion == failure
    with pytest.raises(PrismapInputError, match="different grids or readings: fusion"):
        fused.merge(plain)
    with pytest.raises(PrismapInputError, match="`fusion` must be a MapReading or None"):
        OccupancyMap(0.2, p0=0.1, fusion=(0.05, 0.5))


def test_the_reading_stays_a_probability_at_saturated_sums():
    """The failure shares sum to one only up to rounding; a reading of +-2048 log-odds must still lie in [0, 1]
    (the demo's scoring refused 1.0000000000000002)."""
    fusion = PersistentFailure(rate=0.3, persistence=0.9)
    counts = np.repeat(np.arange(1, 65), 3)
    log_odds = np.tile([2048.0, -2048.0, 700.0], 64)
    p = fusion.probability(log_odds, counts, 0.05)
    assert np.all((p >= 0.0) & (p <= 1.0)) and p[0] > 0.5 > p[1]


def test_the_clamp_is_the_one_view_bound_of_the_persistent_state():
    """FailureClamp keeps the independent sum inside PersistentFailure's one-view bound, for any count."""
    clamp = FailureClamp(0.04)
    p0 = 0.1
    assert clamp.bounds(p0) == pytest.approx(PersistentFailure(0.04, 0.5).bounds(p0, 1))
    assert clamp.bounds(p0, 30) == clamp.bounds(p0)  # more views earn no more certainty than one
    log = logit(p0) + np.array([-2048.0, -40.0, -1.0, 0.0, 0.7, 9.0, 2048.0])
    counts = np.array([1, 7, 2, 0, 3, 5, 64])
    low, high = 0.04 * p0, 1 - 0.04 * (1 - p0)
    np.testing.assert_allclose(clamp.probability(log, counts, p0), np.clip(expit(log), low, high))
    assert clamp.probability(log, counts, p0)[[0, -1]] == pytest.approx([low, high])
    np.testing.assert_array_equal(FailureClamp(0.0).probability(log, counts, p0), expit(log))  # r = 0: independent
    with pytest.raises(PrismapInputError, match="`rate` must lie in"):
        FailureClamp(1.0)
    with pytest.raises(PrismapInputError, match="1-D of one shape"):
        clamp.probability(log, counts[:3], p0)


def test_the_mixture_is_the_persistent_state_that_never_recovers_and_keeps_the_evidence_order():
    """FailureMixture equals PersistentFailure with persistence 1 (a failure stays for every view), hand-derived
    as r p0 + (1 - r) sigmoid(l); its range is the clamp's one-view bound, and unlike the clamp it ties no voxels."""
    rate, p0 = 0.04, 0.1
    mixture = FailureMixture(rate)
    log = logit(p0) + np.array([-2048.0, -30.0, -25.0, -1.0, 0.0, 0.7, 9.0, 25.0, 2048.0])
    counts = np.array([1, 2, 7, 2, 0, 3, 5, 64, 1])
    p = mixture.probability(log, counts, p0)
    np.testing.assert_allclose(p, rate * p0 + (1 - rate) * expit(log), rtol=1e-15)
    np.testing.assert_allclose(p, PersistentFailure(rate, 1.0).probability(log, counts, p0), rtol=1e-12)
    assert p[4] == pytest.approx(p0)  # an unknown voxel (count 0, the prior's log-odds) keeps p0
    assert mixture.bounds(p0) == FailureClamp(rate).bounds(p0) == mixture.bounds(p0, 30)
    low, high = mixture.bounds(p0)
    assert np.all((p >= low) & (p <= high)) and p[0] == pytest.approx(low) and p[-1] == pytest.approx(high)
    clamped = FailureClamp(rate).probability(log, counts, p0)
    assert np.unique(clamped).size == 5  # the clamp ties -2048, -30 and -25 at its floor, 25 and 2048 at its top
    assert np.all(np.diff(p) > 0)  # strictly increasing in the evidence, to the float's resolution
    np.testing.assert_array_equal(FailureMixture(0.0).probability(log, counts, p0), expit(log))  # r = 0
    with pytest.raises(PrismapInputError, match="`rate` must lie in"):
        FailureMixture(1.0)


@pytest.mark.parametrize("reading", [None, PersistentFailure(0.05, 0.6), FailureMixture(0.02), FailureClamp(0.03)])
def test_map_files_keep_every_reading(reading, tmp_path):
    from prismap.grid import OccupancyMap
    from prismap.io import load_map, save_map

    grid = OccupancyMap(0.2, p0=0.1, fusion=reading)
    keys = np.array([[0, 0, 0], [1, 0, 0]], dtype=np.int64)
    grid.set_voxels(keys, logit(0.1) + np.array([-30.0, 30.0]), np.array([2, 4]))
    save_map(grid, tmp_path / "m.npz")
    back = load_map(tmp_path / "m.npz")
    assert back.fusion == reading
    np.testing.assert_array_equal(back.probability_at_keys(keys), grid.probability_at_keys(keys))


def test_version_3_files_read_their_fusion_as_persistent_failure(tmp_path):
    from prismap.grid import OccupancyMap
    from prismap.io import load_map, save_map

    grid = OccupancyMap(0.2, p0=0.1, fusion=PersistentFailure(0.05, 0.6))
    grid.set_voxels(np.zeros((1, 3), np.int64), np.array([3.0]), np.array([2]))
    for reading, fusion in ((PersistentFailure(0.05, 0.6), (0.05, 0.6)), (None, (np.nan, np.nan))):
        save_map(grid, tmp_path / "m.npz")
        with np.load(tmp_path / "m.npz") as data:
            fields = dict(data)
        del fields["fusion_model"]
        fields.update(format_version=np.array(3), fusion=np.array(fusion))
        np.savez(tmp_path / "m.npz", **fields)
        assert load_map(tmp_path / "m.npz").fusion == reading
    fields.update(format_version=np.array(4), fusion_model=np.array("clamped"))
    np.savez(tmp_path / "m.npz", **fields)
    with pytest.raises(PrismapInputError, match=r"m.npz: `fusion_model` must be one of \['independent'"):
        load_map(tmp_path / "m.npz")
