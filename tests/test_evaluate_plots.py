"""Evaluation figures: they draw what the scores say and save atomically."""

import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.evaluate import score_map
from prismap.plots._evaluate import plot_probability_histograms, plot_reliability


@pytest.fixture(scope="module")
def scores():
    rng = np.random.default_rng(0)
    y = rng.random(400) < 0.2
    sharp = np.clip(0.1 + 0.8 * y + rng.normal(0, 0.1, 400), 0, 1)
    return {"sharp": score_map(sharp, y), "prior": score_map(np.full(400, 0.05), y)}


def test_reliability_diagram(scores, tmp_path):
    fig = plot_reliability(scores, path=tmp_path / "rel.png")
    assert (tmp_path / "rel.png").stat().st_size > 0
    ax = fig.axes[0]
    labels = [line.get_label() for line in ax.get_lines()]
    assert labels[1].startswith("sharp (ECE") and labels[2].startswith("prior (ECE")
    # the constant predictor fills one bin: one point at (0.05, occupied fraction)
    x, y = ax.get_lines()[2].get_data()
    np.testing.assert_allclose(x, [0.05])
    np.testing.assert_allclose(y, [scores["prior"].n_occupied / 400])


def test_histograms(scores, tmp_path):
    fig = plot_probability_histograms(scores, path=tmp_path / "hist.pdf")
    assert (tmp_path / "hist.pdf").read_bytes().startswith(b"%PDF")
    assert len(fig.axes) == 2
    # densities: each class's bars integrate to one
    bars = fig.axes[0].patches
    n = len(scores["sharp"].hist_free)
    area_free = sum(b.get_height() * b.get_width() for b in bars[:n])
    assert area_free == pytest.approx(1.0)
    single = plot_probability_histograms({"sharp": scores["sharp"]}, density=False)
    heights = [b.get_height() for b in single.axes[0].patches[:n]]
    np.testing.assert_array_equal(heights, scores["sharp"].hist_free)


def test_plot_errors():
    with pytest.raises(PrismapInputError, match="non-empty dict"):
        plot_reliability({})
    with pytest.raises(PrismapInputError, match="must be a MapScores"):
        plot_probability_histograms({"x": 0.3})
