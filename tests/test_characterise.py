"""Characterisation: error histograms that merge, error-model files, tables, and fits over frames."""

import json

import numpy as np
import pytest
from scipy import ndimage

from prismap.camera import StereoCamera
from prismap.characterise import (
    ErrorHistogram,
    ErrorModel,
    characterise_matcher,
    format_table,
    load_error_model,
    write_characterisation,
    write_error_model,
)
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, MixtureFit, fit_mixtures
from prismap.io import StereoFrame
from prismap.stereo import StereoMatcher, make_matcher

CAMERA = StereoCamera(500.0, 100.0, 80.0, 0.1)
TRUTH = GaussianMixture([0.9, 0.1], [0.0, 0.5], [0.3, 5.0])


class NoisyOracle(StereoMatcher):
    """A fake matcher: the true disparity (``left / 4``, see :func:`_oracle_frame`) minus TRUTH noise.

    Pixels where ``right == 0`` get no value, so coverage is known exactly.
    """

    name = "oracle"

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)

    def compute(self, left, right):
        disparity = left.astype(np.float64) / 4.0 - TRUTH.sample(left.size, self.rng).reshape(left.shape)
        return np.where(right == 0, np.nan, disparity).astype(np.float32)

    def params(self):
        return {"name": self.name}


def _oracle_frame(seed, shape=(400, 500)):
    rng = np.random.default_rng(seed)
    left = rng.integers(0, 256, shape).astype(np.uint8)
    right = (rng.random(shape) > 0.2).astype(np.uint8)  # 20 % of pixels uncomputed
    gt = (left / 4.0).astype(np.float32)
    gt[:5] = np.nan  # unknown ground truth in the top rows
    return StereoFrame(left, right, CAMERA, disparity_gt=gt, name=f"oracle {seed}")


def _shifted_texture_frame(seed, disparity=7.4, shape=(120, 200)):
    """A random texture and the same texture shifted left by a known sub-pixel disparity."""
    rng = np.random.default_rng(seed)
    texture = ndimage.gaussian_filter(rng.random((shape[0], shape[1] + 40)), 1.0)
    texture = 255 * (texture - texture.min()) / np.ptp(texture)
    left = texture[:, 20 : 20 + shape[1]].astype(np.uint8)
    shifted = ndimage.shift(texture, (0, -disparity), order=3, mode="nearest")
    right = np.clip(shifted[:, 20 : 20 + shape[1]], 0, 255).astype(np.uint8)
    return StereoFrame(left, right, CAMERA, disparity_gt=np.full(shape, disparity, np.float32), name=f"shift {seed}")


def _fit(g, ll=-100.0):
    mixture = GaussianMixture(np.full(g, 1.0 / g), np.arange(g, dtype=float), np.ones(g))
    return MixtureFit(mixture, ll, 2 * (3 * g - 1) - 2 * ll, 3 * g - 2 * ll, 50.0, 7, True)


# --- ErrorHistogram ------------------------------------------------------------------------------


def test_histogram_bins_like_numpy_and_counts_what_falls_outside():
    errors = np.array([-3.0, -2.0, -1.99, -0.5, 0.0, 0.49, 1.5, 1.999, 2.0, 7.0])
    hist = ErrorHistogram.from_errors(errors, bin_width=0.5, limit_px=2.0)
    reference, _ = np.histogram(errors[(errors >= -2) & (errors < 2)], bins=hist.edges)
    np.testing.assert_array_equal(hist.counts, reference)
    assert (hist.n_below, hist.n_above) == (1, 2)  # -3 below; 2.0 (the upper edge) and 7 above
    assert hist.n_errors == errors.size
    assert hist.n_bad_1px == 7  # |e| > 1: -3, -2, -1.99, 1.5, 1.999, 2, 7
    assert hist.bad_2px == pytest.approx(2 / 10)  # |e| > 2: -3 and 7
    assert hist.mean_abs_error_px == pytest.approx(np.abs(errors).mean())
    np.testing.assert_allclose(hist.centres, np.arange(-1.75, 2.0, 0.5))


