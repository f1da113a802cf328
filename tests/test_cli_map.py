"""``prismap map`` and ``prismap evaluate``: characterise -> map -> evaluate on a synthetic sequence, error
messages with exit status 2, and a run killed mid-way that resumes to the uninterrupted map."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.characterise import ErrorModel, write_error_model
from prismap.cli import main
from prismap.evaluate import align_to_ground_truth, score_map
from prismap.gmm import fit_mixtures
from prismap.io import load_map, read_ground_truth, read_sequence, write_ground_truth
from prismap.pipeline import MappingConfig, characterise_sequence, map_sequence, run_fingerprint
from support import VOXEL, assert_same_map, synthetic_sequence

PRISMAP = Path(sys.executable).parent / "prismap"


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("cli") / "seq")


@pytest.fixture(scope="module")
def error_model_path(sequence_dir, tmp_path_factory):
    """An error model of SGBM fitted to the sequence's own errors (the characterisation workflow)."""
    params = {"num_disparities": 16}
    histogram = characterise_sequence(
        sequence_dir, "sgbm", matcher_params=params, conditioned=False, progress=False
    ).histogram
    fits = fit_mixtures(histogram.edges, histogram.counts, max_components=2, seed=0)
    model = ErrorModel(
        matcher="sgbm",
        matcher_params=params,
        dataset="synthetic",
        bin_width=histogram.bin_width,
        fits=tuple(fits),
        selected_components=2,
    )
    path = tmp_path_factory.mktemp("model") / "error_model.json"
    write_error_model(model, path)
    return path


def map_args(sequence_dir, out, *extra):
    return [
        "map",
        "--sequence",
        str(sequence_dir),
        "--voxel",
        str(VOXEL),
        "--max-range",
        "8",
        "--matcher-param",
        "num_disparities=16",
        "--out",
        str(out),
        *extra,
    ]


def test_map_then_evaluate_writes_the_pipelines_map_and_its_scores(sequence_dir, error_model_path, tmp_path, capsys):
    out = tmp_path / "map.npz"
    assert (
        main(
            map_args(
                sequence_dir,
                out,
                "--model",
                "convolution",
                "--error-model",
                str(error_model_path),
                "--frames",
                "1:5",
                "--policy",
                "max-abs",
            )
        )
        == 0
    )
    assert "4 frames" in capsys.readouterr().out
    from prismap.characterise import load_error_model

    mixture = load_error_model(error_model_path).mixture
    expected = map_sequence(
        sequence_dir,
        MappingConfig(
            model="convolution",
            voxel_size_m=VOXEL,
            error_model=mixture,
            matcher_params={"num_disparities": 16},
            max_range_m=8.0,
            frames=(1, 5),
            policy="max-abs",
        ),
        progress=False,
    )
    grid = load_map(out)
    assert_same_map(grid, expected)
    assert sorted(tmp_path.iterdir()) == sorted([out, out.with_suffix(".run.json")])  # no checkpoint or temporary file

    assert main(["evaluate", "--map", str(out), "--gt", str(sequence_dir)]) == 0
    printed = capsys.readouterr().out
    truth = read_ground_truth(sequence_dir / "occupancy.npz")
    keys = grid.known_voxels()[0]
    scores = score_map(
        *align_to_ground_truth(
            keys, grid.probability_at_keys(keys), truth.occupied_keys, truth.observed_keys, p0=grid.p0
        )
    )
    assert f"| Brier score | {scores.brier:.4f} |" in printed and f"| ROC AUC | {scores.roc_auc:.4f} |" in printed
    written = json.loads((tmp_path / "map.scores.json").read_text())
    assert written["scores"]["brier"] == pytest.approx(scores.brier, rel=1e-12)
    assert written["scores"]["n_voxels"] == truth.observed_keys.shape[0] and written["n_frames"] == 4


