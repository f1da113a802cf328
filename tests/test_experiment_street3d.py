"""The street experiment at its quick size: separate characterisation frames, every requested cell scored on
the same voxels, the safety score in the table, and the CLI's --world street3d."""

import numpy as np
import pytest
from scipy.stats import norm

from prismap.characterise import compute_features, load_error_model
from prismap.errors import PrismapInputError
from prismap.experiment import WORLDS, run_scene3d, run_street3d
from prismap.experiment._report3d import mapped_log_likelihood
from prismap.stereo._base import to_grey

MODELS_TESTED = ("hitmiss", "prism", "prism_conditioned")


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    out = tmp_path_factory.mktemp("street3d")
    return out, run_street3d(out, quick=True, n_frames=5, matchers=("sgbm",), models=MODELS_TESTED)


def test_the_street_run_characterises_on_frames_it_does_not_map(street):
    out, result = street
    assert result.world == "street3d" and result.settings["world"] == "street3d"
    assert result.settings["image_scale"] == 0.25 and result.settings["mode"] == "projective"
    assert result.settings["model_params"] == {"prism": {"near_m": 1.5}}  # PRISM only: no surface nearer
    assert result.settings["between_frames"] == 4
    table = (out / "sgbm" / "characterisation" / "table.md").read_text()
    assert "street-0 frames [0, 4] and 4 between" in table
    assert load_error_model(out / "sgbm" / "characterisation" / "error_model.json").statistics["n_frames"] == 6
    assert len(list((out / "sgbm" / "disparity").glob("*.png"))) == 3
    assert [c.model for c in result.cells] == list(MODELS_TESTED) and all(c.n_frames == 3 for c in result.cells)
    for path, _ in result.artifacts:
        assert path.is_file(), path


def test_every_street_map_is_scored_on_the_same_voxels_with_the_safety_score(street):
    out, result = street
    assert len({(c.scores.n_voxels, c.scores.n_occupied) for c in result.cells}) == 1
    for cell in result.cells:
        s = cell.scores
        assert np.isfinite([s.brier, s.log_loss, s.roc_auc, s.safety_occupied_called_free]).all()
        assert 0.0 <= s.safety_threshold <= 1.0
    results = (out / "results.md").read_text()
    assert "occupied called free at 90 % free" in results and "threshold at 90 % free" in results
    assert "KITTI-like camera" in results and "310x94" in results
    assert "| sgbm | prism (plain) |" in results and "| sgbm | prism (conditioned) |" in results
    assert "## Targets" in results and "street3d, sgbm: conditioned PRISM's log-loss at least 10% below" in results
    # PRISM separates occupied from free voxels better than hit/miss even at this tiny size
    assert result.cell("sgbm", "prism").scores.roc_auc > result.cell("sgbm", "hitmiss").scores.roc_auc


def test_the_mapping_frames_likelihood_matches_a_per_pixel_reference(street):
    from prismap.io import read_kitti_disparity, read_sequence

    out, _ = street
    model = load_error_model(out / "sgbm" / "characterisation" / "error_model.json")
    frames = list(read_sequence(out / "sequence"))
    measured = mapped_log_likelihood(model, frames, out / "sgbm" / "disparity")
    assert model.conditioned

    def density(mixture, e):  # the mixture's pdf written out, not its logpdf: Gaussians, then the failure floor
        gaussian = sum(w * norm.pdf(e, m, s) for w, m, s in zip(mixture.weights, mixture.means, mixture.sigmas))
        if mixture.search_range_px is None:
            return gaussian
        low, high = mixture.search_range_px
        return (1.0 - mixture.failure_weight) * gaussian + mixture.failure_weight / (high - low)

    labels, errors = [], []
    for index, frame in enumerate(frames):
        disparity = read_kitti_disparity(out / "sgbm" / "disparity" / f"{index:06d}.png")
        label = model.classify(compute_features(to_grey(frame.left), None, disparity, None, **model.feature_settings))
        for v in range(label.shape[0]):
            for u in range(label.shape[1]):
                error = float(frame.disparity_gt[v, u]) - float(disparity[v, u])
                if label[v, u] >= 0 and np.isfinite(error):
                    labels.append(label[v, u])
                    errors.append(error)
    labels, errors = np.array(labels), np.array(errors)
    count = errors.size
    conditioned = (
        sum(np.log(density(mixture, errors[labels == k])).sum() for k, mixture in enumerate(model.class_mixtures))
        / count
    )
    plain = np.log(density(model.mixture, errors)).mean()
    assert measured["n_errors"] == count > 1000
    assert measured["conditioned_nats_per_error"] == pytest.approx(conditioned, rel=1e-9)
    assert measured["plain_nats_per_error"] == pytest.approx(plain, rel=1e-9)
    results = (out / "results.md").read_text()
    assert "street3d, sgbm: log-likelihood of the mapping frames' errors higher conditioned than plain" in results


