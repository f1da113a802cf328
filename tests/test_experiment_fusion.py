"""The experiments' fusion comparison: one stored map read four ways, scored against truth."""

import numpy as np
import pytest
from scipy.special import expit, logit

from prismap.experiment._fusion import FUSIONS, compare_fusions, format_fusion_section, fused_probabilities
from prismap.grid import OccupancyMap, PersistentFailure
from prismap.io import GroundTruthOccupancy

P0 = 0.1
FAILURE = PersistentFailure(0.05, 0.5)


def test_readings_of_the_same_sums():
    log = logit(P0) + np.array([-60.0, -2.0, 0.0, 3.0, 60.0])
    counts = np.array([1, 1, 2, 4, 1])
    got = fused_probabilities(log, counts, P0, FAILURE)
    assert list(got) == list(FUSIONS)
    np.testing.assert_allclose(got["independent"], expit(log))
    low, high = FAILURE.bounds(P0)
    np.testing.assert_allclose(got["clamped at one view"], np.clip(expit(log), low, high))
    np.testing.assert_allclose(got["failure for good"], FAILURE.rate * P0 + (1 - FAILURE.rate) * expit(log))
    np.testing.assert_allclose(got["persistent failure"], FAILURE.probability(log, counts, P0))
    assert got["persistent failure"][0] == pytest.approx(low) and got["persistent failure"][-1] == pytest.approx(high)


def test_a_confident_mistake_costs_less_when_read_with_failures():
    keys = np.array([[i, 0, 0] for i in range(10)], dtype=np.int64)
    grid = OccupancyMap(0.2, p0=P0)
    evidence = np.array([-40.0] * 9 + [-40.0])  # every voxel "certainly free"; voxel 9 is occupied
    grid.set_voxels(keys, logit(P0) + evidence, np.ones(10, dtype=np.int64))
    truth = GroundTruthOccupancy(0.2, keys[9:], keys)
    rows = compare_fusions({("bm", "prism"): grid}, truth, {"bm": FAILURE})
    by_fusion = {row.fusion: row.scores for row in rows}
    independent, persistent = by_fusion["independent"], by_fusion["persistent failure"]
    assert independent.occupied_confident_free == 1.0 and independent.log_loss == pytest.approx(np.log(1e6) / 10)
    floor = FAILURE.bounds(P0)[0]
    expected = (-np.log(floor) - 9 * np.log1p(-floor)) / 10
    assert persistent.log_loss == pytest.approx(expected, rel=1e-6) and persistent.log_loss < independent.log_loss
    assert persistent.evidence_one_view.sum() == 10
    text = format_fusion_section(rows, {"bm": FAILURE})
    assert "| bm | prism | persistent failure |" in text and "r = 0.0500, q = 0.500" in text
    assert rows[0].to_dict()["log_loss"] == pytest.approx(independent.log_loss)


def test_a_matcher_without_a_fit_is_named_in_the_section():
    text = format_fusion_section([], {"bm": None, "sgbm": FAILURE})
    assert "bm: not fitted (too few surface points" in text and "sgbm: r = 0.0500" in text