def test_evaluate_with_out_writes_json_and_reliability_figure(sequence_dir, tmp_path, capsys):
    out = tmp_path / "ideal.npz"
    assert (
        main(
            map_args(
                sequence_dir,
                out,
                "--model",
                "ideal",
                "--disparity-dir",
                str(sequence_dir / "disp"),
                "--mode",
                "projective",
            )
        )
        == 0
    )
    truth_file = tmp_path / "truth.npz"
    write_ground_truth(truth_file, read_ground_truth(sequence_dir / "occupancy.npz"))
    assert main(["evaluate", "--map", str(out), "--gt", str(truth_file), "--out", str(tmp_path / "eval")]) == 0
    capsys.readouterr()
    assert (tmp_path / "eval" / "reliability.png").stat().st_size > 1000
    scores = json.loads((tmp_path / "eval" / "scores.json").read_text())["scores"]
    assert scores["roc_auc"] > 0.7  # exact disparities: the map separates occupied from free voxels


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--sequence", "/nonexistent/seq"], "--sequence /nonexistent/seq: sequence directory not found"),
        (["--model", "prism"], "sensor model 'prism' needs an error model (--error-model MODEL.json)"),
        (
            ["--model", "andert"],
            "sensor model 'andert' needs an error model (--error-model MODEL.json) or --model-param",
        ),
        (["--model", "prism", "--error-model", "/nonexistent/m.json"], "error model /nonexistent/m.json: no such file"),
        (["--voxel", "0"], "`--voxel` must be a finite number > 0; got 0.0"),
        (["--p0", "1.5"], "`--p0` must lie in (0, 1); got 1.5"),
        (["--frames", "4:4"], "--frames '4:4': the range is empty or malformed"),
        (["--frames", "7:"], "frames 7: select no frame of a sequence of 6 frames"),
        (["--frames", "a:b"], "--frames must look like A:B with integers A and B"),
        (["--model-param", "p_hit"], "--model-param 'p_hit': expected KEY=VALUE"),
        (["--model", "hitmiss", "--model-param", "eta=3"], "sensor model 'hitmiss': bad parameter(s) ['eta']"),
        (["--disparity-dir", "/nonexistent/disp"], "--disparity-dir /nonexistent/disp: directory not found"),
        (["--workers", "0"], "--workers must lie in [1, "),
        (["--floor-rays", "-2"], "`floor_rays` must be an integer >= 0 (0: every ray); got -2"),
    ],
)
def test_map_errors_exit_2_with_a_one_line_message(sequence_dir, tmp_path, capsys, argv, message):
    args = map_args(sequence_dir, tmp_path / "m.npz", "--model", "ideal")
    for option, *value in [argv[i : i + 2] for i in range(0, len(argv), 2)]:
        if option in args and option != "--model":
            index = args.index(option)
            args[index : index + 2] = []
        args += [option, *value]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1
    assert not (tmp_path / "m.npz").exists()


def test_evaluate_errors_exit_2(sequence_dir, tmp_path, capsys):
    out = tmp_path / "m.npz"
    assert (
        main(
            map_args(
                sequence_dir, out, "--model", "ideal", "--frames", "0:1", "--disparity-dir", str(sequence_dir / "disp")
            )
        )
        == 0
    )
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
    uninterrupted = map_sequence(
        sequence_dir,
        MappingConfig(model="ideal", voxel_size_m=0.1, matcher_params={"num_disparities": 16}, max_range_m=8.0),
        progress=False,
    )
    assert_same_map(load_map(out), uninterrupted)  # exact

    # a checkpoint left by a run of other options or inputs is refused, not resumed or overwritten
    meta.write_text(
        json.dumps(
            {
                "format": "prismap-map-checkpoint",
                "format_version": 2,
                "fingerprint": "0" * 64,
                "frames_done": 0,
                "map_sha256": [],
            }
        )
    )
    refused = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2 and "refusing to resume" in refused.stderr and "Traceback" not in refused.stderr


