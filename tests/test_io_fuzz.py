"""Fuzzing the dataset readers: arbitrary bytes and mutated valid files raise PrismapInputError or parse.

Each reader (KITTI, New Tsukuba, Velodyne, Middlebury calib.txt, PFM, sequence calib.txt and poses.txt)
gets arbitrary bytes and mutations of a valid file (truncation, byte flips, inserted NaN,
letters and separators, deleted spans that drop or merge columns). Seeded (``derandomize=True``).
"""

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from prismap.errors import PrismapInputError
from prismap.io._kitti import KittiOdometry, read_kitti_calib, read_kitti_disparity, read_kitti_poses
from prismap.io._middlebury import read_middlebury_calib
from prismap.io._pfm import read_pfm
from prismap.io._sequence import read_sequence
from prismap.io._tsukuba import read_tsukuba_depth, read_tsukuba_disparity, read_tsukuba_track
from prismap.io._velodyne import read_velodyne_bin

EXAMPLES = 3000
FUZZ = settings(
    derandomize=True,
    deadline=None,
    max_examples=EXAMPLES,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
TOKENS = [
    b" nan",
    b"NaN",
    b" inf",
    b" 1.5",
    b" -2e3",
    b"x",
    b",",
    b":",
    b"\n",
    b" ",
    b"\t",
    b"e",
    b"-",
    b"<",
    b">",
    b"\x00",
    b"\xff",
]


@st.composite
def mutations(draw, valid):
    """``valid`` after 1-4 edits: truncate, flip a byte, insert a token, delete a span, repeat a line."""
    data = bytearray(valid)
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(data)))
        kind = draw(st.sampled_from(["truncate", "flip", "insert", "delete", "repeat_line"]))
        if kind == "truncate":
            del data[at:]
        elif kind == "flip" and at < len(data):
            data[at] ^= draw(st.integers(1, 255))
        elif kind == "insert":
            data[at:at] = draw(st.sampled_from(TOKENS))
        elif kind == "delete":
            del data[at : at + draw(st.integers(1, 16))]
        elif kind == "repeat_line":
            start = data.rfind(b"\n", 0, at) + 1
            end = data.find(b"\n", at)
            end = len(data) if end < 0 else end + 1
            data[end:end] = data[start:end]
    return bytes(data)


def _fuzz_bytes(valid, max_size=512):
    return st.one_of(st.binary(max_size=max_size), mutations(valid))


def _check(reader, path, data):
    path.write_bytes(data)
    try:
        reader(path)
    except PrismapInputError as exc:
        assert path.name in str(exc)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def _matrix_line(name, values):
    return f"{name}: " + " ".join(f"{v:.12e}" for v in np.ravel(values)) + "\n"


P2 = np.array([[700.0, 0, 600, 42], [0, 700, 180, 0], [0, 0, 1, 0]])
P3 = np.array([[700.0, 0, 600, -336], [0, 700, 180, 0], [0, 0, 1, 0]])
VALID_CALIB = (
    _matrix_line("P0", np.c_[P2[:, :3], np.zeros(3)])
    + _matrix_line("P2", P2)
    + _matrix_line("P3", P3)
    + _matrix_line("Tr", np.c_[np.eye(3), [0.1, 0.2, 0.3]])
).encode()
VALID_POSES = b"".join(
    (" ".join(f"{v:.6e}" for v in np.c_[np.eye(3), [i, 0.1 * i, 2 * i]].ravel()) + "\n").encode() for i in range(4)
)
VALID_TRACK = b"".join(f"{10 * i}, {-5 * i}, {i}, {i}, {-2 * i}, {3 * i}\n".encode() for i in range(4))
VALID_VELODYNE = np.random.default_rng(0).normal(0, 10, size=(8, 4)).astype(np.float32).tobytes()
VALID_DISPARITY16 = cv2.imencode(".png", (np.random.default_rng(1).random((12, 16)) * 20000).astype(np.uint16))[
    1
].tobytes()
VALID_DISPARITY8 = cv2.imencode(".png", np.random.default_rng(2).integers(1, 255, (12, 16), dtype=np.uint8))[
    1
].tobytes()


def _valid_xml(workdir):
    path = workdir / "valid.xml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("depth", np.random.default_rng(3).uniform(50, 900, (3, 4)).astype(np.float32))
    storage.release()
    return path.read_bytes()


@pytest.fixture(scope="module")
def odometry_root(workdir):
    root = workdir / "kitti"
    seq = root / "sequences" / "00"
    for folder in ("image_2", "image_3"):
        (seq / folder).mkdir(parents=True)
        cv2.imwrite(str(seq / folder / "000000.png"), np.zeros((2, 3, 3), np.uint8))
    return root


