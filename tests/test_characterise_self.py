"""Self-characterisation: a matcher's error model from a posed sequence without ground truth recovers the errors
it was given, and errors that repeat in nearby frames do not make it look better than it is."""

import json

import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.characterise import lag_agreement, load_error_model, self_characterise, write_characterisation
from prismap.characterise._self import carried_disparity, choose_min_lag, median_variance, reference_frames
from prismap.errors import PrismapInputError
from prismap.io import StereoFrame
from prismap.stereo import StereoMatcher

CAMERA = StereoCamera(72.0, 47.5, 35.5, 0.5, width=96, height=72)
NORMAL, PLANE_H = np.array([-0.1, -0.15, 1.0]), 10.0
"""A tilted plane ``n . P = h`` (world frame, metres) about 10 m in front of the drive."""
STEP_M = 0.25
"""Sideways step between frames (about 1.8 px of image motion)."""
SIGMA_PX = 0.3


def _pose(k):
    pose = np.eye(4)
    pose[0, 3] = k * STEP_M
    return pose


def _truth(k):
    """Exact disparity of frame ``k`` (pixels)."""
    rays = CAMERA.pixel_rays()
    depth = (PLANE_H - NORMAL @ _pose(k)[:3, 3]) / (rays @ NORMAL)
    return CAMERA.disparity_from_depth(depth)


def _world_xy(k):
    """World (x, y) of the surface point each pixel of frame ``k`` sees, metres."""
    depth = CAMERA.depth_from_disparity(_truth(k))
    points = CAMERA.pixel_rays() * depth[..., None]
    return points[..., 0] + _pose(k)[0, 3], points[..., 1]


class ScriptedMatcher(StereoMatcher):
    """Frame ``k`` (its left image is all ``k``) gets its exact disparity minus ``errors(k)``: deterministic."""

    name = "scripted"

    def __init__(self, errors):
        self.errors = errors

    def compute(self, left, right):
        k = int(left[0, 0])
        return (_truth(k) - self.errors(k)).astype(np.float32)

    def params(self):
        return {}


def _frames(n):
    return [
        StereoFrame(
            np.full((CAMERA.height, CAMERA.width), k, np.uint8),
            np.full((CAMERA.height, CAMERA.width), k, np.uint8),
            CAMERA,
            None,
            _pose(k),
            f"f{k}",
        )
        for k in range(n)
    ]


def _independent(k):
    return np.random.default_rng(100 + k).normal(0.0, SIGMA_PX, (CAMERA.height, CAMERA.width))