def test_histograms_of_frames_add_up_to_the_histogram_of_all_errors():
    rng = np.random.default_rng(1)
    a, b = rng.normal(0, 3, 1000), rng.standard_cauchy(500) * 20
    merged = ErrorHistogram.from_errors(a, n_gt_valid=1200) + ErrorHistogram.from_errors(b, n_gt_valid=600)
    whole = ErrorHistogram.from_errors(np.concatenate([a, b]), n_gt_valid=1800)
    np.testing.assert_array_equal(merged.counts, whole.counts)
    assert merged.statistics() == pytest.approx({**whole.statistics(), "n_frames": 2})
    assert merged.coverage == pytest.approx(1500 / 1800)
    assert (ErrorHistogram.empty() + merged).counts.sum() == merged.counts.sum()
    with pytest.raises(PrismapInputError, match="same bins"):
        merged + ErrorHistogram.empty(bin_width=1 / 16)


def test_density_integrates_to_one():
    hist = ErrorHistogram.from_errors(np.random.default_rng(2).normal(0, 1, 5000))
    assert hist.density().sum() * hist.bin_width == pytest.approx(1.0)


def test_from_disparities_skips_unknown_pixels_and_measures_coverage():
    gt = np.array([[10.0, 10.0, np.inf], [np.nan, 5.0, 5.0]])
    computed = np.array([[9.5, np.nan, 3.0], [4.0, 5.0, 7.5]])
    hist = ErrorHistogram.from_disparities(computed, gt)
    assert hist.n_gt_valid == 4 and hist.n_errors == 3  # (0,0), (1,1), (1,2)
    assert hist.coverage == pytest.approx(3 / 4)
    assert hist.mean_abs_error_px == pytest.approx((0.5 + 0.0 + 2.5) / 3)
    assert hist.n_bad_2px == 1


@pytest.mark.parametrize(
    ("computed", "gt", "message"),
    [
        (np.zeros((2, 3)), np.zeros((3, 2)), "differ in shape"),
        (np.zeros((2, 2)), np.full((2, 2), np.inf), "ground-truth disparity has no valid"),
        (np.full((2, 2), np.nan), np.ones((2, 2)), "computed disparity has no valid pixel"),
        (np.zeros(4), np.zeros(4), "2-D"),
    ],
)
def test_from_disparities_rejects_unusable_maps(computed, gt, message):
    with pytest.raises(PrismapInputError, match=message):
        ErrorHistogram.from_disparities(computed, gt, name="frame 3")


def test_histogram_rejects_a_limit_off_the_bin_grid():
    with pytest.raises(PrismapInputError, match="multiple of `bin_width`"):
        ErrorHistogram.empty(bin_width=0.3, limit_px=1.0)


# --- ErrorModel file and table -------------------------------------------------------------------


def _model(fits, selected=2):
    return ErrorModel(
        "sgbm",
        {"block_size": np.int64(5)},
        "unit",
        1 / 32,
        tuple(fits),
        selected,
        {"criterion": "bic", "tolerance_nats_per_error": 0.01},
        {"n_errors": 50, "coverage": 0.5},
    )


def test_error_model_round_trips_through_json(tmp_path):
    model = _model([_fit(1), _fit(2), _fit(3)])
    path = tmp_path / "sub" / "model.json"
    write_error_model(model, path)
    loaded = load_error_model(path)
    assert loaded.selected_components == 2
    for name in ("weights", "means", "sigmas"):
        np.testing.assert_array_equal(getattr(loaded.mixture, name), getattr(model.mixture, name))
    for name in ("log_likelihood", "aic", "bic", "n_samples", "n_iter", "converged"):
        assert [getattr(f, name) for f in loaded.fits] == [getattr(f, name) for f in model.fits]
    assert loaded.matcher_params == {"block_size": 5}
    assert json.loads(path.read_text())["format_version"] == 3


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.pop("models"), r"missing field\(s\) \['models'\]"),
        (lambda d: d["models"][1].pop("sigmas"), r"models\[1\].*missing field"),
        (lambda d: d.update(format_version=99), "unsupported format_version 99"),
        (lambda d: d.update(selected_components=7), "no 7-component fit"),
        (lambda d: d["models"][0].update(aic="x"), "`aic` must be a number"),
    ],
)
def test_loading_a_broken_error_model_says_what_is_wrong(tmp_path, edit, message):
    data = _model([_fit(1), _fit(2)]).to_dict()
    data["matcher"]["params"] = {}
    edit(data)
    path = tmp_path / "model.json"
    path.write_text(json.dumps(data))
    with pytest.raises(PrismapInputError, match=message) as info:
        load_error_model(path)
    assert str(path) in str(info.value)