@FUZZ
@given(data=_fuzz_bytes(VALID_CALIB))
def test_fuzz_kitti_calib(odometry_root, data):
    calib = odometry_root / "sequences" / "00" / "calib.txt"
    _check(read_kitti_calib, calib, data)
    try:
        KittiOdometry(odometry_root, 0)  # the camera and Velodyne transform built from the fuzzed fields
    except PrismapInputError as exc:
        assert "calib.txt" in str(exc)


@FUZZ
@given(data=_fuzz_bytes(VALID_POSES))
def test_fuzz_kitti_poses(workdir, data):
    _check(read_kitti_poses, workdir / "00.txt", data)


@FUZZ
@given(data=_fuzz_bytes(VALID_VELODYNE))
def test_fuzz_velodyne(workdir, data):
    _check(read_velodyne_bin, workdir / "000000.bin", data)


@FUZZ
@given(data=st.one_of(_fuzz_bytes(VALID_DISPARITY16), mutations(VALID_DISPARITY8)))
def test_fuzz_kitti_disparity(workdir, data):
    _check(read_kitti_disparity, workdir / "000000_10.png", data)


@FUZZ
@given(data=st.one_of(_fuzz_bytes(VALID_DISPARITY8), mutations(VALID_DISPARITY16)))
def test_fuzz_tsukuba_disparity(workdir, data):
    _check(read_tsukuba_disparity, workdir / "tsukuba_disparity_L_00001.png", data)


@FUZZ
@given(data=_fuzz_bytes(VALID_TRACK))
def test_fuzz_tsukuba_track(workdir, data):
    _check(read_tsukuba_track, workdir / "camera_track.txt", data)


@pytest.fixture(scope="module")
def valid_xml(workdir):
    return _valid_xml(workdir)


@FUZZ
@given(data=st.data())
def test_fuzz_tsukuba_depth(workdir, valid_xml, data):
    payload = data.draw(_fuzz_bytes(valid_xml))
    _check(read_tsukuba_depth, workdir / "tsukuba_depth_L_00001.xml", payload)


VALID_MIDDLEBURY_CALIB = (
    b"cam0=[3979.911 0 1244.772; 0 3979.911 1019.507; 0 0 1]\ncam1=[3979.911 0 1369.115; 0 3979.911 1019.507; 0 0 1]\n"
    b"doffs=124.343\nbaseline=193.001\nwidth=2964\nheight=1988\nndisp=270\nvmin=23\nvmax=245\n"
)
VALID_PFM = b"Pf\n4 3\n-1\n" + np.random.default_rng(4).uniform(0, 50, 12).astype("<f4").tobytes()
FEWER = settings(FUZZ, max_examples=EXAMPLES // 3)


@FEWER
@given(data=_fuzz_bytes(VALID_MIDDLEBURY_CALIB))
def test_fuzz_middlebury_calib(workdir, data):
    _check(read_middlebury_calib, workdir / "calib_middlebury.txt", data)


@FEWER
@given(data=_fuzz_bytes(VALID_PFM))
def test_fuzz_pfm(workdir, data):
    _check(read_pfm, workdir / "disp0.pfm", data)


@pytest.fixture(scope="module")
def sequence_dir(workdir):
    directory = workdir / "sequence"
    for folder in ("image_2", "image_3"):
        (directory / folder).mkdir(parents=True)
        for index in range(4):
            cv2.imwrite(str(directory / folder / f"{index:06d}.png"), np.zeros((2, 3), np.uint8))
    (directory / "calib.txt").write_bytes(VALID_CALIB)
    return directory


@FEWER
@given(calib=_fuzz_bytes(VALID_CALIB), poses=_fuzz_bytes(VALID_POSES))
def test_fuzz_sequence_calib_and_poses(sequence_dir, calib, poses):
    """``read_sequence`` reads calib.txt and poses.txt on opening; either may be the broken one."""
    (sequence_dir / "calib.txt").write_bytes(calib)
    (sequence_dir / "poses.txt").write_bytes(poses)
    try:
        read_sequence(sequence_dir)
    except PrismapInputError as exc:
        assert "calib.txt" in str(exc) or "poses.txt" in str(exc)


def test_mutations_reach_both_outcomes(workdir):
    """Not every edit is rejected: a digit changed into another digit still parses (or breaks the rotation)."""
    outcomes = set()
    path = workdir / "mutated.txt"
    rng = np.random.default_rng(0)
    digits = [i for i, byte in enumerate(VALID_POSES) if chr(byte).isdigit()]
    for _ in range(200):
        data = bytearray(VALID_POSES)
        data[rng.choice(digits)] = ord(str(rng.integers(10)))
        path.write_bytes(bytes(data))
        try:
            read_kitti_poses(path)
            outcomes.add("parsed")
        except PrismapInputError as exc:
            assert "rotation is not orthonormal" in str(exc)
            outcomes.add("rejected")
    assert outcomes == {"parsed", "rejected"}