# ------------------------------------------------------------------------------ a KITTI odometry download
T2 = np.array([0.06, -0.001, 0.004])
"""Colour camera 2 in rectified camera-0 coordinates (x_cam2 = x_cam0 + T2), KITTI-like."""


def kitti_odometry_tree(prismap_dir, root, number="00"):
    """The frames of a prismap sequence rewritten as a KITTI odometry download ``root/{sequences/NN,poses/NN.txt}``.

    ``calib.txt`` holds P0..P3 and Tr with camera 2 offset by T2 from camera 0, and ``poses/NN.txt`` camera 0's
    poses ``T_world_cam2 @ [I | T2]``, so reading it back must give the prismap sequence's colour-camera poses.
    """
    prismap_seq = read_sequence(prismap_dir)
    camera = prismap_seq.camera
    seq_dir = root / "sequences" / number
    seq_dir.mkdir(parents=True)
    for folder in ("image_2", "image_3"):
        shutil.copytree(prismap_dir / folder, seq_dir / folder)
    K = camera.K

    def row(name, matrix):
        return f"{name}: " + " ".join(f"{v:.12e}" for v in np.ravel(matrix)) + "\n"

    left, right = np.c_[K, K @ T2], np.c_[K, K @ (T2 - [camera.baseline_m, 0, 0])]
    (seq_dir / "calib.txt").write_text(
        row("P0", np.c_[K, np.zeros(3)])
        + row("P1", np.c_[K, [-386.1, 0, 0]])
        + row("P2", left)
        + row("P3", right)
        + row("Tr", np.eye(4)[:3])
    )
    (seq_dir / "times.txt").write_text("".join(f"{0.1 * i:.6e}\n" for i in range(len(prismap_seq))))
    (seq_dir / "velodyne").mkdir()
    T_cam2_cam0 = np.eye(4)
    T_cam2_cam0[:3, 3] = T2
    (root / "poses").mkdir()
    (root / "poses" / f"{number}.txt").write_text(
        "".join(" ".join(f"{v:.17g}" for v in (pose @ T_cam2_cam0)[:3].ravel()) + "\n" for pose in prismap_seq.poses)
    )
    return seq_dir


@pytest.fixture(scope="module")
def kitti_tree(tmp_path_factory):
    """``(prismap sequence dir, KITTI sequence dir)`` of the same 4 frames."""
    base = tmp_path_factory.mktemp("kitti")
    prismap_dir = synthetic_sequence(base / "seq", n_frames=4, truth=False)
    return prismap_dir, kitti_odometry_tree(prismap_dir, base / "dataset")


def test_the_kitti_tree_reads_back_the_colour_camera_poses(kitti_tree):
    prismap_dir, kitti_dir = kitti_tree
    ours, kitti = read_sequence(prismap_dir), read_sequence(kitti_dir)
    np.testing.assert_allclose(kitti.poses, ours.poses, rtol=0, atol=1e-12)
    assert kitti.camera.focal_baseline == pytest.approx(ours.camera.focal_baseline, rel=1e-12)


def test_map_a_kitti_odometry_sequence_equals_mapping_the_same_frames_in_prismaps_layout(kitti_tree, tmp_path, capsys):
    prismap_dir, kitti_dir = kitti_tree
    out = tmp_path / "kitti.npz"
    argv = map_args(kitti_dir, out, "--model", "ideal", "--disparity-dir", str(prismap_dir / "disp"))
    assert main(argv) == 0
    assert "4 frames" in capsys.readouterr().out
    expected = map_sequence(
        prismap_dir,
        MappingConfig(model="ideal", voxel_size_m=VOXEL, disparity_source="sequence", max_range_m=8.0),
        progress=False,
    )
    assert_same_map(load_map(out), expected, atol=1e-6)


