"""Hostile input (issue 12): each case replays what a hostile user tried, through the real ``prismap`` command in
a subprocess under an address-space limit, and asserts exit 2, exactly one line on stderr, and nothing written or
left behind. Library-level cases (map-file fields, locks, modes, stale temporaries) run in-process."""

import contextlib
import logging
import os
import resource
import shutil
import signal
import struct
import subprocess
import sys
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

from prismap._files import atomic_path, exclusive_lock, write_text_atomic
from prismap._validate import check_pose
from prismap.camera import StereoCamera
from prismap.characterise import ErrorModel, write_error_model
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit
from prismap.grid import OccupancyMap
from prismap.io import StereoFrame, load_map, read_ground_truth, save_map, write_sequence
from support import CAMERA, config, synthetic_sequence

SRC = Path(__file__).resolve().parents[1] / "src"
MEMORY_LIMIT = 3 << 30  # RLIMIT_AS of every subprocess: a case that tries to allocate gigabytes fails the test
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# ----------------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("hostile") / "seq", n_frames=3)


@pytest.fixture(scope="module")
def narrow_error_model(tmp_path_factory):
    """An error model whose sigma is 1e-4 px: PRISM's tables would grow without end."""
    path = tmp_path_factory.mktemp("em") / "narrow.json"
    mixture = GaussianMixture([0.9, 0.1], [0.0, 0.0], [1e-4, 2.0])
    fits = [MixtureFit(mixture, -1e5, 0.0, 0.0, 1e5, 10, True)]
    write_error_model(ErrorModel("sgbm", {}, "hostile", 1 / 32, fits, 2), path)
    return path


def _prismap(argv, cwd, *, file_size_limit=None, timeout=300):
    """Run the real command (this tree's ``prismap``) under :data:`MEMORY_LIMIT`; (status, stderr)."""

    def limits():
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
        if file_size_limit is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
            resource.setrlimit(resource.RLIMIT_FSIZE, (file_size_limit, file_size_limit))

    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")]),
        "MPLBACKEND": "Agg",
    }
    done = subprocess.run(
        [sys.executable, "-c", "import sys; from prismap.cli import main; sys.exit(main())", *argv],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=limits,
    )
    return done.returncode, done.stderr


def refused_line(argv, cwd, work):
    """Run ``argv`` (:func:`_prismap`) and assert what a refused command promises: exit 2, one line starting
    ``prismap <command>``, nothing written into ``work`` and no lock or temporary left in ``cwd``; the line."""
    before = _tree(work)
    status, stderr = _prismap(argv, cwd)
    lines = stderr.strip().splitlines()
    assert status == 2, stderr
    assert len(lines) == 1 and lines[0].startswith(f"prismap {argv[0]}"), stderr
    assert _tree(work) == before
    assert not [p for p in Path(cwd).iterdir() if p.name.startswith(".")]  # no lock or temporary beside WORK
    return lines[0]


def expand(argv, seq, **placeholders):
    """``argv`` with each placeholder (in the given order) replaced, and ``--sequence seq`` for ``map`` without
    ``--bag``."""
    for name, value in placeholders.items():
        argv = [a.replace(name, str(value)) for a in argv]
    if argv[0] == "map" and "--bag" not in argv:
        argv[1:1] = ["--sequence", str(seq)]
    return argv


def _tree(path):
    return sorted(str(p.relative_to(path)) for p in Path(path).rglob("*"))


def _chunk(kind, data):
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png_bomb(width, height):
    """A valid-looking PNG of a few hundred bytes that declares ``width x height`` grey pixels."""
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return PNG_SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(bytes(4096))) + _chunk(b"IEND", b"")


def _rewrite_poses(seq, change):
    rows = np.loadtxt(seq / "poses.txt").reshape(-1, 3, 4)
    np.savetxt(seq / "poses.txt", change(rows).reshape(len(rows), 12))


def _scaled(rows):
    rows[1, :, :3] *= 3.0
    return rows


def _reflected(rows):
    rows[1, :, 0] *= -1.0
    return rows


def _calib(seq, focal_px, baseline_m):
    f, cx, cy = focal_px, CAMERA.cx_px, CAMERA.cy_px
    p2 = [f, 0, cx, 0, 0, f, cy, 0, 0, 0, 1, 0]
    p3 = [f, 0, cx, -f * baseline_m, 0, f, cy, 0, 0, 0, 1, 0]
    (seq / "calib.txt").write_text(
        "".join(f"{name}: {' '.join(repr(float(v)) for v in p)}\n" for name, p in (("P2", p2), ("P3", p3)))
    )


