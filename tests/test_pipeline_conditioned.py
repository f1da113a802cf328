"""Conditioned error models through the pipeline: each pixel's class reaches the grid, the map equals one built
by hand class by class, plain stays one flag away, fingerprints see the classes, unusable models are refused."""

import numpy as np
import pytest

from prismap.camera import integrate_disparity
from prismap.characterise import compute_features
from prismap.errors import PrismapInputError
from prismap.grid import OccupancyMap
from prismap.io import read_sequence
from prismap.pipeline import DisparitySource, map_sequence, open_checkpoint, run_fingerprint
from prismap.sensor_models import ConditionedModel, conditioned_sensor_model
from prismap.stereo import make_matcher
from prismap.stereo._base import to_grey
from support import MIXTURE, assert_same_map, conditioned_error_model, config, synthetic_sequence

MODEL = conditioned_error_model(feature="texture", edges=(20.0, 30.0))  # every class on every frame


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("conditioned") / "seq", n_frames=4)


def hand_map(sequence_dir, cfg, disparity_of):
    """The reference: features, classes and integrate_disparity called frame by frame with the conditioned model."""
    sequence = read_sequence(sequence_dir)
    model = conditioned_sensor_model(
        cfg.model, sequence.camera, voxel_size_m=cfg.voxel_size_m, p0=cfg.p0, error_model=MODEL
    )
    grid = OccupancyMap(cfg.voxel_size_m, p0=cfg.p0)
    for frame in sequence:
        disparity = disparity_of(frame)
        features = compute_features(to_grey(frame.left), to_grey(frame.right), disparity)
        classes = MODEL.classes.assign(features.values, np.isfinite(disparity))
        integrate_disparity(
            grid,
            disparity,
            sequence.camera,
            frame.T_world_cam,
            model,
            mode=cfg.mode,
            max_range_m=cfg.max_range_m,
            ray_class=classes,
        )
    return grid


@pytest.mark.parametrize("name", ["prism", "andert"])
def test_a_conditioned_map_equals_the_map_built_class_by_class(sequence_dir, name):
    cfg = config(model=name, error_model=MODEL)
    assert cfg.conditioned  # the default with a model of several classes
    assert_same_map(
        map_sequence(sequence_dir, cfg, progress=False), hand_map(sequence_dir, cfg, lambda f: f.disparity_gt)
    )


def test_a_conditioned_map_from_the_matcher_equals_the_hand_map(sequence_dir):
    cfg = config(model="prism", error_model=MODEL, disparity_source="matcher")
    matcher = make_matcher("sgbm", num_disparities=16)
    by_hand = hand_map(sequence_dir, cfg, lambda f: matcher.compute(f.left, f.right))
    assert_same_map(map_sequence(sequence_dir, cfg, progress=False), by_hand)


def test_every_class_is_used_and_the_classes_change_the_map(sequence_dir):
    sequence = read_sequence(sequence_dir)
    disparity, _, ray_class = DisparitySource(sequence, config(model="prism", error_model=MODEL))(0)
    valid = np.isfinite(disparity)
    assert set(np.unique(ray_class[valid])) == {0, 1, 2} and (ray_class[~valid] == -1).all()
    conditioned = map_sequence(sequence_dir, config(model="prism", error_model=MODEL), progress=False)
    plain = map_sequence(sequence_dir, config(model="prism", error_model=MODEL, conditioned=False), progress=False)
    mixture_only = map_sequence(sequence_dir, config(model="prism", error_model=MIXTURE), progress=False)
    assert_same_map(plain, mixture_only)  # plain = today's map of the whole-image mixture
    keys = conditioned.known_voxels()[0]
    changed = np.abs(conditioned.probability_at_keys(keys) - plain.probability_at_keys(keys)) > 0.01
    assert changed.mean() > 0.05


def test_models_that_ignore_the_error_model_are_unchanged(sequence_dir):
    cfg = config(model="hitmiss", error_model=MODEL)
    assert not isinstance(cfg.sensor_model(read_sequence(sequence_dir).camera), ConditionedModel)
    assert DisparitySource(read_sequence(sequence_dir), cfg)(0)[2] is None  # no features computed
    assert_same_map(
        map_sequence(sequence_dir, cfg, progress=False),
        map_sequence(sequence_dir, config(model="hitmiss", error_model=None), progress=False),
    )