def test_dask_workers_reopen_a_symlinked_kitti_sequence_by_its_path(kitti_tree, tmp_path):
    distributed = pytest.importorskip("distributed")
    prismap_dir, kitti_dir = kitti_tree
    drive = tmp_path / "drive"  # the images outside any KITTI tree, linked into one
    shutil.copytree(kitti_dir, drive)
    (tmp_path / "dataset" / "sequences").mkdir(parents=True)
    linked = tmp_path / "dataset" / "sequences" / "00"
    linked.symlink_to(drive, target_is_directory=True)
    shutil.copytree(kitti_dir.parent.parent / "poses", tmp_path / "dataset" / "poses")
    config = MappingConfig(
        model="ideal", voxel_size_m=VOXEL, disparity_source=str(prismap_dir / "disp"), max_range_m=8.0
    )
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=None) as client:
        parallel = map_sequence(linked, config, progress=False, client=client, chunk_frames=2)
    assert_same_map(parallel, map_sequence(kitti_dir, config, progress=False), atol=2e-5)


def test_mapping_a_kitti_sequence_without_poses_says_so(kitti_tree, tmp_path, capsys):
    prismap_dir, kitti_dir = kitti_tree
    unposed = tmp_path / "dataset" / "sequences" / "11"
    shutil.copytree(kitti_dir, unposed)
    argv = map_args(unposed, tmp_path / "m.npz", "--model", "ideal", "--disparity-dir", str(prismap_dir / "disp"))
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert (
        "11: no poses.txt; mapping needs the pose of every frame (a KITTI odometry sequence ROOT/sequences/NN "
        "takes ROOT/poses/NN.txt"
        in err
        and "Traceback" not in err
    )


def test_a_checkpoint_fingerprint_covers_kittis_pose_file(kitti_tree, tmp_path):
    _, kitti_dir = kitti_tree
    copy = tmp_path / "dataset" / "sequences" / "00"
    shutil.copytree(kitti_dir, copy)
    shutil.copytree(kitti_dir.parent.parent / "poses", tmp_path / "dataset" / "poses")
    config = MappingConfig(model="ideal", voxel_size_m=VOXEL)
    before = run_fingerprint(read_sequence(copy), config)
    pose_file = tmp_path / "dataset" / "poses" / "00.txt"
    text = pose_file.read_text()
    pose_file.write_text(text.replace(" 0 ", " 0.0 "))  # same poses, other bytes
    assert pose_file.read_text() != text
    assert run_fingerprint(read_sequence(copy), config) != before


@pytest.fixture(scope="module")
def conditioned_model_path(tmp_path_factory):
    from support import conditioned_error_model

    path = tmp_path_factory.mktemp("conditioned") / "error_model.json"
    write_error_model(conditioned_error_model(feature="texture", edges=(20.0, 30.0)), path)
    return path


def test_map_is_conditioned_by_default_and_plain_one_option_away(
    sequence_dir, conditioned_model_path, tmp_path, capsys
):
    from prismap.characterise import load_error_model
    from support import config

    model = load_error_model(conditioned_model_path)
    for extra, text, conditioned in (
        ((), "(prism, conditioned on 3 error classes,", True),
        (("--plain",), "(prism, plain,", False),
    ):
        out = tmp_path / f"{conditioned}.npz"
        assert (
            main(
                map_args(
                    sequence_dir,
                    out,
                    "--model",
                    "prism",
                    "--error-model",
                    str(conditioned_model_path),
                    "--frames",
                    "0:3",
                    *extra,
                )
            )
            == 0
        )
        assert text in capsys.readouterr().out
        cfg = config(
            model="prism",
            error_model=model if conditioned else model.mixture,
            disparity_source="matcher",
            frames=(0, 3),
        )
        assert_same_map(load_map(out), map_sequence(sequence_dir, cfg, progress=False))


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (("--matcher", "bm"), "the conditioned error model was fitted to matcher 'sgbm'; this run uses 'bm'"),
        (("--disparity-dir", "DISP"), None),
    ],
)
def test_map_refuses_a_conditioned_model_it_cannot_use(sequence_dir, tmp_path, capsys, extra, message):
    from support import conditioned_error_model

    path = tmp_path / "lr.json"
    write_error_model(conditioned_error_model(feature="lr_disagreement_px", edges=(0.5, 1.0)), path)
    extra = [str(sequence_dir / "disp") if e == "DISP" else e for e in extra]
    out = tmp_path / "m.npz"
    assert main(map_args(sequence_dir, out, "--model", "andert", "--error-model", str(path), *extra)) == 2
    err = capsys.readouterr().err
    assert (message or "lr_disagreement_px, which needs the matcher's left-right check") in err
    assert "Traceback" not in err and err.count("\n") == 1 and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lr.json"]


