"""Hostile input, round two (issue 25): outputs, bounds on options and checkpoints.

Each command case runs the real ``prismap`` in a subprocess under the address-space limit of
``test_hostile`` and asserts exit 2, one line naming the problem, and nothing written or left behind.
"""

import json
import shutil
import subprocess

import numpy as np
import pytest
from test_hostile import _prismap, expand, refused_line

from prismap.characterise import ErrorModel, write_error_model
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit
from prismap.grid import OccupancyMap
from prismap.io import load_map, save_map
from prismap.pipeline import map_sequence
from support import config, synthetic_sequence

MAP = ["map", "--disparity-dir", "SEQ/disp", "--model", "hitmiss", "--voxel", "0.1"]


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("hostile25") / "seq", n_frames=3)


@pytest.fixture(scope="module")
def error_model(tmp_path_factory):
    """A plausible SGBM-like error model (0.4 px core, 4 px outliers)."""
    path = tmp_path_factory.mktemp("em25") / "sgbm.json"
    mixture = GaussianMixture([0.9, 0.1], [0.0, 0.0], [0.4, 4.0])
    write_error_model(
        ErrorModel("sgbm", {}, "hostile", 1 / 32, [MixtureFit(mixture, -1e3, 0.0, 0.0, 1e3, 10, True)], 2), path
    )
    return path


@pytest.fixture(scope="module")
def small_map(tmp_path_factory):
    """A map file with occupied voxels (PLY export writes those)."""
    grid = OccupancyMap(0.1, p0=0.5)
    grid.set_voxels(np.array([[0, 0, 0], [1, 2, 3]], np.int32), np.array([2.0, -1.0]), np.array([1, 1], np.uint16))
    path = tmp_path_factory.mktemp("map25") / "m.npz"
    save_map(grid, path)
    return path


def _with_voxel_size(source, target, size):
    fields = dict(np.load(source))
    fields["voxel_size_m"] = np.array(size)
    np.savez(target, **fields)


def _device_named(work, name):
    (work / name).symlink_to("/dev/null")