def test_loading_a_missing_or_non_json_file_fails_clearly(tmp_path):
    with pytest.raises(PrismapInputError, match="no such file"):
        load_error_model(tmp_path / "absent.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(PrismapInputError, match="not valid JSON"):
        load_error_model(tmp_path / "bad.json")


def test_table_follows_the_thesis_layout_and_hides_light_components_beyond_three():
    heavy = MixtureFit(
        GaussianMixture([0.05, 0.6, 0.3, 0.05], [9.0, -0.4, 0.1, 3.0], [20.0, 0.7, 2.0, 1.0]),
        -100.0,
        230.0,
        240.0,
        50.0,
        9,
        True,
    )
    table = format_table(_model([_fit(1), _fit(2), heavy], selected=4))
    rows = [line for line in table.splitlines() if line.startswith("| ")]
    assert rows[0].split(" | ")[:6] == ["| G", "AIC", "BIC", "µ1", "σ1", "w1"]
    assert rows[1].startswith("| 1 | 204 | 203 | ")  # AIC = 2k - 2 ln L = 4 + 200, BIC = 3 + 200
    selected = rows[-1].rstrip(" |").split(" | ")
    assert selected[0] == "| 4*"
    assert selected[3:9] == ["-0.40", "0.70", "0.60", "0.10", "2.00", "0.30"]  # heaviest first, w > 0.1 only
    assert "2 component(s) with weight <= 0.1 (together 0.10) not shown" in table
    assert "thesis printed 2G" in table


# --- characterise_matcher ------------------------------------------------------------------------


def test_characterisation_recovers_the_error_mixture_of_a_known_matcher():
    frames = [_oracle_frame(seed) for seed in range(3)]
    result = characterise_matcher(frames, NoisyOracle(seed=5), max_components=3, dataset="oracle", conditioned=False)
    hist = result.histogram
    gt_known = sum(int(np.isfinite(f.disparity_gt).sum()) for f in frames)
    computed = sum(int((np.isfinite(f.disparity_gt) & (f.right != 0)).sum()) for f in frames)
    assert hist.n_frames == 3 and hist.n_gt_valid == gt_known and hist.n_errors == computed
    assert result.model.selected_components == 2
    mixture = result.mixture
    np.testing.assert_allclose(mixture.weights, TRUTH.weights, atol=0.01)
    np.testing.assert_allclose(mixture.means, TRUTH.means, atol=0.05)
    np.testing.assert_allclose(mixture.sigmas, TRUTH.sigmas, rtol=0.05)
    # the fits are those of fit_mixtures on the merged histogram
    direct = fit_mixtures(hist.edges, hist.counts, max_components=3)
    assert [f.log_likelihood for f in result.model.fits] == [f.log_likelihood for f in direct]
    assert result.model.statistics["bad_2px"] == pytest.approx(hist.n_bad_2px / hist.n_errors)


def test_sgbm_on_a_shifted_texture_has_a_narrow_unbiased_dominant_component(tmp_path):
    frames = [_shifted_texture_frame(seed) for seed in range(2)]
    matcher = make_matcher("sgbm", num_disparities=16, block_size=5)
    result = characterise_matcher(frames, matcher, max_components=3, dataset="shifted texture", conditioned=False)
    heaviest = int(np.argmax(result.mixture.weights))
    assert result.histogram.coverage > 0.8
    assert abs(result.mixture.means[heaviest]) < 0.2
    assert result.mixture.sigmas[heaviest] < 0.3
    paths = write_characterisation(result, tmp_path / "out")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "error_model.json",
        "errors.png",
        "errors_wide.png",
        "table.md",
    ]
    assert load_error_model(paths["model"]).matcher_params == json.loads(json.dumps(matcher.params()))
    assert paths["figure"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_characterisation_rejects_frames_it_cannot_use():
    with pytest.raises(PrismapInputError, match="frame set is empty"):
        characterise_matcher([], NoisyOracle(seed=0))
    no_gt = StereoFrame(np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.uint8), CAMERA, name="blank")
    with pytest.raises(PrismapInputError, match=r"frame 0 \(blank\): has no ground-truth"):
        characterise_matcher([no_gt], NoisyOracle(seed=0))
    uncomputed = StereoFrame(
        np.ones((4, 4), np.uint8), np.zeros((4, 4), np.uint8), CAMERA, disparity_gt=np.ones((4, 4), np.float32)
    )
    with pytest.raises(PrismapInputError, match="computed disparity has no valid pixel"):
        characterise_matcher([uncomputed], NoisyOracle(seed=0))
