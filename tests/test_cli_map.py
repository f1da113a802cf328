"""``prismap map`` and ``prismap evaluate``: characterise -> map -> evaluate on a synthetic sequence, error
messages with exit status 2, and a run killed mid-way that resumes to the uninterrupted map."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from prismap.camera import StereoCamera
from prismap.characterise import ErrorModel, write_error_model
from prismap.cli import main
from prismap.evaluate import align_to_ground_truth, score_map
from prismap.gmm import fit_mixtures
from prismap.io import load_map, read_ground_truth, write_ground_truth
from prismap.pipeline import MappingConfig, characterise_sequence, map_sequence
from support import VOXEL, assert_same_map, synthetic_sequence

PRISMAP = Path(sys.executable).parent / "prismap"


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("cli") / "seq")


@pytest.fixture(scope="module")
def error_model_path(sequence_dir, tmp_path_factory):
    """An error model of SGBM fitted to the sequence's own errors (the characterisation workflow)."""
    params = {"num_disparities": 16}
    histogram = characterise_sequence(sequence_dir, "sgbm", matcher_params=params, progress=False)
    fits = fit_mixtures(histogram.edges, histogram.counts, max_components=2, seed=0)
    model = ErrorModel(matcher="sgbm", matcher_params=params, dataset="synthetic", bin_width=histogram.bin_width,
                       fits=tuple(fits), selected_components=2)
    path = tmp_path_factory.mktemp("model") / "error_model.json"
    write_error_model(model, path)
    return path


def map_args(sequence_dir, out, *extra):
    return ["map", "--sequence", str(sequence_dir), "--voxel", str(VOXEL), "--max-range", "8",
            "--matcher-param", "num_disparities=16", "--out", str(out), *extra]


def test_map_then_evaluate_writes_the_pipelines_map_and_its_scores(sequence_dir, error_model_path, tmp_path, capsys):
    out = tmp_path / "map.npz"
    assert main(map_args(sequence_dir, out, "--model", "convolution", "--error-model", str(error_model_path),
                         "--frames", "1:5", "--policy", "max-abs")) == 0
    assert "4 frames" in capsys.readouterr().out
    from prismap.characterise import load_error_model

    mixture = load_error_model(error_model_path).mixture
    expected = map_sequence(sequence_dir, MappingConfig(
        model="convolution", voxel_size_m=VOXEL, error_model=mixture, matcher_params={"num_disparities": 16},
        max_range_m=8.0, frames=(1, 5), policy="max-abs"), progress=False)
    grid = load_map(out)
    assert_same_map(grid, expected)
    assert sorted(tmp_path.iterdir()) == [out]  # no checkpoint or temporary file left behind

    assert main(["evaluate", "--map", str(out), "--gt", str(sequence_dir)]) == 0
    printed = capsys.readouterr().out
    truth = read_ground_truth(sequence_dir / "occupancy.npz")
    keys = grid.known_voxels()[0]
    scores = score_map(*align_to_ground_truth(keys, grid.probability_at_keys(keys), truth.occupied_keys,
                                              truth.observed_keys, p0=grid.p0))
    assert f"| Brier score | {scores.brier:.4f} |" in printed and f"| ROC AUC | {scores.roc_auc:.4f} |" in printed
    written = json.loads((tmp_path / "map.scores.json").read_text())
    assert written["scores"]["brier"] == pytest.approx(scores.brier, rel=1e-12)
    assert written["scores"]["n_voxels"] == truth.observed_keys.shape[0] and written["n_frames"] == 4


def test_evaluate_with_out_writes_json_and_reliability_figure(sequence_dir, tmp_path, capsys):
    out = tmp_path / "ideal.npz"
    assert main(map_args(sequence_dir, out, "--model", "ideal", "--disparity-dir", str(sequence_dir / "disp"),
                         "--mode", "projective")) == 0
    truth_file = tmp_path / "truth.npz"
    write_ground_truth(truth_file, read_ground_truth(sequence_dir / "occupancy.npz"))
    assert main(["evaluate", "--map", str(out), "--gt", str(truth_file), "--out", str(tmp_path / "eval")]) == 0
    capsys.readouterr()
    assert (tmp_path / "eval" / "reliability.png").stat().st_size > 1000
    scores = json.loads((tmp_path / "eval" / "scores.json").read_text())["scores"]
    assert scores["roc_auc"] > 0.7  # exact disparities: the map separates occupied from free voxels


