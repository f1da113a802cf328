"""The diagnostics of the scale's extremes: "confident and wrong" rates, logit-spaced reliability bins, the
per-frame evidence histograms, and their figures."""

import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.evaluate import EVIDENCE_EDGES, LOGIT_BIN_EDGES, evidence_histograms, score_map
from prismap.experiment._results import scores_from_dict
from prismap.plots import plot_evidence_histograms, plot_reliability_logit


def test_confident_and_wrong_rates_by_hand():
    p = np.array([0.995, 0.99, 0.5, 0.001, 0.2, 0.01, 0.0, 0.9])
    y = np.array([False, False, False, False, True, True, True, True])
    s = score_map(p, y)
    assert s.free_confident_occupied == pytest.approx(2 / 4)  # 0.995 and 0.99 (>= 0.99 counts)
    assert s.occupied_confident_free == pytest.approx(2 / 4)  # 0.01 and 0.0
    only_free = score_map(np.array([0.3, 0.999]), np.array([False, False]))
    assert only_free.free_confident_occupied == 0.5 and np.isnan(only_free.occupied_confident_free)


def test_calibration_at_the_extremes_by_hand():
    p = np.array([0.995, 0.99, 0.999, 0.5, 0.001, 0.01, 0.0, 0.005, 0.2])
    y = np.array([False, True, True, False, False, True, False, False, True])
    s = score_map(p, y)
    assert s.free_share_at_high_p == pytest.approx(1 / 3)  # 0.995 of 0.995, 0.99, 0.999
    assert s.occupied_share_at_low_p == pytest.approx(1 / 4)  # 0.01 of 0.001, 0.01, 0.0, 0.005
    timid = score_map(np.array([0.2, 0.8]), np.array([False, True]))
    assert np.isnan(timid.free_share_at_high_p) and np.isnan(timid.occupied_share_at_low_p)
    assert timid.free_confident_occupied == 0.0  # never sure, so never "confident and wrong"


def test_logit_bins_reach_the_extremes():
    assert LOGIT_BIN_EDGES[0] == 0.0 and LOGIT_BIN_EDGES[-1] == 1.0
    assert LOGIT_BIN_EDGES[1] < 2e-4 and LOGIT_BIN_EDGES[-2] > 1 - 2e-4
    np.testing.assert_allclose(np.diff(np.log(LOGIT_BIN_EDGES[1:-1] / (1 - LOGIT_BIN_EDGES[1:-1]))), 1.5)
    p = np.array([0.0, 1e-6, 1e-3, 0.5, 0.5, 1 - 1e-6, 1.0])
    y = np.array([True, False, False, True, False, True, True])
    s = score_map(p, y)
    assert s.logit_bin_counts.sum() == p.size
    assert s.logit_bin_counts[0] == 2 and s.logit_bin_counts[-1] == 2  # 0, 1e-6 | 1 - 1e-6, 1
    assert s.logit_bin_occupied_fraction[0] == 0.5 and s.logit_bin_mean_probability[0] == pytest.approx(5e-7)
    middle = np.searchsorted(LOGIT_BIN_EDGES, 0.5, side="right") - 1
    assert s.logit_bin_counts[middle] == 2 and s.logit_bin_occupied_fraction[middle] == 0.5
    # equal-width bins lump 0 .. 1e-3 together; the logit bins tell them apart
    assert s.bin_counts[0] == 3 and np.count_nonzero(s.logit_bin_counts[:6]) == 2


def test_evidence_histograms_by_hand():
    increments = np.array([-3000.0, -25.0, 0.05, 4.0, 40.0, -60.0])
    counts = np.array([1, 1, 1, 2, 2, 3])
    one, per = evidence_histograms(increments, counts)
    assert one.sum() == 3 and per.sum() == 6

    def bin_of(value):
        return int(np.searchsorted(EVIDENCE_EDGES, value, side="right") - 1)

    assert one[0] == 1  # -3000 lands in the end bin
    assert one[bin_of(-25.0)] == 1 and one[bin_of(0.0)] == 1
    assert per[bin_of(2.0)] == 1 and per[bin_of(20.0)] == 1 and per[bin_of(-20.0)] == 2  # -25 (one view) and -60 / 3
    with pytest.raises(PrismapInputError, match="integers >= 1"):
        evidence_histograms(np.zeros(2), np.array([1, 0]))
    with pytest.raises(PrismapInputError, match="integers >= 1"):
        evidence_histograms(np.zeros(2), np.array([1]))


