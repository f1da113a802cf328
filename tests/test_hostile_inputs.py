"""Hostile input, round two (issue 25): absurd calibrations and ground truth, and files too large to read whole.

Each case runs the real ``prismap`` in a subprocess under the address-space limit of ``test_hostile`` (3 GB)
and asserts exit 2, one line naming the file and the problem, and nothing written or left behind.
"""

import os
import shutil
import struct
import zlib

import cv2
import numpy as np
import pytest
from test_hostile import PNG_SIGNATURE, _calib, _chunk, expand, refused_line

from prismap.characterise import ErrorModel, write_error_model
from prismap.gmm import GaussianMixture, MixtureFit
from prismap.io import write_pfm
from support import CAMERA, synthetic_sequence

MAP = ["map", "--disparity-dir", "SEQ/disp", "--model", "hitmiss", "--voxel", "0.1"]
CHARACTERISE = ["characterise", "--dataset", "SEQ/mb", "--matcher", "bm", "--out", "WORK/ch"]
PRISM_MAP = [
    "map",
    "--disparity-dir",
    "SEQ/disp",
    "--model",
    "prism",
    "--error-model",
    "SEQ/em.json",
    "--voxel",
    "0.1",
    "--out",
    "WORK/o.npz",
]
SPARSE_BYTES = 3 << 30
"""A file of 3 GB that takes no disk: reading it whole exceeds the subprocess's address-space limit."""


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    seq = synthetic_sequence(tmp_path_factory.mktemp("hostile25in") / "seq", n_frames=2)
    _middlebury_folder(seq / "mb")
    return seq


def _middlebury_folder(folder, *, height=24, width=40, doffs=3.0, disparity=None):
    rng = np.random.default_rng(0)
    folder.mkdir(exist_ok=True)
    for name in ("im0.png", "im1.png"):
        cv2.imwrite(str(folder / name), rng.integers(0, 256, (height, width, 3), dtype=np.uint8))
    (folder / "calib.txt").write_text(
        f"cam0=[100.5 0 {width / 2}; 0 100.5 {height / 2}; 0 0 1]\n"
        f"cam1=[100.5 0 {width / 2 + 3}; 0 100.5 {height / 2}; 0 0 1]\n"
        f"doffs={doffs}\nbaseline=120.5\nwidth={width}\nheight={height}\nndisp=32\nvmin=2\nvmax=20\n"
    )
    if disparity is None:
        disparity = rng.uniform(2, 20, (height, width)).astype(np.float32)
    write_pfm(folder / "disp0.pfm", disparity)


def _sparse(path):
    """``path`` grown to :data:`SPARSE_BYTES` with zeros after its valid content (a sparse file)."""
    os.truncate(path, SPARSE_BYTES)


def _absurd_means(seq, mean, width=None):
    """An error model whose selected mixture has means +-``mean`` px (num_disparities 64), made on a rig of image
    ``width`` (None: not recorded, so errors within MAX_ERROR_PX; else within max(64, width) px)."""
    mixture = GaussianMixture([0.5, 0.5], [mean, -mean], [0.5, 3.0])
    rig = (
        None
        if width is None
        else {
            "focal_px": 100.0,
            "baseline_m": 0.1,
            "width": width,
            "height": 96,
            "matcher": "sgbm",
            "matcher_params": None,
        }
    )
    write_error_model(
        ErrorModel(
            "sgbm",
            {"num_disparities": 64},
            "hostile",
            1 / 32,
            [MixtureFit(mixture, -1e3, 0.0, 0.0, 1e3, 10, True)],
            2,
            rig=rig,
        ),
        seq / "em.json",
    )


def _png_of(seq, build):
    """Replace the left image of frame 1 by a PNG of valid chunk CRCs whose content ``build(width, height)``
    breaks: the chunks of a grey 8-bit image of the sequence's size."""
    path = seq / "image_2" / "000001.png"
    height, width = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).shape[:2]
    path.write_bytes(
        PNG_SIGNATURE + b"".join(_chunk(kind, body) for kind, body in build(width, height)) + _chunk(b"IEND", b"")
    )


def _ihdr(width, height, bit_depth=8):
    return b"IHDR", struct.pack(">IIBBBBB", width, height, bit_depth, 0, 0, 0, 0)


def _rows(width, height):
    return bytes(height * (1 + width))


