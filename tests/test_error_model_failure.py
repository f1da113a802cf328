"""The error-model file and the failure component: older files load without one and map exactly as a model
built from the same Gaussians; characterisation gives every mixture one over the matcher's search range."""

import json

import numpy as np
import pytest

from prismap.camera import integrate_disparity
from prismap.characterise import characterise_matcher, load_error_model
from prismap.grid import OccupancyMap
from prismap.sensor_models import conditioned_sensor_model, failure_floor
from prismap.stereo import make_matcher, search_range
from support import planes_frame

FIT_FIELDS = {
    "log_likelihood": -100.0,
    "aic": 210.0,
    "bic": 215.0,
    "n_samples": 1000.0,
    "n_iter": 12,
    "converged": True,
}
WEIGHTS, MEANS, SIGMAS = [0.9, 0.1], [0.02, -0.3], [0.35, 4.0]


def _version_2_file(path):
    """A version-2 file as main wrote it before the failure component: a plain model of one class."""
    entry = {"n_components": 2, "weights": WEIGHTS, "means": MEANS, "sigmas": SIGMAS, **FIT_FIELDS}
    data = {
        "format": "prismap-error-model",
        "format_version": 2,
        "matcher": {"name": "sgbm", "params": {}},
        "dataset": "test",
        "bin_width_px": 0.03125,
        "statistics": {},
        "selection": {"criterion": "bic"},
        "selected_components": 2,
        "models": [entry],
        "features": {"names": []},
        "classes": [{"bounds": {}, "share": 1.0, "selected_components": 2, "models": [entry]}],
    }
    path.write_text(json.dumps(data))
    return path


def test_a_version_2_file_has_no_failure_component_and_maps_as_its_gaussians(tmp_path):
    from prismap.gmm import GaussianMixture

    model = load_error_model(_version_2_file(tmp_path / "old.json"))
    assert model.mixture.failure_weight == 0.0 and model.mixture.search_range_px is None
    assert failure_floor(model.mixture) == 0.0
    camera, pose, depth = planes_frame(width=48, height=36)
    disparity = np.round(camera.focal_baseline / depth * 16) / 16
    maps = []
    for error_model in (model, GaussianMixture(WEIGHTS, MEANS, SIGMAS)):
        for name in ("prism", "andert"):
            sensor = conditioned_sensor_model(
                name,
                camera,
                voxel_size_m=0.2,
                p0=0.05,
                error_model=error_model,
                **({"near_m": 1.0, "far_depth_m": 40.0} if name == "prism" else {}),
            )
            grid = OccupancyMap(0.2, p0=0.05)
            integrate_disparity(grid, disparity, camera, pose, sensor, mode="projective", max_range_m=20.0)
            maps.append(grid.known_voxels())
    for old, new in zip(maps[:2], maps[2:]):
        np.testing.assert_array_equal(old[0], new[0])
        np.testing.assert_array_equal(old[1], new[1])  # the same fixed-point log-odds, bit for bit


def test_search_range_comes_from_the_matcher_parameters():
    assert make_matcher("sgbm", min_disparity=4, num_disparities=48).search_range_px() == (4.0, 52.0)
    assert make_matcher("variational", min_disparity=2.0, max_disparity=40.0).search_range_px() == (2.0, 40.0)
    assert search_range({"block_size": 5}) is None


def test_characterisation_gives_every_mixture_a_failure_component():
    from prismap.io import load_middlebury_motorcycle

    frame = load_middlebury_motorcycle()
    rows = slice(150, 250)
    small = type(frame)(
        frame.left[rows],
        frame.right[rows],
        frame.camera,
        disparity_gt=frame.disparity_gt[rows],
        name="motorcycle rows 150-250",
    )
    matcher = make_matcher("sgbm", num_disparities=96, left_right_check=True)
    result = characterise_matcher(
        [small], matcher, dataset="motorcycle", progress=False, max_components=3, max_classes=4
    )
    model = result.model
    for mixture in (model.mixture, *model.class_mixtures):
        assert mixture.search_range_px == (0.0, 96.0)
        n = model.statistics["n_errors"] if mixture is model.mixture else None
        assert mixture.failure_weight > (1.0 / (n + 1) if n else 0.0)
    assert all(class_model.outlier is None for class_model in model.class_models)
    plain = characterise_matcher(
        [small], matcher, dataset="motorcycle", progress=False, max_components=3, max_classes=4, failures=False
    )
    assert plain.model.mixture.failure_weight == 0.0 and plain.model.mixture.search_range_px is None
    assert model.fit(3).n_parameters == plain.model.fit(3).n_parameters + 1


@pytest.mark.parametrize("failures", [True, False])
def test_written_model_round_trips_its_failure_component(tmp_path, failures):
    from prismap.characterise import write_error_model
    from prismap.io import load_middlebury_motorcycle

    frame = load_middlebury_motorcycle()
    rows = slice(200, 240)
    small = type(frame)(frame.left[rows], frame.right[rows], frame.camera, disparity_gt=frame.disparity_gt[rows])
    result = characterise_matcher(
        [small],
        make_matcher("bm", num_disparities=96),
        progress=False,
        conditioned=False,
        max_components=2,
        failures=failures,
    )
    write_error_model(result.model, tmp_path / "model.json")
    loaded = load_error_model(tmp_path / "model.json")
    assert loaded.mixture.failure_weight == result.model.mixture.failure_weight
    assert loaded.mixture.search_range_px == result.model.mixture.search_range_px


def test_a_version_2_file_with_a_failure_component_is_refused_and_version_3_names_it(tmp_path):
    from prismap.characterise import format_table, write_error_model
    from prismap.errors import PrismapInputError

    path = _version_2_file(tmp_path / "old.json")
    data = json.loads(path.read_text())
    data["models"][0].update(failure_weight=0.01, search_range_px=[0.0, 64.0])
    path.write_text(json.dumps(data))
    with pytest.raises(PrismapInputError, match="needs format_version 3; this file says 2"):
        load_error_model(path)
    data["format_version"] = 3
    data["classes"][0]["models"][0].update(failure_weight=0.02, search_range_px=[0.0, 64.0])
    path.write_text(json.dumps(data))
    model = load_error_model(path)
    assert model.mixture.failure_weight == 0.01 and model.class_mixtures[0].failure_weight == 0.02
    write_error_model(model, tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text())["format_version"] == 3
    table = format_table(model)
    assert "0..64 px (W = 64 px)" in table and "| w_f |" in table and "1.0e-02" in table