# name -> (prepare(seq, work, map) or None, argv with SEQ/WORK/EM/MAP placeholders, expected text)
CASES = {
    # item 9: an output that is an input of the run, or not a regular file
    "--out seq/poses.txt": (None, [*MAP, "--out", "SEQ/poses.txt"], "poses.txt, an input of this run"),
    "--out seq/disp/000000.png": (
        None,
        [*MAP, "--out", "SEQ/disp/000000.png"],
        "lies inside",
    ),
    "export m.ply --to m.ply": (
        lambda s, w, m: shutil.copy(m, w / "m.ply"),
        ["export", "WORK/m.ply", "--to", "WORK/m.ply"],
        "an input of this run (the map file)",
    ),
    "export --to a device": (
        lambda s, w, m: _device_named(w, "dev.ply"),
        ["export", "MAP", "--to", "WORK/dev.ply"],
        "exists and is not a regular file",
    ),
    # item 13: one line instead of a traceback
    "--out of 300 characters": (
        None,
        [*MAP, "--out", "WORK/" + "x" * 296 + ".npz"],
        "the file name has 300 bytes; at most 200",
    ),
    # item 12: workers bound by the cores
    "--workers 1000": (None, [*MAP, "--workers", "1000", "--out", "WORK/o.npz"], "--workers must lie in [1, "),
    # item 18: a refused run leaves no directory behind
    "--out a/b/c/o.npz refused": (None, [*MAP, "--p0", "2", "--out", "WORK/a/b/c/o.npz"], "`--p0` must lie in"),
    # item 4: a voxel size whose centres overflow
    "map with voxel size 1e300": (
        lambda s, w, m: _with_voxel_size(m, w / "big.npz", 1e300),
        ["export", "WORK/big.npz", "--to", "WORK/big.ply"],
        "`voxel_size_m` must be at most 1e+06 m",
    ),
    # items 5 and 15: bounded --distances
    "--distances beyond the rig": (
        None,
        ["models", "compare", "--error-model", "EM", "--distances", "10000", "--out", "WORK/cmp"],
        "10000 m lies beyond this rig's range",
    ),
    "--distances 17 values": (
        None,
        [
            "models",
            "compare",
            "--error-model",
            "EM",
            "--distances",
            ",".join(str(d) for d in range(1, 18)),
            "--out",
            "WORK/cmp",
        ],
        "holds 17 distances; at most 16",
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_hostile_command_exits_2_with_one_line_and_writes_nothing(name, sequence, error_model, small_map, tmp_path):
    prepare, argv, expected = CASES[name]
    seq, work = tmp_path / "seq", tmp_path / "work"
    shutil.copytree(sequence, seq)
    work.mkdir()
    if prepare is not None:
        prepare(seq, work, small_map)
    seq_before = {p: p.read_bytes() for p in seq.rglob("*") if p.is_file()}
    argv = expand(argv, seq, SEQ=seq, WORK=work, EM=error_model, MAP=small_map)
    assert expected in refused_line(argv, tmp_path, work)
    assert {p: p.read_bytes() for p in seq.rglob("*") if p.is_file()} == seq_before  # no input clobbered


def test_a_viewer_on_an_address_this_machine_lacks_is_refused_at_once(small_map, tmp_path):
    """Item 14: viser would retry 1000 ports on 203.0.113.7 (TEST-NET-3) and never say it is ready."""
    try:
        status, stderr = _prismap(
            ["view", str(small_map), "--host", "203.0.113.7", "--port", "0"], tmp_path, timeout=60
        )
    except subprocess.TimeoutExpired:
        pytest.fail("prismap view hung on an address it cannot bind")
    assert status == 2, stderr
    assert stderr.strip().splitlines() == [stderr.strip()]
    assert "--host 203.0.113.7: cannot listen on this address" in stderr


# ------------------------------------------------------------------------------- item 6: checkpoints
@pytest.fixture
def checkpointed(sequence, tmp_path):
    """A checkpoint of the run (frames saved after 1 and 2 of 3) and the run's config."""
    run = config(model="hitmiss", voxel_size_m=0.1)
    checkpoint = tmp_path / "run.checkpoint.npz"
    map_sequence(sequence, run, progress=False, checkpoint=checkpoint, checkpoint_every=1)
    assert load_map(checkpoint).n_frames == 2
    return run, checkpoint


def test_a_checkpoint_map_swapped_for_another_is_refused(sequence, checkpointed):
    run, checkpoint = checkpointed
    coarse = OccupancyMap(0.2, p0=run.p0)
    coarse.n_frames = 1
    save_map(coarse, checkpoint)
    with pytest.raises(PrismapInputError, match="is not the map run.checkpoint.json vouches for"):
        map_sequence(sequence, run, progress=False, checkpoint=checkpoint, checkpoint_every=1)


def test_a_checkpoint_map_with_edited_frames_is_refused(sequence, checkpointed):
    run, checkpoint = checkpointed
    fields = dict(np.load(checkpoint))
    fields["n_frames"] = np.array(3)
    np.savez(checkpoint, **fields)
    with pytest.raises(PrismapInputError, match="SHA-256 differs"):
        map_sequence(sequence, run, progress=False, checkpoint=checkpoint, checkpoint_every=1)


def test_a_checkpoint_vouched_for_but_of_another_voxel_size_is_refused(sequence, checkpointed):
    """Both files forged together: the map's own contents must still fit the run."""
    from prismap.pipeline._checkpoint import _digest

    run, checkpoint = checkpointed
    coarse = OccupancyMap(0.2, p0=run.p0)
    coarse.n_frames = 1
    save_map(coarse, checkpoint)
    meta_path = checkpoint.with_suffix(".json")
    meta = json.loads(meta_path.read_text())
    meta["map_sha256"] = [_digest(checkpoint)]
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(PrismapInputError, match="voxel size 0.2, this run's is 0.1"):
        map_sequence(sequence, run, progress=False, checkpoint=checkpoint, checkpoint_every=1)


def test_a_kill_between_the_staged_map_and_its_rename_still_resumes(sequence, checkpointed):
    """The JSON lists the old and the new map while the new one waits: the old one in place resumes."""
    from prismap.pipeline._checkpoint import _digest

    run, checkpoint = checkpointed
    meta_path = checkpoint.with_suffix(".json")
    meta = json.loads(meta_path.read_text())
    meta["map_sha256"] = ["0" * 64, _digest(checkpoint)]
    meta_path.write_text(json.dumps(meta))
    resumed = map_sequence(sequence, run, progress=False, checkpoint=checkpoint, checkpoint_every=1)
    whole = map_sequence(sequence, run, progress=False)
    assert resumed.n_frames == 3
    for mine, theirs in zip(resumed.known_voxels(), whole.known_voxels()):
        assert np.array_equal(mine, theirs)


# ------------------------------------------------------------------ items 13 and 18: a full disk, one line, no DIR
@pytest.fixture(scope="module")
def sequence_map(sequence, tmp_path_factory):
    """A map of the sequence's first frame at the ground truth's voxel size (for evaluate)."""
    path = tmp_path_factory.mktemp("seqmap25") / "m.npz"
    save_map(map_sequence(sequence, config(model="hitmiss", frames=(0, 1)), progress=False), path)
    return path


FULL_DISK = {
    "evaluate --out DIR": ["evaluate", "--map", "SEQMAP", "--gt", "SEQ", "--out", "WORK/ev"],
    "characterise --out DIR": [
        "characterise",
        "--dataset",
        "SEQ/mb",
        "--matcher",
        "bm",
        "--plain",
        "--out",
        "WORK/a/ch",
    ],
    "models compare --out DIR": ["models", "compare", "--error-model", "EM", "--out", "WORK/mc"],
    "export .mcap": ["export", "MAP", "--to", "WORK/m.mcap"],
    "export rosbag2 mcap": ["export", "MAP", "--to", "WORK/bag", "--format", "rosbag2"],
    "export rosbag2 sqlite3": ["export", "MAP", "--to", "WORK/d/bag", "--format", "rosbag2", "--storage", "sqlite3"],
}


@pytest.mark.parametrize("name", list(FULL_DISK))
def test_a_full_disk_is_one_line_and_leaves_no_directory(
    name, sequence, error_model, small_map, sequence_map, tmp_path
):
    from test_hostile_inputs import _middlebury_folder

    seq, work = tmp_path / "seq", tmp_path / "work"
    shutil.copytree(sequence, seq)
    _middlebury_folder(seq / "mb")
    work.mkdir()
    argv = [
        a.replace("SEQMAP", str(sequence_map))
        .replace("SEQ", str(seq))
        .replace("WORK", str(work))
        .replace("EM", str(error_model))
        .replace("MAP", str(small_map))
        for a in FULL_DISK[name]
    ]
    # numba caches its kernels on a first run, which must not be the one under the file-size limit
    (tmp_path / "warm").mkdir()
    warm = [a.replace(str(work), str(tmp_path / "warm")) for a in argv]
    assert _prismap(warm, tmp_path)[0] == 0
    shutil.rmtree(tmp_path / "warm")
    status, stderr = _prismap(argv, tmp_path, file_size_limit=2048)
    lines = stderr.strip().splitlines()
    assert status == 2, stderr
    assert len(lines) == 1 and lines[0].startswith(f"prismap {argv[0]}") and f": error: {work}" in lines[0], stderr
    assert "cannot write (File too large" in lines[0] or "cannot write (disk I/O error)" in lines[0]
    assert list(work.iterdir()) == []


def test_a_refused_experiment_writes_no_settings(tmp_path):
    status, stderr = _prismap(
        ["experiment", "--world", "office2d", "--quick", "--voxel", "1e-9", "--out", str(tmp_path / "exp")], tmp_path
    )
    assert status == 2 and len(stderr.strip().splitlines()) == 1, stderr
    assert "`voxel_size_m` = 1e-09" in stderr
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ item 7: a characterisation killed mid-figure
def test_a_characterisation_killed_while_drawing_its_classes_figure_is_redone(tmp_path):
    from prismap.characterise._run import written_characterisation
    from support import conditioned_error_model

    write_error_model(conditioned_error_model(feature="texture", edges=(20.0, 30.0)), tmp_path / "error_model.json")
    for name in ("table.md", "errors.png", "errors_wide.png"):
        (tmp_path / name).write_bytes(b"x")
    stale = tmp_path / ".errors_classes.png.999999999.abcd.tmp.png"  # its process is gone (above any pid_max)
    stale.write_bytes(b"half a figure")
    assert written_characterisation(tmp_path) is None  # errors_classes.png is missing: characterise again
    assert not stale.exists()
    (tmp_path / "errors_classes.png").write_bytes(b"x")
    assert sorted(p.name for p in written_characterisation(tmp_path).values()) == [
        "error_model.json",
        "errors.png",
        "errors_classes.png",
        "errors_wide.png",
        "table.md",
    ]


def test_a_plain_characterisation_needs_no_classes_figure(tmp_path, error_model):
    from prismap.characterise._run import written_characterisation

    shutil.copy(error_model, tmp_path / "error_model.json")
    for name in ("table.md", "errors.png", "errors_wide.png"):
        (tmp_path / name).write_bytes(b"x")
    assert "figure_classes" not in written_characterisation(tmp_path)


def test_ctrl_c_inside_a_compiled_kernel_is_an_interruption_not_a_traceback(monkeypatch, capsys):
    """Item 13: Ctrl-C in the numba ray caster surfaced as a SystemError (2 of 18 tries)."""
    from test_hostile import _parser_with

    from prismap.cli import _main

    def kernel(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("<built-in function cast> returned a result with an exception set")  # noqa: B904

    def bug(args):
        raise SystemError("a real bug")

    def register(subparsers):
        subparsers.add_parser("kernel").set_defaults(func=kernel)
        subparsers.add_parser("bug").set_defaults(func=bug)

    monkeypatch.setattr(_main, "COMMANDS", ())
    monkeypatch.setattr(_main, "build_parser", _parser_with(register, _main.build_parser))
    assert _main.main(["kernel"]) == 130
    assert capsys.readouterr().err.strip().splitlines() == ["prismap kernel: interrupted"]
    with pytest.raises(SystemError, match="a real bug"):
        _main.main(["bug"])