def _flip_byte(path):
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def _bomb_images(seq):
    for folder in ("image_2", "image_3"):
        for image in (seq / folder).glob("*.png"):
            image.write_bytes(_png_bomb(20000, 20000))


def _huge_map(path, n_voxels=300_000_000):
    """A small .npz whose headers declare ``n_voxels`` voxels (the data is cut short)."""
    scalars = {
        "format": np.array("prismap-map"),
        "format_version": np.array(1),
        "voxel_size_m": np.array(0.1),
        "p0": np.array(0.05),
        "ndim": np.array(3),
        "policy": np.array("mean"),
        "clamp": np.full(2, np.nan),
        "occupied_threshold": np.array(0.5),
        "free_threshold": np.array(0.5),
        "n_frames": np.array(1),
    }
    with zipfile.ZipFile(path, "w") as archive:
        for name, value in scalars.items():
            with archive.open(f"{name}.npy", "w") as member:
                np.lib.format.write_array(member, value)
        for name, dtype, shape in (
            ("keys", "<i4", (n_voxels, 3)),
            ("log_odds", "<f4", (n_voxels,)),
            ("counts", "<u2", (n_voxels,)),
        ):
            with archive.open(f"{name}.npy", "w") as member:
                np.lib.format.write_array_header_1_0(member, {"descr": dtype, "fortran_order": False, "shape": shape})
                member.write(bytes(1024))


MAP = ["map", "--disparity-dir", "SEQ/disp", "--model", "hitmiss", "--voxel", "0.1"]

# name -> (prepare(seq, work) or None, argv with SEQ/WORK/EM placeholders, expected text in the message)
CASES = {
    "pose scaled x3": (
        lambda s, w: _rewrite_poses(s, _scaled),
        [*MAP, "--out", "WORK/o.npz"],
        "poses.txt line 2: rotation is not orthonormal",
    ),
    "pose reflection": (
        lambda s, w: _rewrite_poses(s, _reflected),
        [*MAP, "--out", "WORK/o.npz"],
        "poses.txt line 2: rotation is not orthonormal with det +1",
    ),
    "focal 1e300": (lambda s, w: _calib(s, 1e300, 0.1), [*MAP, "--out", "WORK/o.npz"], "`focal_px` must lie in"),
    "baseline 1e-300": (
        lambda s, w: _calib(s, 72.0, 1e-300),
        [*MAP, "--out", "WORK/o.npz"],
        "`baseline_m` must lie in",
    ),
    "focal x baseline 1e10": (
        lambda s, w: _calib(s, 1e6, 1e4),
        [*MAP, "--out", "WORK/o.npz"],
        "`focal_px * baseline_m (the depth of a 1 px disparity)` must lie in",
    ),
    "PNG of 20000x20000": (lambda s, w: _bomb_images(s), [*MAP, "--out", "WORK/o.npz"], "declares 20000x20000 pixels"),
    "corrupt PNG": (
        lambda s, w: _flip_byte(s / "image_2" / "000001.png"),
        [*MAP, "--out", "WORK/o.npz"],
        "image_2/000001.png: left image cannot be decoded (truncated or corrupt PNG)",
    ),
    "--out a directory": (None, [*MAP, "--out", "WORK"], "is a directory; expected a file name"),
    "--out under a file": (
        lambda s, w: (w / "file").write_text("x"),
        [*MAP, "--out", "WORK/file/o.npz"],
        "is not a directory",
    ),
    "--out unwritable": (None, [*MAP, "--out", "/proc/prismap-hostile/o.npz"], "--out /proc/prismap-hostile/o.npz"),
    "--model-param p0": (
        None,
        [*MAP, "--model-param", "p0=0.2", "--out", "WORK/o.npz"],
        "p0: cannot be set as a model parameter",
    ),
    "--model-param error_model": (
        None,
        [*MAP, "--model-param", "error_model=1", "--out", "WORK/o.npz"],
        "error_model: cannot be set as a model parameter",
    ),
    "--model-param voxel_size_m": (
        None,
        [*MAP, "--model-param", "voxel_size_m=1", "--out", "WORK/o.npz"],
        "voxel_size_m: cannot be set as a model parameter",
    ),
    "--voxel 1e-9": (
        None,
        ["map", "--disparity-dir", "SEQ/disp", "--model", "hitmiss", "--voxel", "1e-9", "--out", "WORK/o.npz"],
        "voxel size 1e-09 m: the map's key range",
    ),
    "num_disparities 160000": (
        None,
        [
            "map",
            "--matcher",
            "sgbm",
            "--matcher-param",
            "num_disparities=160000",
            "--model",
            "hitmiss",
            "--voxel",
            "0.1",
            "--out",
            "WORK/o.npz",
        ],
        "must be below the image width 96 px",
    ),
    "prism sigma 1e-4 (map)": (
        None,
        [
            "map",
            "--disparity-dir",
            "SEQ/disp",
            "--model",
            "prism",
            "--error-model",
            "EM",
            "--voxel",
            "0.1",
            "--out",
            "WORK/o.npz",
        ],
        "MAX_TABLE_NODES",
    ),
    "prism sigma 1e-4 (models compare)": (
        None,
        ["models", "compare", "--error-model", "EM", "--out", "WORK/cmp"],
        "MAX_TABLE_NODES",
    ),
    "map declaring 300 M voxels": (
        lambda s, w: _huge_map(s / "huge.npz"),
        ["evaluate", "--map", "SEQ/huge.npz", "--gt", "SEQ", "--out", "WORK/eval"],
        "more than the memory budget",
    ),
    "experiment --frames 100000": (
        None,
        ["experiment", "--world", "office2d", "--quick", "--frames", "100000", "--out", "WORK/exp"],
        "`n_frames` must be at most 99",
    ),
    "experiment --seed -1": (
        None,
        ["experiment", "--world", "office2d", "--seed", "-1", "--out", "WORK/exp"],
        "argument --seed: expected an integer >= 0",
    ),
    "demo --seed -1": (
        None,
        ["demo", "--quick", "--seed", "-1", "--out", "WORK/demo"],
        "argument --seed: expected an integer >= 0",
    ),
    "characterise --bin-width 1e-9": (
        None,
        [
            "characterise",
            "--dataset",
            "middlebury-motorcycle",
            "--matcher",
            "bm",
            "--bin-width",
            "1e-9",
            "--out",
            "WORK/ch",
        ],
        "MAX_BINS",
    ),
    "characterise --seed -1": (
        None,
        ["characterise", "--dataset", "middlebury-motorcycle", "--matcher", "bm", "--seed", "-1", "--out", "WORK/ch"],
        "--seed",
    ),
}
XFAIL = {}


