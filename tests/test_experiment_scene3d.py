"""The 3-D experiment on rendered stereo pairs: SGBM characterised on other frames, every model scored.

Configuration (``run_scene3d(quick=True, matchers=("sgbm",))``): the seeded indoor scene, 12 frames of a
160x120 New Tsukuba camera, frames 0, 4, 8 characterise SGBM and the other 9 are mapped, 0.2 m voxels,
rays to 10 m, scene shifted half a voxel off the grid.
"""

import numpy as np
import pytest

from prismap.errors import PrismapInputError
from prismap.experiment import MODELS, run_scene3d, split_frames


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene3d")
    return out, run_scene3d(out, quick=True, matchers=("sgbm",))


def test_prism_beats_ideal_on_brier_and_log_loss_and_hitmiss_on_log_loss(scene):
    _, result = scene
    prism, ideal, hitmiss = (result.cell("sgbm", m).scores for m in ("prism", "ideal", "hitmiss"))
    assert prism.brier < ideal.brier and prism.log_loss < ideal.log_loss
    assert prism.log_loss < hitmiss.log_loss
    assert prism.occupied_called_free <= ideal.occupied_called_free


@pytest.mark.xfail(strict=True, reason=(
    "refuted at this size: hit/miss has the lower Brier score (0.111 vs PRISM 0.113) and calls fewer truly "
    "occupied voxels free (0.86 vs 0.98); see the report and results.md"))
def test_prism_beats_hitmiss_on_brier_and_on_occupied_called_free(scene):
    _, result = scene
    prism, hitmiss = (result.cell("sgbm", m).scores for m in ("prism", "hitmiss"))
    assert prism.brier < hitmiss.brier
    assert prism.occupied_called_free < hitmiss.occupied_called_free


def test_the_run_characterises_on_frames_it_does_not_map(scene):
    out, result = scene
    characterise, mapping = split_frames(12, 4)
    assert characterise.tolist() == [0, 4, 8] and not set(characterise) & set(mapping)
    assert len(mapping) == 9 and all(c.n_frames == 9 for c in result.cells)
    table = (out / "sgbm" / "characterisation" / "table.md").read_text()
    assert "frames [0, 4, 8]" in table and "bad-1px" in table and "bad-2px" in table and "coverage" in table
    assert len(list((out / "sgbm" / "disparity").glob("*.png"))) == 9
    assert [c.model for c in result.cells] == list(MODELS)
    for path, _ in result.artifacts:
        assert path.is_file(), path


def test_every_model_sees_the_same_scored_voxels_and_prior(scene):
    _, result = scene
    assert len({(c.scores.n_voxels, c.scores.n_occupied) for c in result.cells}) == 1
    s = result.cells[0].scores
    assert result.p0 == pytest.approx((s.n_occupied + 1) / (s.n_voxels + 2))
    assert np.isfinite([c.scores.brier for c in result.cells]).all()


@pytest.mark.parametrize(
    "kwargs, message",
    [({"n_frames": 1}, "`n_frames` must be an integer >= 2"), ({"matchers": ("sad",)}, "subset of"),
     ({"characterise_every": 1}, "`characterise_every` must be an integer >= 2"),
     ({"grid_offset": 1.5}, r"`grid_offset` must lie in \[0, 1\)")],
)
def test_bad_scene_options_are_named(tmp_path, kwargs, message):
    with pytest.raises(PrismapInputError, match=message):
        run_scene3d(tmp_path, quick=True, **kwargs)
