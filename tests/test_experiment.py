"""The 2-D experiment (PRISM under its own assumptions), the results table and cells, the map-slice figure."""

import json
import re

import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.evaluate import score_map
from prismap.experiment import (
    MODELS,
    SGBM_LIKE_MIXTURE,
    CellResult,
    format_results_table,
    prior_of,
    read_results,
    run_office2d,
    score_grid,
    write_results,
)
from prismap.grid import OccupancyMap
from prismap.io import GroundTruthOccupancy
from prismap.plots import plot_map_slices


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    """The quick 2-D office run: 99 scans of 180 rays, 0.2 m cells, errors from the SGBM-like mixture."""
    out = tmp_path_factory.mktemp("office2d")
    return out, run_office2d(out, quick=True)


def test_prism_wins_on_the_office_when_its_assumptions_hold(office):
    _, result = office
    scores = {cell.model: cell.scores for cell in result.cells}
    assert set(scores) == set(MODELS)
    others = [name for name in MODELS if name != "prism"]
    prism = scores["prism"]
    for name in others:
        assert prism.brier < scores[name].brier, name
        assert prism.log_loss < scores[name].log_loss, name
    assert prism.ece < 0.05
    assert prism.roc_auc > max(scores[name].roc_auc for name in others)


def test_every_map_is_scored_on_the_same_voxels_with_the_ground_truth_prior(office):
    _, result = office
    counts = {(c.scores.n_voxels, c.scores.n_occupied) for c in result.cells}
    assert len(counts) == 1
    n_voxels, n_occupied = counts.pop()
    assert result.p0 == pytest.approx((n_occupied + 1) / (n_voxels + 2))  # Laplace-smoothed occupancy ratio
    assert 0.02 < result.p0 < 0.2  # a few percent, not 0.5


def test_the_run_writes_its_tables_and_figures_and_resumes(office, monkeypatch):
    out, result = office
    for path, caption in result.artifacts:
        assert path.is_file() and path.stat().st_size > 0 and caption
    table = (out / "results.md").read_text()
    for model in MODELS:
        assert f"| known-mixture | {model} |" in table
    cells = read_results(out / "results.json")
    assert [(c.matcher, c.model) for c in cells] == [(c.matcher, c.model) for c in result.cells]
    assert cells[-1].scores.brier == result.cells[-1].scores.brier

    import prismap.pipeline

    def no_model(*args, **kwargs):
        raise AssertionError("a finished cell was recomputed")

    monkeypatch.setattr(prismap.pipeline, "build_sensor_model", no_model)
    again = run_office2d(out, quick=True)
    assert [c.scores.brier for c in again.cells] == [c.scores.brier for c in result.cells]


def test_a_directory_of_another_run_is_refused(office):
    out, _ = office
    with pytest.raises(PrismapInputError, match=r"other settings \(differing: n_frames, seed\)"):
        run_office2d(out, quick=True, seed=1, n_frames=5)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"n_frames": 0}, "`n_frames` must be a positive integer"),
        ({"voxel_size_m": -1}, "voxel_size_m"),
        ({"error_model": [0.3]}, "`error_model` must be a GaussianMixture"),
    ],
)
def test_bad_office_options_are_named(tmp_path, kwargs, message):
    with pytest.raises(PrismapInputError, match=message):
        run_office2d(tmp_path, quick=True, **kwargs)


@pytest.mark.parametrize(
    "world, message",
    [
        ("office2d", r"`n_frames` must be at most \d+ \(the scans of the office tour\); got 100000"),
        ("scene3d", r"`n_frames` must be an integer in \[1, 360\].*got 100000"),
        ("street3d", r"100000 frames of 1.0 m end at x = 100003 m: the street allows up to x = 54 m"),
    ],
)
def test_experiment_frames_beyond_the_world_exit_2_before_anything_is_written(tmp_path, capsys, world, message):
    from prismap.cli import main

    out = tmp_path / "out"
    assert main(["experiment", "--world", world, "--quick", "--frames", "100000", "--out", str(out)]) == 2
    assert re.search(message, capsys.readouterr().err)
    assert not out.exists()


# ------------------------------------------------------------------------------------- scoring and cells
def small_truth():
    """Observed: a 4 x 3 block of layer 0; occupied: its x = 3 column (3 voxels) and one unobserved voxel."""
    observed = np.array([(x, y, 0) for x in range(4) for y in range(3)])
    occupied = np.array([(3, y, 0) for y in range(3)] + [(9, 9, 0)])
    return GroundTruthOccupancy(0.5, occupied, observed)


def test_score_grid_scores_unknown_voxels_as_the_prior():
    truth = small_truth()
    grid = OccupancyMap(0.5, p0=0.25)
    keys = np.array([(0, 0, 0), (3, 0, 0), (7, 7, 0)])  # the last lies outside the ground truth's region
    grid.set_voxels(keys, np.log(np.array([0.1, 0.9, 0.5]) / np.array([0.9, 0.1, 0.5])), np.ones(3, dtype=np.int64))
    expected = np.full(12, 0.25)
    expected[0], expected[9] = 0.1, 0.9  # x-major order of `observed`: key (3, 0) is index 9
    truth_flags = np.zeros(12, dtype=bool)
    truth_flags[9:] = True
    got = score_grid(grid, truth)
    want = score_map(expected, truth_flags)
    assert got.n_voxels == 12 and got.n_occupied == 3
    assert got.brier == pytest.approx(want.brier, rel=1e-6)
    assert got.log_loss == pytest.approx(want.log_loss, rel=1e-6)