def _case_params():
    params = []
    for name in CASES:
        marks = [pytest.mark.xfail(reason=XFAIL[name], strict=True)] if name in XFAIL else []
        params.append(pytest.param(name, id=name, marks=marks))
    return params


@pytest.mark.parametrize("name", _case_params())
def test_hostile_command_exits_2_with_one_line_and_writes_nothing(name, sequence, narrow_error_model, tmp_path):
    prepare, argv, expected = CASES[name]
    seq, work = tmp_path / "seq", tmp_path / "work"
    shutil.copytree(sequence, seq)
    work.mkdir()
    if prepare is not None:
        prepare(seq, work)
    argv = expand(argv, seq, SEQ=seq, WORK=work, EM=narrow_error_model)
    assert expected in refused_line(argv, tmp_path, work)


def _map_argv(sequence, out):
    return ["map", "--sequence", str(sequence), *(a.replace("SEQ", str(sequence)) for a in MAP[1:]), "--out", str(out)]


def test_a_file_size_limit_during_the_save_is_one_line_and_leaves_nothing(sequence, tmp_path):
    status, stderr = _prismap(_map_argv(sequence, tmp_path / "o.npz"), tmp_path, file_size_limit=32 * 1024)
    assert status == 2, stderr
    assert stderr.strip().splitlines() == [
        f"prismap map: error: {tmp_path / 'o.npz'}: cannot write (File too large (the file-size limit, ulimit -f))"
    ]
    assert list(tmp_path.iterdir()) == []