PNG_FAULTS = {
    "bad compressed data": lambda w, h: [_ihdr(w, h), (b"IDAT", b"\x78\x9c" + bytes(range(200, 255)) * 8)],
    "too little data": lambda w, h: [_ihdr(w, h), (b"IDAT", zlib.compress(_rows(w, h)[: len(_rows(w, h)) // 2]))],
    "bit depth 7": lambda w, h: [_ihdr(w, h, 7), (b"IDAT", zlib.compress(_rows(w, h)))],
    "a second header chunk": lambda w, h: [_ihdr(w, h), _ihdr(w, h), (b"IDAT", zlib.compress(_rows(w, h)))],
}


def _frames_of_16000x8000(seq):
    """Every image a valid 16000x8000 colour PNG (under MAX_IMAGE_PIXELS), without ground truth of the old size."""
    data = cv2.imencode(".png", np.zeros((8000, 16000, 3), np.uint8))[1].tobytes()
    for image in (*seq.glob("image_2/*.png"), *seq.glob("image_3/*.png")):
        image.write_bytes(data)
    shutil.rmtree(seq / "disp")
    (seq / "occupancy.npz").unlink()


def _calib_cx(seq, cx):
    _calib(seq, CAMERA.focal_px, CAMERA.baseline_m)
    text = (seq / "calib.txt").read_text().split("\n")
    text = [" ".join([*line.split()[:3], repr(cx), *line.split()[4:]]) for line in text if line]
    (seq / "calib.txt").write_text("\n".join(text) + "\n")


# name -> (prepare(seq), argv with SEQ/WORK placeholders, expected text in the message)
CASES = {
    # item 3: absurd calibrations
    "calib.txt cx 1e300": (
        lambda s: _calib_cx(s, 1e300),
        [*MAP, "--out", "WORK/o.npz"],
        "calib.txt: `cx_px` must lie in (-1e+06, 1e+06) px",
    ),
    "Middlebury doffs -1e5": (
        lambda s: _middlebury_folder(s / "mb", doffs=-1e5),
        CHARACTERISE,
        "mb/calib.txt: `doffs_px` must be > -40 px",
    ),
    # item 2: absurd error-model means
    "error model means +-1e15 px": (
        lambda s: _absurd_means(s, 1e15),
        PRISM_MAP,
        "`means` reach 1e+15 px; an error of this rig and matcher lies within +-16384 px",
    ),
    "error model means +-1e10 px": (lambda s: _absurd_means(s, 1e10), PRISM_MAP, "`means` reach 1e+10 px"),
    "error model means +-16385 px": (lambda s: _absurd_means(s, 16385.0), PRISM_MAP, "`means` reach 16385 px"),
    "error model means beyond the rig's image width": (
        lambda s: _absurd_means(s, 129.0, width=128),
        PRISM_MAP,
        "`means` reach 129 px; an error of this rig and matcher lies within +-128 px",
    ),
    # item 16: PNGs of valid checksums but bad content (libpng printed a line of its own)
    **{
        f"PNG with {fault}": (
            lambda s, fault=fault: _png_of(s, PNG_FAULTS[fault]),
            [*MAP, "--out", "WORK/o.npz"],
            "000001.png: left image cannot be decoded (truncated or corrupt PNG",
        )
        for fault in PNG_FAULTS
    },
    # item 11: a frame under the pixel limit that the matcher cannot match in the memory budget
    "SGBM on 16000x8000": (
        _frames_of_16000x8000,
        ["map", "--matcher", "sgbm", "--model", "hitmiss", "--voxel", "0.1", "--frames", "0:1", "--out", "WORK/o.npz"],
        "sgbm: matching a 16000x8000 pair needs",
    ),
    # item 17: ground truth that cannot set the search range
    "ground truth all negative": (
        lambda s: _middlebury_folder(s / "mb", disparity=np.full((24, 40), -3.0, np.float32)),
        CHARACTERISE,
        "mb/disp0.pfm: every valid ground-truth disparity",
    ),
    # item 10: files far larger than their content needs
    "calib.txt of 3 GB": (
        lambda s: _sparse(s / "calib.txt"),
        [*MAP, "--out", "WORK/o.npz"],
        "calib.txt: KITTI calibration file holds 3221225472 bytes, more than the limit",
    ),
    "poses.txt of 3 GB": (
        lambda s: _sparse(s / "poses.txt"),
        [*MAP, "--out", "WORK/o.npz"],
        "poses.txt: pose file holds 3221225472 bytes, more than the limit",
    ),
    "disp0.pfm of 3 GB": (
        lambda s: _sparse(s / "mb" / "disp0.pfm"),
        CHARACTERISE,
        "disp0.pfm: PFM file holds 3221225472 bytes, more than the limit",
    ),
    "PNG of 3 GB": (
        lambda s: _sparse(s / "image_2" / "000001.png"),
        [*MAP, "--out", "WORK/o.npz"],
        "000001.png: left image holds 3221225472 bytes, more than the limit",
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_hostile_input_exits_2_with_one_line_and_writes_nothing(name, sequence, tmp_path):
    prepare, argv, expected = CASES[name]
    seq, work = tmp_path / "seq", tmp_path / "work"
    shutil.copytree(sequence, seq)
    work.mkdir()
    prepare(seq)
    assert expected in refused_line(expand(argv, seq, SEQ=seq, WORK=work), tmp_path, work)


def test_error_beyond_the_search_range_loads_when_the_rig_allows_it(tmp_path):
    """A near object's true disparity exceeds the search range, so a class may hold errors of 108 px on a
    620 px wide rig with num_disparities 64: characterise writes such models, and map must load them."""
    from prismap.characterise import load_error_model
    from prismap.errors import PrismapInputError

    _absurd_means(tmp_path, 108.0, width=620)
    assert load_error_model(tmp_path / "em.json").mixture.means.tolist() == [108.0, -108.0]
    _absurd_means(tmp_path, 621.0, width=620)
    with pytest.raises(PrismapInputError, match=r"`means` reach 621 px; .* within \+-620 px"):
        load_error_model(tmp_path / "em.json")