def test_the_cli_runs_the_street_world(monkeypatch, tmp_path, capsys):
    import prismap.experiment
    from prismap.cli._main import main

    calls = []

    def fake(world, out, **kwargs):
        calls.append((world, kwargs))
        (out / "results.md").parent.mkdir(parents=True, exist_ok=True)
        (out / "results.md").write_text("| table |\n")
        return type("R", (), {"artifacts": ()})()

    monkeypatch.setattr(prismap.experiment, "run_rendered_world", fake)
    assert main(["experiment", "--world", "street3d", "--quick", "--out", str(tmp_path)]) == 0
    assert main(["experiment", "--world", "avenue3d", "--out", str(tmp_path), "--seed", "3"]) == 0
    assert calls == [
        ("street3d", {"n_frames": None, "voxel_size_m": None, "seed": 0, "quick": True}),
        ("avenue3d", {"n_frames": None, "voxel_size_m": None, "seed": 3, "quick": False}),
    ]
    assert "| table |" in capsys.readouterr().out


def test_bad_street_options_are_named(tmp_path):
    assert set(WORLDS) == {"scene3d", "street3d", "avenue3d"}
    with pytest.raises(PrismapInputError, match="60 frames of 1.0 m end at x = 63 m"):
        run_street3d(tmp_path, n_frames=60)
    with pytest.raises(PrismapInputError, match="`between_frames` must be an integer >= 0; got -1"):
        run_street3d(tmp_path, between_frames=-1)
    with pytest.raises(PrismapInputError, match="world 'scene3d' has no drive between its frames"):
        run_scene3d(tmp_path, between_frames=2)
    assert not (tmp_path / "settings.json").exists()  # refused before anything is written


def test_the_results_say_how_the_errors_repeat_across_mapping_frames(street):
    import json

    from prismap.characterise import frame_error_correlation
    from prismap.io import read_kitti_disparity, read_sequence

    out, _ = street
    sequence = read_sequence(out / "sequence")
    frames = list(sequence)
    disparities = [read_kitti_disparity(out / "sgbm" / "disparity" / f"{i:06d}.png") for i in range(len(frames))]
    expected = frame_error_correlation(frames, disparities, sequence.camera, lag=1)
    stored = json.loads((out / "results.json").read_text())["error_correlation"]["sgbm"]
    assert stored == expected.to_dict()
    assert stored["n_pairs"] > 1000 and 0.0 <= stored["gross_rate"] <= 1.0
    # the street's SGBM errors repeat: correlated, and a gross error is followed by another far more often than one strikes
    assert stored["correlation"] > 0.1 and stored["gross_repeat"] > 2 * stored["gross_rate"]
    results = (out / "results.md").read_text()
    assert "## Errors repeated across frames" in results
    assert f"| sgbm | {expected.n_pairs} | {expected.correlation:.3f} |" in results


def test_the_results_compare_fusions_fitted_on_the_characterisation_frames(street):
    import json

    from prismap.characterise import fit_fusion
    from prismap.io import read_kitti_disparity, read_sequence

    out, _ = street
    document = json.loads((out / "results.json").read_text())
    block = document["fusion"]["blocks"]["sgbm"]
    assert block["model"] == "persistent-failure" and block["n_pairs"] >= 100
    assert 0.0 <= block["rate"] <= block["persistence"] <= 1.0
    rows = document["fusion"]["rows"]
    assert {(r["model"], r["fusion"]) for r in rows} == {
        (m, f)
        for m in ("prism", "prism_conditioned")
        for f in ("independent", "persistent failure", "failure for good", "clamped at one view")
    }
    cells = {c["model"]: c["scores"] for c in document["cells"]}
    for row in rows:  # the maps take prismap map's default reading, a failure for good: its row is the cell's score
        if row["fusion"] == "failure for good":
            assert row["log_loss"] == pytest.approx(cells[row["model"]]["log_loss"], rel=1e-12)
    assert block == json.loads((out / "sgbm" / "characterisation" / "error_model.json").read_text())["fusion"]
    sequence = read_sequence(out / "sequence")
    assert "## Fusion of repeated failures" in (out / "results.md").read_text()
    # refitting on the mapping frames gives another block: the run fits on the characterisation frames only
    mapped = [read_kitti_disparity(out / "sgbm" / "disparity" / f"{i:06d}.png") for i in range(len(sequence))]
    assert fit_fusion(list(sequence), mapped, sequence.camera) != block