def test_scores_round_trip_with_the_new_fields():
    rng = np.random.default_rng(3)
    y = rng.random(300) < 0.3
    p = np.clip(0.05 + 0.9 * y + rng.normal(0, 0.2, 300), 0, 1)
    s = score_map(p, y, evidence=(rng.normal(0, 10, 50), rng.integers(1, 5, 50)))
    back = scores_from_dict(s.to_dict())
    for name in ("logit_bin_counts", "evidence_one_view", "evidence_per_view"):
        np.testing.assert_array_equal(getattr(back, name), getattr(s, name))
        assert getattr(back, name).dtype == np.int64
    assert back.free_confident_occupied == s.free_confident_occupied
    assert back.occupied_share_at_low_p == s.occupied_share_at_low_p


@pytest.fixture(scope="module")
def scores():
    rng = np.random.default_rng(0)
    y = rng.random(500) < 0.2
    sure = np.where(y, 1 - 1e-5, 1e-5)
    sure[:10] = 1 - sure[:10]  # ten confident mistakes
    evidence = (rng.normal(0, 30, 200), rng.integers(1, 4, 200))
    return {"sure": score_map(sure, y, evidence=evidence), "prior": score_map(np.full(500, 0.2), y)}


def test_logit_reliability_figure(scores, tmp_path):
    fig = plot_reliability_logit(scores, path=tmp_path / "rel.png")
    assert (tmp_path / "rel.png").stat().st_size > 0
    lines = fig.axes[0].get_lines()
    assert "free at P>=0.99" in lines[1].get_label() and "occupied at P<=0.01" in lines[1].get_label()
    x, _ = lines[2].get_data()  # the constant predictor: one point at logit(0.2)
    np.testing.assert_allclose(x, [np.log(0.2 / 0.8)])
    x_sure, _ = lines[1].get_data()
    assert x_sure.min() < -9 and x_sure.max() > 9  # the extreme bins are drawn


def test_evidence_figure(scores, tmp_path):
    fig = plot_evidence_histograms(scores, path=tmp_path / "ev.png")
    assert (tmp_path / "ev.png").stat().st_size > 0
    assert len([ax for ax in fig.axes if ax.get_title()]) == 1  # "prior" has no evidence and is skipped
    heights = [bar.get_height() for bar in fig.axes[0].patches]
    n = len(EVIDENCE_EDGES) - 1
    np.testing.assert_array_equal(heights[n:], scores["sure"].evidence_per_view)
    with pytest.raises(PrismapInputError, match="evidence histograms"):
        plot_evidence_histograms({"prior": scores["prior"]})


def test_the_report_lists_every_maps_confident_and_wrong_rates():
    from types import SimpleNamespace

    from prismap.experiment import CellResult
    from prismap.experiment._report import REPORT_PARTS, _confident_and_wrong

    y = np.array([False, False, False, True])
    cells = (
        CellResult("bm", "prism_conditioned", score_map(np.array([0.995, 0.2, 0.1, 0.005]), y), 1.0, 3),
        CellResult("bm", "andert", score_map(np.array([0.5, 0.2, 0.1, 0.7]), y), 1.0, 3),
    )
    report = SimpleNamespace(experiments={"street3d": SimpleNamespace(cells=cells)})
    html = "".join(_confident_and_wrong(report))
    assert _confident_and_wrong in REPORT_PARTS
    assert "<td><strong>prism (conditioned)</strong></td><td>33.333%</td><td>100.000%</td>" in html
    assert "<td>andert</td><td>0.000%</td><td>0.000%</td>" in html
    assert _confident_and_wrong(SimpleNamespace(experiments={})) == []


def test_prismap_evaluate_prints_the_extremes():
    from prismap.cli._evaluate import format_scores

    p = np.array([0.995, 0.999, 0.5, 0.001, 0.2, 0.005])
    y = np.array([False, True, False, False, True, True])
    lines = format_scores(score_map(p, y), title="t").splitlines()
    assert "| free at P >= 0.99 | 33.333% |" in lines and "| occupied at P <= 0.01 | 33.333% |" in lines
    assert "| of P >= 0.99: free | 50.00% |" in lines and "| of P <= 0.01: occupied | 50.00% |" in lines
    timid = format_scores(score_map(np.array([0.3, 0.7]), np.array([False, True])), title="t")
    assert "| of P >= 0.99: free | n/a |" in timid.splitlines()