def test_a_second_run_on_a_locked_output_is_refused(sequence, tmp_path):
    out = tmp_path / "o.npz"
    with exclusive_lock(out):
        status, stderr = _prismap(_map_argv(sequence, out), tmp_path)
    assert status == 2
    assert stderr.strip().splitlines() == [
        f"prismap map: error: --out {out}: another prismap run is using it (lock {tmp_path / '.o.npz.lock'}); "
        "wait for it to finish or choose another output"
    ]
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------- in-process
def test_a_checkpoint_in_use_is_refused(sequence, tmp_path):
    from prismap.pipeline import map_sequence

    checkpoint = tmp_path / "run.checkpoint.npz"
    with exclusive_lock(checkpoint, "checkpoint"):
        with pytest.raises(PrismapInputError, match="checkpoint .*run.checkpoint.npz: another prismap run"):
            map_sequence(sequence, config(), progress=False, checkpoint=checkpoint, checkpoint_every=1)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("rotation", "message"),
    [(3.0 * np.eye(3), r"max \|R\^T R - I\| = 8"), (np.diag([-1.0, 1.0, 1.0]), "det = -1")],
    ids=["scaled x3", "reflection"],
)
def test_every_pose_source_refuses_invalid_rotations(rotation, message):
    pose = np.eye(4)
    pose[:3, :3] = rotation
    with pytest.raises(
        PrismapInputError, match="`T_world_cam`: rotation is not orthonormal with det \\+1 .*" + message
    ):
        check_pose(pose, "`T_world_cam`")
    image = np.zeros((4, 6), np.uint8)
    with pytest.raises(PrismapInputError, match="f0: `T_world_cam`: rotation is not orthonormal"):
        StereoFrame(image, image, CAMERA, None, pose, name="f0")
    check_pose(np.eye(4), "identity")  # a valid pose passes


@pytest.mark.parametrize(
    ("focal", "baseline", "name"),
    [(1e300, 0.1, "focal_px"), (600.0, 1e-300, "baseline_m"), (1e6, 1e4, "focal_px \\* baseline_m")],
)
def test_cameras_without_a_representable_depth_range_are_refused(focal, baseline, name):
    with pytest.raises(PrismapInputError, match=f"`{name}.*` must lie in"):
        StereoCamera(focal, 10.0, 10.0, baseline)


def _map_fields(**changes):
    fields = {
        "format": np.array("prismap-map"),
        "format_version": np.array(1),
        "voxel_size_m": np.array(0.1),
        "p0": np.array(0.05),
        "ndim": np.array(3),
        "policy": np.array("mean"),
        "clamp": np.full(2, np.nan),
        "occupied_threshold": np.array(0.5),
        "free_threshold": np.array(0.5),
        "n_frames": np.array(2),
        "keys": np.array([[0, 0, 0], [1, 2, 3]], np.int32),
        "log_odds": np.array([0.5, -0.5], np.float32),
        "counts": np.array([1, 2], np.uint16),
    }
    fields.update(changes)
    return fields


BAD_MAP_FIELDS = {
    "clamp 0-d": ({"clamp": np.array(0.1)}, r"`clamp` must be an \(2,\) float array; got shape \(\)"),
    "clamp string": ({"clamp": np.array("0.1,0.9")}, r"`clamp` must be an \(2,\) float array"),
    "ndim string": ({"ndim": np.array("3")}, r"`ndim` must be an integer \(a 0-d array\); got shape \(\), dtype <U1"),
    "n_frames string": ({"n_frames": np.array("2")}, "`n_frames` must be an integer"),
    "version string": ({"format_version": np.array("1")}, "`format_version` must be an integer"),
    "version 1.9": ({"format_version": np.array(1.9)}, "`format_version` must be an integer"),
    "voxel size array": ({"voxel_size_m": np.array([0.1, 0.1])}, r"`voxel_size_m` must be a number \(a 0-d array\)"),
    "negative n_frames": ({"n_frames": np.array(-3)}, "`n_frames` must be >= 0; got -3"),
    "duplicate keys": ({"keys": np.array([[1, 2, 3], [1, 2, 3]], np.int32)}, "`keys` holds 1 duplicate voxel keys"),
}