@pytest.mark.parametrize(("argv", "message"), [
    (["--sequence", "/nonexistent/seq"], "--sequence /nonexistent/seq: sequence directory not found"),
    (["--model", "prism"], "sensor model 'prism' needs an error model (--error-model MODEL.json)"),
    (["--model", "prism", "--error-model", "/nonexistent/m.json"], "error model /nonexistent/m.json: no such file"),
    (["--voxel", "0"], "`--voxel` must be a finite number > 0; got 0.0"),
    (["--p0", "1.5"], "`--p0` must lie in (0, 1); got 1.5"),
    (["--frames", "4:4"], "--frames '4:4': the range is empty or malformed"),
    (["--frames", "7:"], "frames 7: select no frame of a sequence of 6 frames"),
    (["--frames", "a:b"], "--frames 'a:b': expected A:B"),
    (["--model-param", "p_hit"], "--model-param 'p_hit': expected KEY=VALUE"),
    (["--model", "hitmiss", "--model-param", "eta=3"], "sensor model 'hitmiss': bad parameter(s) ['eta']"),
    (["--disparity-dir", "/nonexistent/disp"], "--disparity-dir /nonexistent/disp: directory not found"),
    (["--workers", "0"], "--workers must be >= 1; got 0"),
])
def test_map_errors_exit_2_with_a_one_line_message(sequence_dir, tmp_path, capsys, argv, message):
    args = map_args(sequence_dir, tmp_path / "m.npz", "--model", "ideal")
    for option, *value in [argv[i:i + 2] for i in range(0, len(argv), 2)]:
        if option in args and option != "--model":
            index = args.index(option)
            args[index:index + 2] = []
        args += [option, *value]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1
    assert not (tmp_path / "m.npz").exists()


def test_evaluate_errors_exit_2(sequence_dir, tmp_path, capsys):
    out = tmp_path / "m.npz"
    assert main(map_args(sequence_dir, out, "--model", "ideal", "--frames", "0:1",
                         "--disparity-dir", str(sequence_dir / "disp"))) == 0
    other = tmp_path / "coarse.npz"
    truth = read_ground_truth(sequence_dir / "occupancy.npz")
    write_ground_truth(other, type(truth)(0.5, truth.occupied_keys, truth.observed_keys))
    cases = [
        (["--map", str(tmp_path / "none.npz"), "--gt", str(sequence_dir)], "none.npz: no such map file"),
        (["--map", str(out), "--gt", str(tmp_path)], "a directory without occupancy.npz"),
        (["--map", str(out), "--gt", str(tmp_path / "x.npz")], "x.npz: no such file or directory"),
        (["--map", str(out), "--gt", str(other)], "voxel size 0.5 m differs from the map's 0.2 m"),
    ]
    capsys.readouterr()
    for argv, message in cases:
        assert main(["evaluate", *argv]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err


def test_a_killed_run_resumes_to_the_uninterrupted_map(tmp_path):
    camera = StereoCamera(96.0, 63.5, 47.5, 0.1, width=128, height=96)
    sequence_dir = synthetic_sequence(tmp_path / "seq", n_frames=10, camera=camera, truth=False)
    out = tmp_path / "map.npz"
    command = [str(PRISMAP), *map_args(sequence_dir, out, "--model", "ideal", "--checkpoint-every", "2")]
    command[command.index("--voxel") + 1] = "0.1"
    meta = tmp_path / "map.checkpoint.json"
    env = dict(os.environ, PRISMAP_PROGRESS="0")
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        if meta.is_file() and json.loads(meta.read_text())["frames_done"] >= 2:
            break
        time.sleep(0.005)
    process.send_signal(signal.SIGKILL)
    process.communicate()
    assert process.returncode == -signal.SIGKILL, "the run finished before it could be killed"
    assert not out.exists()  # never a partial output
    assert 2 <= load_map(tmp_path / "map.checkpoint.npz").n_frames < 10

    finished = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert finished.returncode == 0, finished.stderr
    assert "10 frames" in finished.stdout
    assert not meta.exists() and not (tmp_path / "map.checkpoint.npz").exists()
    uninterrupted = map_sequence(sequence_dir, MappingConfig(
        model="ideal", voxel_size_m=0.1, matcher_params={"num_disparities": 16}, max_range_m=8.0), progress=False)
    assert_same_map(load_map(out), uninterrupted)  # exact

    # a checkpoint left by a run of other options or inputs is refused, not resumed or overwritten
    meta.write_text(json.dumps({"format": "prismap-map-checkpoint", "format_version": 1, "fingerprint": "0" * 64,
                                "frames_done": 0}))
    refused = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2 and "refusing to resume" in refused.stderr and "Traceback" not in refused.stderr
