"""``prismap characterise --dataset`` on a small KITTI stereo folder end to end, and one clear error per bad
dataset or selection, with nothing written."""

import json

import numpy as np
import pytest

from prismap.cli import main
from prismap.io import write_disparity_png
from support import shifted_pair, write_kitti_stereo


@pytest.fixture(scope="module")
def kitti_2015(tmp_path_factory):
    rng = np.random.default_rng(11)
    pairs = [shifted_pair(rng, 48, 80, d) for d in (3, 9, 6, 12)]
    return write_kitti_stereo(tmp_path_factory.mktemp("kitti") / "training", pairs, year=2015)


def test_characterise_a_kitti_stereo_selection_with_sgbm(kitti_2015, tmp_path, capsys):
    out = tmp_path / "out"
    status = main(
        [
            "characterise",
            "--dataset",
            str(kitti_2015),
            "--frames",
            "0:4",
            "--every",
            "2",
            "--matcher",
            "sgbm",
            "--max-components",
            "2",
            "--plain",
            "--out",
            str(out),
        ]
    )
    assert status == 0, capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["error_model.json", "errors.png", "errors_wide.png", "table.md"]
    model = json.loads((out / "error_model.json").read_text())
    assert model["dataset"] == str(kitti_2015)
    statistics = model["statistics"]
    assert statistics["n_frames"] == 2  # frames 0 and 2: disparities 3 and 6 px
    assert statistics["n_gt_valid"] == 48 * (80 - 3) + 48 * (80 - 6)
    assert model["matcher"]["params"]["num_disparities"] == 16  # 16 * ceil((6 + 1) / 16), from the ground truth alone
    assert statistics["coverage"] > 0.5 and statistics["mean_abs_error_px"] < 1.0  # whole-pixel shifts SGBM finds


def _fails(capsys, argv, message, out):
    status = main(["characterise", *argv, "--matcher", "sgbm", "--out", str(out)])
    err = capsys.readouterr().err
    assert status == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert message in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--every", "0"], "`every` must be an integer >= 1; got 0"),
        (["--frames", "2:2"], "`frames` 2:2 selects no frame of the 4 frames"),
        (["--frames", "0:40"], "40 lies outside the 4 frames"),
    ],
)
def test_bad_selections_exit_2_and_write_nothing(kitti_2015, tmp_path, capsys, extra, message):
    _fails(capsys, ["--dataset", str(kitti_2015), *extra], message, tmp_path / "out")


def test_bad_datasets_exit_2_and_write_nothing(tmp_path, capsys):
    rng = np.random.default_rng(0)
    testing = write_kitti_stereo(tmp_path / "testing", [shifted_pair(rng, 16, 24, 2)], year=2015, disparities=())
    _fails(
        capsys, ["--dataset", str(testing)], "folder without ground-truth disparities: no disp_noc_0/", tmp_path / "out"
    )
    training = write_kitti_stereo(tmp_path / "training", [shifted_pair(rng, 16, 24, 2)] * 2, year=2015)
    write_disparity_png(training / "disp_noc_0" / "000001_10.png", np.ones((16, 20)), "disparity")
    _fails(
        capsys,
        ["--dataset", str(training)],
        "disparity size (16, 20) differs from the left image's (16, 24)",
        tmp_path / "out",
    )
    (tmp_path / "holiday").mkdir()
    _fails(
        capsys, ["--dataset", str(tmp_path / "holiday")], "no dataset layout recognised; looked for", tmp_path / "out"
    )


def test_an_unusable_out_is_refused_before_any_work(kitti_2015, tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    _fails(capsys, ["--dataset", str(kitti_2015)], "file is not a directory", tmp_path / "file" / "out")
    status = main(["characterise", "--dataset", str(kitti_2015), "--matcher", "sgbm", "--out", str(tmp_path / "file")])
    assert status == 2 and "exists and is not a directory" in capsys.readouterr().err
    assert (tmp_path / "file").read_text() == "x"


def test_the_search_range_stays_below_the_image_width(tmp_path, capsys):
    """A true disparity of 37 px on 40 px wide images asks for 48 px of search: it runs with 32 (the last multiple
    of 16 below the width) instead of failing in the matcher; images at most 16 px wide are refused up front."""
    rng = np.random.default_rng(3)
    left, right, truth = shifted_pair(rng, 24, 40, 30)
    truth[5, 38] = 37.0
    wide = write_kitti_stereo(tmp_path / "wide", [(left, right, truth)], year=2015)
    out = tmp_path / "out"
    status = main(
        [
            "characterise",
            "--dataset",
            str(wide),
            "--matcher",
            "sgbm",
            "--max-components",
            "1",
            "--plain",
            "--out",
            str(out),
        ]
    )
    assert status == 0, capsys.readouterr().err
    assert json.loads((out / "error_model.json").read_text())["matcher"]["params"]["num_disparities"] == 32
    narrow = write_kitti_stereo(tmp_path / "narrow", [shifted_pair(rng, 16, 16, 2)], year=2015)
    _fails(
        capsys,
        ["--dataset", str(narrow)],
        "--dataset: images 16 px wide leave no disparity search range",
        tmp_path / "out2",
    )