@pytest.mark.parametrize("change", BAD_MAP_FIELDS, ids=list(BAD_MAP_FIELDS))
def test_map_files_with_fields_of_the_wrong_type_rank_or_value_are_refused(tmp_path, change):
    changes, message = BAD_MAP_FIELDS[change]
    path = tmp_path / "bad.npz"
    np.savez(path, **_map_fields(**changes))
    with pytest.raises(PrismapInputError, match=message):
        load_map(path)
    np.savez(path, **_map_fields())
    assert load_map(path).n_known == 2  # the unchanged file loads


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"version": np.array("1")}, "`version` must be an integer"),
        ({"voxel_size_m": np.array([0.1])}, "`voxel_size_m` must be a number"),
        ({"observed_keys": np.zeros(3, np.int64)}, r"`observed_keys` must be an \(N, 3\) integer array"),
    ],
)
def test_ground_truth_files_with_fields_of_the_wrong_type_or_rank_are_refused(tmp_path, changes, message):
    fields = {
        "format": np.array("prismap-ground-truth-occupancy"),
        "version": np.array(1),
        "voxel_size_m": np.array(0.1),
        "occupied_keys": np.zeros((1, 3), np.int64),
        "observed_keys": np.zeros((1, 3), np.int64),
        **changes,
    }
    np.savez(tmp_path / "gt.npz", **fields)
    with pytest.raises(PrismapInputError, match=message):
        read_ground_truth(tmp_path / "gt.npz")


def test_stale_temporaries_of_dead_processes_are_removed_by_the_next_save(tmp_path):
    path = tmp_path / "m.npz"
    dead = tmp_path / ".m.npz.999999999.abcd.tmp.npz"  # above any pid_max: its process is gone
    alive = tmp_path / f".m.npz.{os.getpid()}.efgh.tmp.npz"  # a save in progress in a live process
    dead.write_bytes(b"partial")
    alive.write_bytes(b"partial")
    save_map(OccupancyMap(0.1, p0=0.5), path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([alive.name, "m.npz"])


def test_a_failed_write_leaves_no_temporary_and_the_old_file(tmp_path):
    path = tmp_path / "notes.txt"
    write_text_atomic(path, "old")
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"] and path.read_text() == "old"


@contextlib.contextmanager
def _umask(mask):
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def test_new_outputs_follow_the_umask_and_replaced_ones_keep_their_mode(tmp_path):
    with _umask(0o022):
        write_text_atomic(tmp_path / "new.txt", "a")
        assert (tmp_path / "new.txt").stat().st_mode & 0o777 == 0o644
        os.chmod(tmp_path / "new.txt", 0o640)
        write_text_atomic(tmp_path / "new.txt", "b")
        assert (tmp_path / "new.txt").stat().st_mode & 0o777 == 0o640
        frame = StereoFrame(np.zeros((4, 6), np.uint8), np.zeros((4, 6), np.uint8), CAMERA, None, np.eye(4))
        write_sequence([frame], tmp_path / "seq")
        assert (tmp_path / "seq").stat().st_mode & 0o777 == 0o755
        assert (tmp_path / "seq" / "poses.txt").stat().st_mode & 0o777 == 0o644
    with _umask(0o077):
        write_text_atomic(tmp_path / "private.txt", "c")
        assert (tmp_path / "private.txt").stat().st_mode & 0o777 == 0o600


def test_dask_workers_drop_reports_of_bad_input_only():
    from prismap.cli._map import _DropInputErrors

    drop = _DropInputErrors()
    bad = logging.LogRecord(
        "distributed.worker",
        logging.ERROR,
        "",
        0,
        "Compute Failed\nException: %r",
        (PrismapInputError("x.png: left image cannot be decoded"),),
        None,
    )
    other = logging.LogRecord(
        "distributed.worker", logging.ERROR, "", 0, "Compute Failed\nException: %r", (ZeroDivisionError("a bug"),), None
    )
    assert not drop.filter(bad) and drop.filter(other)


def test_opencv_errors_become_one_line_naming_the_call(monkeypatch, capsys):
    import cv2

    from prismap.cli import _main

    def register(subparsers):
        subparsers.add_parser("boom").set_defaults(func=lambda args: cv2.resize(np.zeros((0, 0)), (0, 0)))

    monkeypatch.setattr(_main, "COMMANDS", ())
    monkeypatch.setattr(_main, "build_parser", _parser_with(register, _main.build_parser))
    assert _main.main(["boom"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("prismap boom: error: OpenCV ") and "resize" in err[0]


def _parser_with(register, build):
    def parser():
        built = build()
        register(next(a for a in built._actions if a.dest == "command"))
        return built

    return parser


def test_the_top_level_package_loads_study_and_experiment():
    import prismap

    assert prismap.study.run_models_compare and prismap.experiment.run_office2d
