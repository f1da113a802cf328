"""prismap map's readings of the error model's fusion block: the clamp at the one-view bound by default, the
persistent failure state, and the independent sum one option away; the same stored sums, kept by checkpoints."""

import numpy as np
import pytest

from prismap.characterise import ErrorModel
from prismap.errors import PrismapInputError
from prismap.gmm import MixtureFit
from prismap.grid import FailureMixture, PersistentFailure
from prismap.io import load_map
from prismap.pipeline import map_sequence
from support import MIXTURE, config, synthetic_sequence

BLOCK = {"model": "persistent-failure", "rate": 0.05, "persistence": 0.6, "gross_px": 3.0, "n_pairs": 1000}


@pytest.fixture(scope="module")
def sequence_dir(tmp_path_factory):
    return synthetic_sequence(tmp_path_factory.mktemp("fusion") / "seq", n_frames=4)


def _error_model(fusion=BLOCK):
    return ErrorModel(
        "sgbm", {}, "test", 1 / 32, (MixtureFit(MIXTURE, -1.0, 1.0, 1.0, 100.0, 3, True),), 2, fusion=fusion
    )


def test_persistent_failure_reads_the_independent_sums(sequence_dir, tmp_path):
    independent = map_sequence(sequence_dir, config(error_model=_error_model(), fusion="independent"), progress=False)
    fused = map_sequence(sequence_dir, config(error_model=_error_model(), fusion="persistent-failure"), progress=False)
    keys, log, counts = independent.known_voxels()
    keys_f, log_f, counts_f = fused.known_voxels()
    np.testing.assert_array_equal(keys, keys_f)
    np.testing.assert_array_equal(log, log_f)
    np.testing.assert_array_equal(counts, counts_f)
    assert independent.fusion is None and fused.fusion == PersistentFailure(0.05, 0.6)
    expected = PersistentFailure(0.05, 0.6).probability(log, counts, 0.05)
    np.testing.assert_allclose(fused.probability_at_keys(keys), expected)
    low, high = PersistentFailure(0.05, 0.6).bounds(0.05, int(counts.max()))
    assert fused.probability_at_keys(keys).min() >= low * (1 - 1e-9)


def test_a_checkpoint_keeps_the_fusion(sequence_dir, tmp_path):
    cfg = config(error_model=_error_model(), fusion="persistent-failure")
    checkpoint = tmp_path / "run.checkpoint.npz"
    map_sequence(sequence_dir, cfg, progress=False, checkpoint=checkpoint, checkpoint_every=2)
    assert load_map(checkpoint).fusion == PersistentFailure(0.05, 0.6)


def test_the_fusion_option_is_checked():
    with pytest.raises(PrismapInputError, match="needs an error model with a fusion block"):
        config(error_model=_error_model(None), fusion="persistent-failure")
    with pytest.raises(PrismapInputError, match="`fusion` must be one of"):
        config(error_model=_error_model(), fusion="clamped")
    plain = config(error_model=_error_model(), fusion="independent")
    fused = config(error_model=_error_model(), fusion="persistent-failure")
    assert "fusion" not in plain.to_dict()
    assert fused.to_dict()["fusion"] == {"reading": "persistent-failure", **BLOCK}
    mixed = config(error_model=_error_model())
    clamped = config(error_model=_error_model(), fusion="failure-clamp")
    assert mixed.to_dict()["fusion"] == {"reading": "failure-mixture", **BLOCK}
    assert clamped.to_dict()["fusion"] == {"reading": "failure-clamp", **BLOCK}
    fingerprints = {cfg.fingerprint() for cfg in (plain, fused, mixed, clamped)}
    assert len(fingerprints) == 4  # no resuming one as another


def test_the_default_reading_is_the_failure_mixture_when_the_error_model_has_a_block(sequence_dir):
    """r p0 + (1 - r) sigmoid(l) for models that take the error model and a block; the independent sum otherwise."""
    assert config(error_model=_error_model()).fusion == "failure-mixture"
    assert config(error_model=_error_model()).map_reading == FailureMixture(0.05)
    assert config(error_model=_error_model(None)).fusion == "independent"
    assert config(error_model=_error_model(), model="hitmiss").fusion == "independent"  # takes no error model
    mixed = map_sequence(sequence_dir, config(model="prism", error_model=_error_model()), progress=False)
    cfg = config(model="prism", error_model=_error_model(), fusion="independent")
    independent = map_sequence(sequence_dir, cfg, progress=False)
    keys, log, counts = independent.known_voxels()
    np.testing.assert_array_equal(mixed.known_voxels()[1], log)  # the stored sums do not change
    low, high = FailureMixture(0.05).bounds(mixed.p0)
    p = mixed.probability_at_keys(keys)
    np.testing.assert_allclose(p, 0.05 * mixed.p0 + 0.95 * independent.probability_at_keys(keys))
    assert independent.probability_at_keys(keys).min() < low  # PRISM's free evidence passes the lower bound
    assert p.min() >= low and p.max() <= high
