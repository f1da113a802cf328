"""The error model's fusion block: fitted from consecutive frames' errors, written and read back."""

import numpy as np
import pytest
from test_characterise_correlation import CAMERA, _frames, _world_x

from prismap.characterise._fusion import MIN_PAIRS, fit_fusion, fusion_block, fusion_from_block, path_order
from prismap.errors import PrismapInputError
from prismap.grid import PersistentFailure


def test_fit_reads_rate_and_persistence_of_failures_fixed_to_the_world():
    frames = _frames(5)[::-1]  # any order: the fit pairs them along the path
    rng = np.random.default_rng(11)
    disparities = []
    for frame in frames:
        x = _world_x(frame)
        stuck = np.abs(x - 0.5) < 0.4  # a stripe of the plane where the matcher always fails by 6 px
        noise = rng.normal(0.0, 0.2, x.shape)
        disparities.append(frame.disparity_gt - noise - np.where(stuck, 6.0, 0.0))
    block = fit_fusion(frames, disparities, CAMERA)
    share = np.mean([np.mean(np.abs(_world_x(f) - 0.5) < 0.4) for f in frames[1:]])
    assert block["model"] == "persistent-failure" and block["n_pairs"] > MIN_PAIRS
    assert block["rate"] == pytest.approx(share, abs=0.02)
    assert block["persistence"] > 0.9  # the stripe fails again from the next position
    independent = [f.disparity_gt - np.where(rng.random(f.disparity_gt.shape) < 0.1, 6.0, 0.0) for f in frames]
    loose = fit_fusion(frames, independent, CAMERA)
    assert loose["rate"] == pytest.approx(0.1, abs=0.01) and loose["persistence"] == pytest.approx(0.1, abs=0.02)


def test_fit_refuses_too_few_pairs_and_frames_without_poses():
    frames = _frames(2)
    with pytest.raises(PrismapInputError, match="surface points"):
        fit_fusion(frames, [f.disparity_gt * np.nan for f in frames], CAMERA)
    with pytest.raises(PrismapInputError, match="at least 2 frames"):
        fit_fusion(frames[:1], [frames[0].disparity_gt], CAMERA)
    unposed = [type(f)(f.left, f.right, f.camera, f.disparity_gt, None, f.name) for f in frames]
    with pytest.raises(PrismapInputError, match="frame 0 .* no pose"):
        fit_fusion(unposed, [f.disparity_gt for f in frames], CAMERA)


def test_block_round_trip_and_errors():
    model = PersistentFailure(0.05, 0.6)
    block = fusion_block(model, gross_px=3.0, n_pairs=1000)
    assert block == {"model": "persistent-failure", "rate": 0.05, "persistence": 0.6, "gross_px": 3.0, "n_pairs": 1000}
    assert fusion_from_block(block) == model
    assert fusion_from_block(None) is None and fusion_from_block(fusion_block(None)) is None
    with pytest.raises(PrismapInputError, match="m.json: field 'fusion' must be an object"):
        fusion_from_block({"model": "clamp"}, source="m.json")
    with pytest.raises(PrismapInputError, match="lacks 'persistence'"):
        fusion_from_block({"model": "persistent-failure", "rate": 0.1})
    with pytest.raises(PrismapInputError, match="field 'fusion': `persistence`"):
        fusion_from_block({"model": "persistent-failure", "rate": 0.3, "persistence": 0.1})


def test_characterisation_frames_are_ordered_along_the_path():
    drive_and_between = np.array([[4.0, 0, 0], [8.0, 0, 0], [5.0, 0, 0], [7.0, 0, 0], [9.0, 0, 0], [11.0, 0, 0]])
    assert path_order(drive_and_between) == [0, 2, 3, 1, 4, 5]
    angle = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    loop = np.stack([3.8 * np.cos(angle), 2.0 * np.sin(angle), np.zeros(8)], axis=1)
    assert path_order(loop) in ([0, 1, 2, 3, 4, 5, 6, 7], [0, 7, 6, 5, 4, 3, 2, 1])


def test_the_error_model_stores_its_fusion_block(tmp_path):
    import json

    from prismap.characterise import ErrorModel, load_error_model, write_error_model
    from prismap.gmm import GaussianMixture, MixtureFit

    fit = MixtureFit(GaussianMixture([0.8, 0.2], [0.0, -0.5], [0.3, 3.0]), -1.0, 1.0, 1.0, 100.0, 3, True)
    plain = ErrorModel("bm", {}, "test", 1 / 32, (fit,), 2)
    assert plain.persistent_failure is None and "fusion" not in plain.to_dict()
    block = {"model": "persistent-failure", "rate": 0.02, "persistence": 0.4, "gross_px": 3.0, "n_pairs": 500}
    fused = ErrorModel("bm", {}, "test", 1 / 32, (fit,), 2, fusion=block)
    write_error_model(fused, tmp_path / "m.json")
    loaded = load_error_model(tmp_path / "m.json")
    assert loaded.fusion == block and loaded.persistent_failure == PersistentFailure(0.02, 0.4)
    data = json.loads((tmp_path / "m.json").read_text())
    data["fusion"]["persistence"] = 0.01
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(PrismapInputError, match="bad.json.*field 'fusion': `persistence`"):
        load_error_model(tmp_path / "bad.json")