def test_prior_is_the_smoothed_occupancy_ratio_of_the_observed_voxels():
    assert prior_of(small_truth()) == pytest.approx((3 + 1) / (12 + 2))
    with pytest.raises(PrismapInputError, match="observes no voxel"):
        prior_of(GroundTruthOccupancy(0.5, np.zeros((0, 3), int), np.zeros((0, 3), int)))


def test_results_round_trip_and_table_marks_the_best(tmp_path):
    rng = np.random.default_rng(3)
    truth = rng.random(200) < 0.2
    cells = [
        CellResult(
            "sgbm",
            name,
            score_map(np.clip(truth * q + rng.random(200) * (1 - q), 0, 1), truth),
            float(i),
            7,
            {"seed": 3},
        )
        for i, (name, q) in enumerate([("ideal", 0.2), ("prism", 0.8)])
    ]
    paths = write_results(cells, tmp_path, title="T", notes=("a note",), settings={"seed": 3})
    back = read_results(paths["json"])
    assert [c.to_dict() for c in back] == [c.to_dict() for c in cells]
    table = paths["table"].read_text()
    assert table == format_results_table(cells, title="T", notes=("a note",))
    prism_row = next(line for line in table.splitlines() if "| prism |" in line)
    ideal_row = next(line for line in table.splitlines() if "| ideal |" in line)
    assert prism_row.count("**") == 2 * 7 and "**" not in ideal_row  # the sharper map is best on all seven scores
    assert json.loads(paths["json"].read_text())["settings"] == {"seed": 3}


def test_a_cell_of_an_older_results_version_is_recomputed(tmp_path):
    from prismap.experiment._results import read_cell, write_cell

    cell = CellResult("sgbm", "prism", score_map([0.2, 0.8], [False, True]), 1.0, 3, {"seed": 0})
    path = tmp_path / "cell.json"
    write_cell(cell, path)
    assert read_cell(path, {"seed": 0}).to_dict() == cell.to_dict()
    old = json.loads(path.read_text())
    old["version"] = 1
    del old["scores"]["safety_threshold"]
    path.write_text(json.dumps(old))
    assert read_cell(path, {"seed": 0}) is None


def test_a_version_2_results_file_reads_without_the_extremes(tmp_path):
    """The docs' results pages render results files of the previous version (no confident-and-wrong rates)."""
    from pathlib import Path

    data = json.loads(
        (Path(__file__).resolve().parents[1] / "docs" / "results" / "scene3d_sgbm_10frames.json").read_text()
    )
    data["version"] = 2  # the docs' file written back as version 2: its cells without the version-3 scores
    for cell in data["cells"]:
        cell["version"] = 2
        for name in [n for n in cell["scores"] if n.endswith("_confident_occupied") or n.endswith("_confident_free")]:
            del cell["scores"][name]
        for name in [n for n in cell["scores"] if n.startswith(("logit_bin", "evidence_"))]:
            del cell["scores"][name]
    (tmp_path / "v2.json").write_text(json.dumps(data))
    cells = read_results(tmp_path / "v2.json")
    assert cells and all(np.isnan(c.scores.free_confident_occupied) for c in cells)
    assert all(c.scores.logit_bin_counts.sum() == 0 for c in cells) and cells[0].scores.brier > 0


def test_unreadable_results_name_the_file(tmp_path):
    path = tmp_path / "results.json"
    path.write_text("{not json")
    with pytest.raises(PrismapInputError, match="results.json: unreadable results file"):
        read_results(path)
    path.write_text(json.dumps({"format": "prismap-experiment-results", "cells": [{"format": "x", "version": 1}]}))
    with pytest.raises(PrismapInputError, match=r"cell 0: not a version \[2, 3\] experiment cell"):
        read_results(path)


# ------------------------------------------------------------------------------------------ map slices
def test_map_slices_draw_truth_and_maps_on_one_window(tmp_path):
    truth = small_truth()
    grid = OccupancyMap(0.5, p0=0.25)
    grid.set_voxels(np.array([(3, 1, 0)]), np.array([2.0]), np.array([1]))
    fig = plot_map_slices({"m": grid}, truth, layer=0, path=tmp_path / "s.png", title="t")
    assert (tmp_path / "s.png").is_file()
    truth_image = fig.axes[0].images[0].get_array()
    map_image = fig.axes[1].images[0].get_array()
    assert truth_image.shape == map_image.shape == (3, 4)
    np.testing.assert_array_equal(np.asarray(truth_image), np.repeat([[0, 0, 0, 1]], 3, axis=0))
    assert np.ma.count(map_image) == 1 and map_image[1, 3] == pytest.approx(1 / (1 + np.exp(-2.0)))


def test_map_slices_refuse_bad_input():
    truth = small_truth()
    with pytest.raises(PrismapInputError, match="no voxel in z layer 5"):
        plot_map_slices({"m": OccupancyMap(0.5, p0=0.25)}, truth, layer=5)
    with pytest.raises(PrismapInputError, match="voxel size 0.25 m"):
        plot_map_slices({"m": OccupancyMap(0.25, p0=0.25)}, truth, layer=0)
    with pytest.raises(PrismapInputError, match="non-empty dict"):
        plot_map_slices({}, truth, layer=0)


def test_the_mixture_is_the_documented_sgbm_like_one():
    np.testing.assert_allclose(SGBM_LIKE_MIXTURE.weights, [0.84, 0.10, 0.06])
    np.testing.assert_allclose(SGBM_LIKE_MIXTURE.means, [0.01, -0.04, -10.4])
    np.testing.assert_allclose(SGBM_LIKE_MIXTURE.sigmas, [0.24, 0.92, 13.6])
