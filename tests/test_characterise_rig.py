"""The rig check: an error model records its rig; mapping with another rig warns naming both, --strict-rig exits 2."""

import dataclasses
import json

import pytest

from prismap.camera import StereoCamera
from prismap.characterise import (
    ErrorModel,
    check_rig,
    describe_rig,
    load_error_model,
    rig_differences,
    write_error_model,
)
from prismap.cli import main
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit
from prismap.io import read_sequence
from prismap.stereo import make_matcher
from support import VOXEL, synthetic_sequence

STREET = StereoCamera(360.0, 310.0, 94.0, 0.54, width=621, height=188)


def _model(rig, dataset="somewhere"):
    fit = MixtureFit(GaussianMixture([1.0], [0.0], [0.5]), -1.0, 4.0, 5.0, 100.0, 3, True)
    return ErrorModel("sgbm", {}, dataset, 1 / 32, (fit,), 1, rig=rig)


def test_rig_differences_name_every_field_that_differs():
    sgbm = make_matcher("sgbm", num_disparities=64).params()
    mine = describe_rig(STREET, None, "sgbm", sgbm)
    assert rig_differences(mine, mine) == []
    # within 1 % is the same rig: a calibration's rounding must not warn
    close = describe_rig(dataclasses.replace(STREET, focal_px=362.0), None, "sgbm", sgbm)
    assert rig_differences(mine, close) == []
    other = describe_rig(
        StereoCamera(3979.9, 1244.8, 1019.6, 0.193, width=2964, height=1988),
        None,
        "sgbm",
        make_matcher("sgbm", num_disparities=272).params(),
    )
    found = rig_differences(other, mine)
    assert found == [
        "focal length 3979.9 px vs 360 px",
        "baseline 0.193 m vs 0.54 m",
        "image width 2964 px vs 621 px",
        "image height 1988 px vs 188 px",
        "matcher parameter num_disparities 272 vs 64",
    ]
    assert rig_differences(mine, describe_rig(STREET, None, "bm", None)) == ["matcher sgbm vs bm"]
    # unknown fields are not compared (disparities made elsewhere: no matcher)
    assert rig_differences(mine, describe_rig(STREET, None, None, None)) == []


def test_check_rig_warns_or_refuses_and_a_model_without_a_rig_is_refused_when_strict():
    here = describe_rig(STREET, None, "sgbm", None)
    model = _model(describe_rig(dataclasses.replace(STREET, baseline_m=0.12), (188, 621), "sgbm", None), "motorcycle")
    message = check_rig(model, here, strict=False, where="error model m.json")
    assert "error model m.json was made on another rig (motorcycle: f 360 px, b 0.12 m, 621x188, sgbm)" in message
    assert "this run's (f 360 px, b 0.54 m, 621x188, sgbm)" in message and "baseline 0.12 m vs 0.54 m" in message
    with pytest.raises(PrismapInputError, match=r"baseline 0.12 m vs 0.54 m \(--strict-rig\)"):
        check_rig(model, here, strict=True)
    assert check_rig(_model(here), here, strict=True) is None
    assert check_rig(_model(None), here, strict=False) is None  # an older file: silent unless strict
    with pytest.raises(PrismapInputError, match="records no rig"):
        check_rig(_model(None), here, strict=True)


def test_the_rig_survives_the_file(tmp_path):
    rig = describe_rig(STREET, None, "sgbm", make_matcher("sgbm").params())
    path = tmp_path / "m.json"
    write_error_model(_model(rig), path)
    assert load_error_model(path).rig == rig
    data = json.loads(path.read_text())
    data["rig"] = {"focal_px": "wide"}
    path.write_text(json.dumps(data))
    with pytest.raises(PrismapInputError, match="rig"):
        load_error_model(path)


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("rig") / "seq")


def _map(sequence_dir, model_path, out, *extra):
    return main(
        [
            "map",
            "--sequence",
            str(sequence_dir),
            "--voxel",
            str(VOXEL),
            "--max-range",
            "8",
            "--model",
            "convolution",
            "--matcher-param",
            "num_disparities=16",
            "--error-model",
            str(model_path),
            "--out",
            str(out),
            *extra,
        ]
    )


def test_mapping_with_a_model_of_another_rig_warns_and_strict_rig_exits_2(sequence_dir, tmp_path, capsys):
    camera = read_sequence(sequence_dir).camera
    params = make_matcher("sgbm", num_disparities=16).params()
    same, other = tmp_path / "same.json", tmp_path / "other.json"
    write_error_model(_model(describe_rig(camera, None, "sgbm", params)), same)
    write_error_model(
        _model(
            describe_rig(dataclasses.replace(camera, focal_px=2 * camera.focal_px), None, "sgbm", params),
            "middlebury-motorcycle",
        ),
        other,
    )
    assert _map(sequence_dir, same, tmp_path / "a.npz") == 0
    assert "warning" not in capsys.readouterr().err
    assert _map(sequence_dir, other, tmp_path / "b.npz") == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "prismap map: warning: --error-model" in err
    assert f"focal length {2 * camera.focal_px:g} px vs {camera.focal_px:g} px" in err
    assert (tmp_path / "b.npz").is_file()
    assert _map(sequence_dir, other, tmp_path / "c.npz", "--strict-rig") == 2
    err = capsys.readouterr().err
    assert err.startswith("prismap map: error: --error-model") and "(--strict-rig)" in err
    assert not (tmp_path / "c.npz").exists()