def _repeating(k, block=3, cell_m=0.3):
    """Errors fixed to the surface for frames of one block of ``block`` frames, independent between blocks."""
    x, y = _world_xy(k)
    field = np.random.default_rng(k // block).normal(0.0, SIGMA_PX, (200, 200))
    return field[np.floor(y / cell_m).astype(int) + 100, np.floor(x / cell_m).astype(int) + 100]


def _core_sigma(model):
    return model.mixture.dominant_sigma()


def test_carried_disparity_is_exact_between_true_frames():
    shape = (CAMERA.height, CAMERA.width)
    carried = carried_disparity(_truth(3), _pose(3), _pose(0), CAMERA, shape, near_m=5.0)
    ok = np.isfinite(carried)
    assert ok.mean() > 0.8  # the frame 0.75 m to the right sees most of frame 0's view beyond 5 m
    np.testing.assert_allclose(carried[ok], _truth(0)[ok], atol=1e-6)
    # space nearer than near_m must be seen free too: near the camera frame 3 sees little of frame 0's rays
    assert np.isfinite(carried_disparity(_truth(3), _pose(3), _pose(0), CAMERA, shape)).mean() < 0.6


def test_independent_errors_are_recovered_with_the_reference_noise_removed():
    result = self_characterise(
        _frames(10), ScriptedMatcher(_independent), max_components=1, conditioned=False, progress=False
    )
    record = result.record
    assert record["min_lag"] >= 1
    # a carried value is an affine fit over about 9 points of the other frame: smoother than one error
    assert 0.2 * SIGMA_PX < record["carried_sigma_px"] < 0.6 * SIGMA_PX
    model = result.characterisation.model
    fitted = result.characterisation.histogram  # errors against the references: wider than one frame's
    assert fitted.statistics()["n_errors"] > 20_000
    assert _core_sigma(model) == pytest.approx(SIGMA_PX, rel=0.06)
    assert record["reference_variance_px2"] == pytest.approx(
        median_variance(round(record["mean_references"])) * record["carried_sigma_px"] ** 2, rel=0.3
    )


def test_repeating_errors_push_the_references_away_and_keep_the_model_honest():
    frames = _frames(12)
    matcher = ScriptedMatcher(_repeating)
    disparities = [matcher.compute(f.left, f.right).astype(float) for f in frames]
    agreement = lag_agreement(frames, disparities, CAMERA, max_lag=4)
    sigmas = [row["core_sigma_px"] for row in agreement]
    assert sigmas[0] < 0.8 * sigmas[2]  # neighbours share most errors: their differences are small
    honest = self_characterise(frames, matcher, max_lag=4, max_components=1, conditioned=False, progress=False)
    assert honest.record["min_lag"] >= 3
    near = self_characterise(frames, matcher, min_lag=1, max_components=1, conditioned=False, progress=False)
    honest_sigma, near_sigma = _core_sigma(honest.characterisation.model), _core_sigma(near.characterisation.model)
    assert honest_sigma == pytest.approx(SIGMA_PX, rel=0.15)
    assert near_sigma < 0.85 * honest_sigma  # references from the next frames would make the matcher look better


def test_the_written_model_says_how_it_was_made(tmp_path):
    result = self_characterise(
        _frames(6),
        ScriptedMatcher(_independent),
        min_lag=1,
        max_components=1,
        conditioned=False,
        progress=False,
        dataset="scripted drive",
    )
    write_characterisation(result.characterisation, tmp_path)
    data = json.loads((tmp_path / "error_model.json").read_text())
    assert data["source"] == "self"
    assert data["provenance"]["min_lag"] == 1
    model = load_error_model(tmp_path / "error_model.json")
    assert model.source == "self"
    assert model.rig["focal_px"] == CAMERA.focal_px and model.rig["width"] == CAMERA.width


def test_too_little_shared_surface_is_refused():
    rows = [{"lag": 1, "n_pixels": 10, "core_sigma_px": 0.3, "gross_rate": 0.1}]
    with pytest.raises(PrismapInputError, match="share too little surface"):
        choose_min_lag(rows)


def test_reference_frames_and_median_variance():
    assert reference_frames(5, 12, 3, 4) == [2, 8, 1, 9]
    assert reference_frames(0, 12, 2, 3) == [2, 3, 4]
    assert median_variance(1) == pytest.approx(1.0, rel=0.01)
    assert median_variance(3) == pytest.approx(0.449, rel=0.02)  # order statistics of three normals


def test_bad_input_is_refused():
    frames = _frames(4)
    unposed = [StereoFrame(f.left, f.right, CAMERA, None, None, f.name) for f in frames]
    with pytest.raises(PrismapInputError, match="has no pose"):
        self_characterise(unposed, ScriptedMatcher(_independent), progress=False)
    with pytest.raises(PrismapInputError, match="at least 2 posed frames"):
        self_characterise(frames[:1], ScriptedMatcher(_independent), progress=False)
    with pytest.raises(PrismapInputError, match="min_lag"):
        self_characterise(frames, ScriptedMatcher(_independent), min_lag=9, progress=False)


def test_cli_self_characterises_a_sequence_and_refuses_one_without_poses(tmp_path, capsys):
    from prismap import sim
    from prismap.cli import main
    from prismap.io import write_sequence

    # a textured wall 2 m ahead, the camera stepping 5 cm sideways (1.8 px) per frame
    wall = sim.Scene3D.from_boxes([[-5.0, -5.0, 2.0]], [[5.0, 5.0, 2.5]], texel_m=0.005)
    frames = list(wall.frames(CAMERA, np.stack([_pose(k / 5) for k in range(6)]), seed=0))
    sequence = write_sequence(frames, tmp_path / "seq") and tmp_path / "seq"
    out = tmp_path / "model"
    argv = [
        "characterise",
        "--self",
        "--sequence",
        str(sequence),
        "--matcher",
        "sgbm",
        "--plain",
        "--max-disparity",
        "15",
        "--max-components",
        "2",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "self-characterised from 6 frames" in printed and "reference noise" in printed
    model = load_error_model(out / "error_model.json")
    assert model.source == "self" and model.provenance["n_frames"] == 6
    assert model.rig["matcher_params"]["num_disparities"] == 16 and model.rig["width"] == CAMERA.width
    (sequence / "poses.txt").unlink()
    assert main(argv[:-1] + [str(tmp_path / "other")]) == 2
    assert "no poses.txt" in capsys.readouterr().err
    assert not (tmp_path / "other" / "error_model.json").exists()
    assert (
        main(
            [
                "characterise",
                "--self",
                "--dataset",
                "middlebury-motorcycle",
                "--sequence",
                str(sequence),
                "--matcher",
                "bm",
                "--out",
                str(tmp_path / "third"),
            ]
        )
        == 2
    )
    assert "--self uses no ground truth" in capsys.readouterr().err
