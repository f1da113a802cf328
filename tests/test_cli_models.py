"""``prismap models compare``: the files it writes and its errors on bad input."""

import json

import pytest

from prismap.characterise import ErrorModel, write_error_model
from prismap.cli import _main
from prismap.gmm import GaussianMixture, MixtureFit

FITS = {
    1: GaussianMixture.gaussian(3.4, -0.6),
    2: GaussianMixture([0.9, 0.1], [0.01, -5.0], [0.3, 10.0]),
    3: GaussianMixture([0.84, 0.10, 0.06], [0.01, -0.04, -10.4], [0.24, 0.92, 13.6]),
}


@pytest.fixture
def prismap(monkeypatch):
    """``prismap`` with only the ``models`` command registered (other commands are not under test)."""
    monkeypatch.setattr(_main, "COMMANDS", ("models",))
    return _main.main


@pytest.fixture(scope="module")
def error_model_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("em") / "error_model.json"
    fits = [MixtureFit(mixture, -1e5 - g, 0.0, 0.0, 1e5, 10, True) for g, mixture in FITS.items()]
    write_error_model(ErrorModel("sgbm", {}, "middlebury-motorcycle", 1 / 32, fits, 3), path)
    return path


def test_compare_writes_figures_and_tables(prismap, error_model_path, tmp_path, capsys):
    out = tmp_path / "study"
    status = prismap(
        [
            "models",
            "compare",
            "--error-model",
            str(error_model_path),
            "--out",
            str(out),
            "--distances",
            "10,2",
            "--camera",
            "kitti",
        ]
    )
    assert status == 0
    for name in ("profiles.png", "prism_sweeps.png", "influence.png", "divergence.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    record = json.loads((out / "models_compare.json").read_text())
    comparison = record["comparison"]
    assert record["camera"] == "kitti"
    assert comparison["distances_m"] == [2.0, 10.0]
    assert comparison["noise_sigma_px"] == 0.24
    assert comparison["setup"]["focal_baseline"] == pytest.approx(721.5377 * 0.5327)
    assert set(comparison["divergences"]) == {"ideal", "hitmiss", "convolution", "andert"}
    assert len(record["influence"]["measured_m"]) == 16
    tables = (out / "tables.md").read_text()
    for heading in ("## Divergence from PRISM", "## PRISM's maximum influence distance"):
        assert heading in tables
    assert "| andert | 10.00 |" in tables
    assert "wrote" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--distances", "2,x"], "--distances: expected comma-separated metres"),
        (["--distances", "2,-5"], "--distances: expected positive distances"),
        (["--camera", "kitti", "--focal-px", "700"], "either --camera or --focal-px"),
        (["--focal-px", "700"], "--focal-px and --baseline-m must be given together"),
        (["--focal-px", "700", "--baseline-m", "0"], "`--baseline-m` must be"),
        (["--p0", "1.5"], "`--p0` must lie in"),
        (["--voxel", "-0.1"], "`--voxel` must be"),
    ],
)
def test_bad_options_exit_2_with_a_message(prismap, error_model_path, tmp_path, capsys, options, message):
    status = prismap(["models", "compare", "--error-model", str(error_model_path), "--out", str(tmp_path), *options])
    assert status == 2
    err = capsys.readouterr().err
    assert err.startswith("prismap models compare: error:") and message in err
    assert not list(tmp_path.iterdir())


def test_missing_and_bad_error_model_files(prismap, tmp_path, capsys):
    missing = tmp_path / "nope.json"
    assert prismap(["models", "compare", "--error-model", str(missing), "--out", str(tmp_path / "o")]) == 2
    assert f"error model {missing}: no such file" in capsys.readouterr().err
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    assert prismap(["models", "compare", "--error-model", str(broken), "--out", str(tmp_path / "o")]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": "something-else"}))
    assert prismap(["models", "compare", "--error-model", str(other), "--out", str(tmp_path / "o")]) == 2
    assert "not a prismap error model" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_unknown_camera_is_rejected_by_the_parser(prismap, error_model_path, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        prismap(["models", "compare", "--error-model", str(error_model_path), "--out", str(tmp_path), "--camera", "x"])
    assert exc.value.code == 2
    assert "invalid choice: 'x'" in capsys.readouterr().err
