"""``prismap characterise`` end to end: Motorcycle with SGBM, and clear errors for unusable input."""

import itertools
import json

import cv2
import numpy as np
import pytest

from prismap.characterise import load_error_model
from prismap.cli import main
from prismap.io import write_pfm


@pytest.fixture(scope="module")
def motorcycle_sgbm(tmp_path_factory):
    out = tmp_path_factory.mktemp("motorcycle_sgbm")
    # bound 12, not the default 24: the search's cost is its class fits, whatever the pixels (half of it here)
    status = main(
        [
            "characterise",
            "--dataset",
            "middlebury-motorcycle",
            "--matcher",
            "sgbm",
            "--max-components",
            "4",
            "--max-classes",
            "12",
            "--out",
            str(out),
        ]
    )
    return status, out


def test_cli_writes_the_model_table_and_figures(motorcycle_sgbm):
    status, out = motorcycle_sgbm
    assert status == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "error_model.json",
        "errors.png",
        "errors_classes.png",
        "errors_wide.png",
        "table.md",
    ]
    for name in ("errors.png", "errors_classes.png", "errors_wide.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    data = json.loads((out / "error_model.json").read_text())
    assert [m["n_components"] for m in data["models"]] == [1, 2, 3, 4]
    assert data["matcher"]["name"] == "sgbm" and data["dataset"] == "middlebury-motorcycle"
    assert data["matcher"]["params"]["num_disparities"] % 16 == 0
    table = (out / "table.md").read_text()
    assert f"| {data['selected_components']}* |" in table
    assert "## Error classes" in table and len(data["classes"]) >= 2


def test_conditioned_model_of_sgbm_on_motorcycle_predicts_held_out_errors_better(motorcycle_sgbm):
    # The errors crowd at the depth edges of the computed disparity (issue 10): conditioning must win, and the
    # pixels of the classes nearest an edge must err far more often than those farthest from one.
    _, out = motorcycle_sgbm
    model = load_error_model(out / "error_model.json")
    record = model.class_selection
    assert model.conditioned and record["held_out"] == "two folds: left / right image halves (one frame)"
    assert record["conditioned_nats_per_error"] > record["plain_nats_per_error"] + 0.03
    assert "edge_distance_px" in model.classes.features
    column = list(model.classes.features).index("edge_distance_px")
    nearest = [k for k in range(model.n_classes) if model.classes.lower[k, column] == -np.inf]
    farthest = [k for k in range(model.n_classes) if model.classes.upper[k, column] == np.inf]
    bad = np.array([model.class_models[k].statistics["bad_2px"] for k in range(model.n_classes)])
    share = np.array([model.class_models[k].share for k in range(model.n_classes)])
    rate = {name: share[ks] @ bad[ks] / share[ks].sum() for name, ks in (("nearest", nearest), ("farthest", farthest))}
    assert rate["nearest"] > 3 * rate["farthest"]


def test_sgbm_on_motorcycle_has_a_sub_pixel_core_and_a_wide_outlier_component(motorcycle_sgbm):
    _, out = motorcycle_sgbm
    model = load_error_model(out / "error_model.json")
    mixture = model.mixture
    assert model.selected_components >= 2
    assert mixture.weights[0] > 0.6  # components are stored heaviest first
    assert mixture.sigmas[0] < 1.0 and abs(mixture.means[0]) < 0.2
    wide = mixture.sigmas > 5.0
    assert wide.any() and 0.01 < mixture.weights[wide].sum() < 0.2
    assert model.statistics["coverage"] > 0.7
    # more components fit at least as well; with one Gaussian the failure component takes the heavy tails
    lls = [fit.log_likelihood for fit in model.fits]
    assert all(b >= a - 1e-6 * abs(a) for a, b in itertools.pairwise(lls))
    assert model.fit(2).mean_log_likelihood - model.fit(1).mean_log_likelihood > 0.02
    assert model.fit(1).mixture.failure_weight > 0.01 and mixture.search_range_px == (0.0, 64.0)


def _middlebury_folder(path, *, image, disparity):
    path.mkdir()
    height, width = disparity.shape
    cv2.imwrite(str(path / "im0.png"), image)
    cv2.imwrite(str(path / "im1.png"), image)
    write_pfm(path / "disp0.pfm", disparity)
    (path / "calib.txt").write_text(
        f"cam0=[500 0 {width / 2}; 0 500 {height / 2}; 0 0 1]\ncam1=[500 0 {width / 2}; 0 500 {height / 2}; 0 0 1]\n"
        f"doffs=0\nbaseline=100\nwidth={width}\nheight={height}\nndisp=32\n"
    )
    return path


def _run_failing(capsys, argv):
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2
    assert "Traceback" not in err
    return err


def test_a_missing_dataset_path_is_a_clear_error(capsys, tmp_path):
    err = _run_failing(
        capsys,
        ["characterise", "--dataset", str(tmp_path / "nowhere"), "--matcher", "bm", "--out", str(tmp_path / "out")],
    )
    assert "no such file or directory" in err and "nowhere" in err
    assert not (tmp_path / "out").exists()


def test_a_matcher_output_without_valid_pixels_is_a_clear_error(capsys, tmp_path):
    flat = np.full((64, 96, 3), 128, np.uint8)  # no texture: block matching finds nothing
    folder = _middlebury_folder(tmp_path / "flat", image=flat, disparity=np.full((64, 96), 10, np.float32))
    err = _run_failing(
        capsys, ["characterise", "--dataset", str(folder), "--matcher", "bm", "--out", str(tmp_path / "out")]
    )
    assert "computed disparity has no valid pixel" in err and "flat" in err


def test_ground_truth_without_valid_pixels_is_a_clear_error(capsys, tmp_path):
    texture = np.random.default_rng(0).integers(0, 256, (64, 96, 3)).astype(np.uint8)
    folder = _middlebury_folder(tmp_path / "nogt", image=texture, disparity=np.full((64, 96), np.inf, np.float32))
    err = _run_failing(
        capsys, ["characterise", "--dataset", str(folder), "--matcher", "sgbm", "--out", str(tmp_path / "out")]
    )
    assert "no valid ground-truth disparity" in err


def test_bad_options_are_clear_errors(capsys, tmp_path):
    err = _run_failing(
        capsys,
        [
            "characterise",
            "--dataset",
            "middlebury-motorcycle",
            "--matcher",
            "sgbm",
            "--bin-width",
            "0",
            "--out",
            str(tmp_path / "out"),
        ],
    )
    assert "--bin-width" in err
    err = _run_failing(
        capsys,
        [
            "characterise",
            "--dataset",
            "middlebury-motorcycle",
            "--matcher",
            "sgbm",
            "--max-components",
            "0",
            "--out",
            str(tmp_path / "out"),
        ],
    )
    assert "--max-components" in err
    err = _run_failing(
        capsys,
        [
            "characterise",
            "--dataset",
            "middlebury-motorcycle",
            "--matcher",
            "sgbm",
            "--max-classes",
            "0",
            "--out",
            str(tmp_path / "out"),
        ],
    )
    assert "--max-classes" in err
    for option in ("--search-frames", "--max-samples"):
        err = _run_failing(
            capsys,
            [
                "characterise",
                "--dataset",
                "middlebury-motorcycle",
                "--matcher",
                "sgbm",
                option,
                "0",
                "--out",
                str(tmp_path / "out"),
            ],
        )
        assert f"`{option}` must be >= 1; got 0" in err


def test_plain_option_writes_one_class(tmp_path):
    texture = np.random.default_rng(1).integers(0, 256, (64, 128, 3)).astype(np.uint8)
    folder = _middlebury_folder(tmp_path / "tex", image=texture, disparity=np.full((64, 128), 10, np.float32))
    assert (
        main(
            [
                "characterise",
                "--dataset",
                str(folder),
                "--matcher",
                "sgbm",
                "--plain",
                "--max-components",
                "1",
                "--out",
                str(tmp_path / "out"),
            ]
        )
        == 0
    )
    model = load_error_model(tmp_path / "out" / "error_model.json")
    assert not model.conditioned and model.n_classes == 1 and not model.class_selection
    assert not (tmp_path / "out" / "errors_classes.png").exists()