def test_the_fingerprint_covers_the_classes_and_the_flag(sequence_dir):
    sequence = read_sequence(sequence_dir)
    conditioned = config(model="prism", error_model=MODEL)
    plain = config(model="prism", error_model=MODEL, conditioned=False)
    other_classes = config(model="prism", error_model=conditioned_error_model(feature="texture", edges=(22.0, 30.0)))
    prints = {run_fingerprint(sequence, c) for c in (conditioned, plain, other_classes)}
    assert len(prints) == 3
    assert plain == config(model="prism", error_model=MIXTURE)  # a plain run only depends on the mixture
    assert conditioned.to_dict()["conditioned"] is True and plain.to_dict()["conditioned"] is False
    assert conditioned.to_dict()["error_model"]["classes"][1]["bounds"] == {"texture": [20.0, 30.0]}


def test_a_checkpoint_of_the_plain_run_is_refused_by_the_conditioned_run(sequence_dir, tmp_path):
    checkpoint = tmp_path / "run.checkpoint.npz"
    plain = config(model="prism", error_model=MODEL, conditioned=False)
    open_checkpoint(checkpoint, run_fingerprint(read_sequence(sequence_dir), plain))
    with pytest.raises(PrismapInputError, match="another configuration"):
        map_sequence(sequence_dir, config(model="prism", error_model=MODEL), progress=False, checkpoint=checkpoint)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        (
            {"error_model": conditioned_error_model(matcher="bm"), "disparity_source": "matcher"},
            "fitted to matcher 'bm'; this run uses 'sgbm'",
        ),
        (
            {
                "error_model": conditioned_error_model(feature="lr_disagreement_px", edges=(0.5, 1.0)),
                "disparity_source": "matcher",
            },
            "lr_disagreement_px, which needs the matcher's left-right check",
        ),
        (
            {"error_model": conditioned_error_model(feature="lr_disagreement_px", edges=(0.5, 1.0))},
            "lr_disagreement_px, which needs the matcher's left-right check",
        ),  # precomputed disparities have none
    ],
)
def test_a_model_whose_features_the_run_cannot_compute_is_refused_before_any_work(
    sequence_dir, tmp_path, monkeypatch, changes, message
):
    def no_frame(self, index):
        raise AssertionError("a frame was read")

    monkeypatch.setattr(DisparitySource, "__call__", no_frame)
    checkpoint = tmp_path / "run.checkpoint.npz"
    with pytest.raises(PrismapInputError, match=message):
        map_sequence(sequence_dir, config(model="prism", **changes), progress=False, checkpoint=checkpoint)
    assert list(tmp_path.iterdir()) == []  # not even the checkpoint's fingerprint


def test_the_lr_feature_works_with_the_left_right_check(sequence_dir):
    model = conditioned_error_model(feature="lr_disagreement_px", edges=(0.25, 0.75))
    cfg = config(
        model="andert",
        error_model=model,
        disparity_source="matcher",
        matcher_params={"num_disparities": 16, "left_right_check": True},
    )
    disparity, _, ray_class = DisparitySource(read_sequence(sequence_dir), cfg)(1)
    matcher = make_matcher("sgbm", num_disparities=16, left_right_check=True)
    frame = read_sequence(sequence_dir)[1]
    _, lr = matcher.compute_with_confidence(frame.left, frame.right)
    expected = np.where(np.isfinite(disparity), np.digitize(lr, [0.25, 0.75]), -1)
    np.testing.assert_array_equal(ray_class, expected)


def test_bad_conditioned_flags_are_named():
    with pytest.raises(PrismapInputError, match="`conditioned` needs an error model with more than one class"):
        config(model="prism", error_model=MIXTURE, conditioned=True)
    with pytest.raises(PrismapInputError, match="`conditioned` must be True, False or None; got 'yes'"):
        config(model="prism", error_model=MODEL, conditioned="yes")
    with pytest.raises(PrismapInputError, match="`error_model` must be an ErrorModel, a GaussianMixture or None"):
        config(model="prism", error_model={"weights": [1.0]})