def test_map_writes_the_command_that_reproduces_it(sequence_dir, conditioned_model_path, tmp_path, capsys):
    import shlex

    out = tmp_path / "first.npz"
    assert (
        main(
            map_args(
                sequence_dir,
                out,
                "--model",
                "prism",
                "--error-model",
                str(conditioned_model_path),
                "--frames",
                "1:3",
                "--plain",
                "--model-param",
                "pass_through=0.05",
                "--p0",
                "0.08",
                "--floor-rays",
                "2",
            )
        )
        == 0
    )
    printed = capsys.readouterr().out
    record = json.loads(out.with_suffix(".run.json").read_text())
    assert f"reproduce with: {record['command']}" in printed and shlex.split(record["command"]) == record["argv"]
    argv = record["argv"]
    for option, value in (
        ("--p0", "0.08"),
        ("--voxel", str(VOXEL)),
        ("--max-range", "8.0"),
        ("--frames", "1:3"),
        ("--subsample", "1"),
        ("--mode", "ray"),
        ("--floor-rays", "2"),
        ("--out", str(out)),
    ):
        assert argv[argv.index(option) + 1] == value, option
    assert (
        "--plain" in argv and "--model-param=pass_through=0.05" in argv and "--matcher-param=num_disparities=16" in argv
    )
    assert record["settings"]["p0"] == 0.08 and record["settings"]["conditioned"] is False
    assert record["settings"]["floor_rays"] == 2
    again = tmp_path / "again.npz"
    assert main(argv[1:-1] + [str(again)]) == 0  # the recorded command, writing elsewhere
    assert_same_map(load_map(again), load_map(out))


def test_a_second_map_run_reads_the_tables_the_first_built(
    sequence_dir, conditioned_model_path, tmp_path, capsys, monkeypatch
):
    from prismap.sensor_models import _table_store

    monkeypatch.setenv("PRISMAP_TABLE_CACHE", str(tmp_path / "tables"))
    monkeypatch.setattr(_table_store, "_STORES", {})  # a fresh process's store object
    argv = ["--model", "prism", "--error-model", str(conditioned_model_path), "--frames", "0:3"]
    assert main(map_args(sequence_dir, tmp_path / "first.npz", *argv)) == 0
    first = capsys.readouterr().out.splitlines()[-1]
    built = int(first.split(", ")[1].split()[0])
    assert built > 0 and first.startswith(f"PRISM tables: 0 read from {tmp_path / 'tables'}")
    monkeypatch.setattr(_table_store, "_STORES", {})
    assert main(map_args(sequence_dir, tmp_path / "second.npz", *argv)) == 0
    assert capsys.readouterr().out.splitlines()[-1] == (
        f"PRISM tables: {built} read from {tmp_path / 'tables'}, 0 built and written there"
    )
    assert_same_map(load_map(tmp_path / "second.npz"), load_map(tmp_path / "first.npz"))
    monkeypatch.setenv("PRISMAP_TABLE_CACHE", "off")
    assert main(map_args(sequence_dir, tmp_path / "off.npz", *argv)) == 0
    assert "PRISM tables" not in capsys.readouterr().out
    assert_same_map(load_map(tmp_path / "off.npz"), load_map(tmp_path / "first.npz"))
