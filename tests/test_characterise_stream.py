"""Conditioned characterisation in bounded memory: the mergeable pixel sample, streamed class histograms against
the in-memory reference, determinism whatever the chunking, and peak memory flat in the number of frames."""

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.characterise import PixelSample, characterise_matcher, choose_classes, compute_features
from prismap.characterise._sample import characterised_pixels
from prismap.characterise._select import fit_classes, outlier_component
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.io import StereoFrame
from prismap.stereo import StereoMatcher
from prismap.stereo._base import to_grey

NEAR_EDGE = GaussianMixture([0.6, 0.4], [0.0, -2.0], [0.5, 4.0])
FAR_FROM_EDGE = GaussianMixture([0.9, 0.1], [0.0, 0.3], [0.15, 0.8])
SHAPE = (40, 60)
CAMERA = StereoCamera(500.0, 30.0, 20.0, 0.1)
N_FRAMES = 12


def _step_disparity(shape):
    """8 px steps every 20 columns on a ramp of 0.1 px per row."""
    rows, columns = np.mgrid[0 : shape[0], 0 : shape[1]]
    return 10.0 + 8.0 * ((columns // 20) % 2) + 0.1 * rows


class SeededEdgeMatcher(StereoMatcher):
    """Truth minus a wide error within 2 columns of a step, a narrow one elsewhere; seeded by the left image.

    Deterministic, as the two passes need: the same frame gives the same disparity every time.
    """

    name = "seeded-edge"

    def compute(self, left, right):
        rng = np.random.default_rng(int(np.asarray(left, dtype=np.int64).sum()))
        columns = np.arange(left.shape[1]) % 20
        near = np.broadcast_to((columns < 2) | (columns >= 18), left.shape)
        noise = np.where(
            near,
            np.clip(NEAR_EDGE.sample(left.size, rng), -0.9, 0.9).reshape(left.shape),
            0.5 * FAR_FROM_EDGE.sample(left.size, rng).reshape(left.shape),
        )
        disparity = (_step_disparity(left.shape) - noise).astype(np.float32)
        disparity[:, :3] = np.nan  # unmatched border columns
        return disparity

    def params(self):
        return {"name": self.name}


@pytest.fixture(scope="module")
def frames():
    rng = np.random.default_rng(11)
    truth = _step_disparity(SHAPE).astype(np.float32)
    truth[0, :] = np.nan  # unknown ground truth on the first row
    return [
        StereoFrame(
            rng.integers(0, 256, SHAPE).astype(np.uint8),
            rng.integers(0, 256, SHAPE).astype(np.uint8),
            CAMERA,
            disparity_gt=truth,
            name=f"step {i}",
        )
        for i in range(N_FRAMES)
    ]


def _features(frame):
    disparity = SeededEdgeMatcher().compute(frame.left, frame.right)
    return compute_features(to_grey(frame.left), to_grey(frame.right), disparity)


def _in_memory(frames):
    """Every characterised pixel of every frame: float64 features, errors, frame-parity folds."""
    values, errors, fold = {}, [], []
    for position, frame in enumerate(frames):
        features = _features(frame)
        keep = characterised_pixels(features, frame.disparity_gt)
        for name, array in features.values.items():
            values.setdefault(name, []).append(array[keep].astype(np.float32).astype(np.float64))
        errors.append((frame.disparity_gt.astype(np.float64) - features.values["disparity_px"])[keep])
        fold.append(np.full(int(keep.sum()), position % 2))
    return {n: np.concatenate(v) for n, v in values.items()}, np.concatenate(errors), np.concatenate(fold)


OPTIONS = {"max_components": 3, "max_classes": 3, "progress": False}


# --- the sample ------------------------------------------------------------------------------------


def test_samples_of_chunks_merge_into_the_brute_force_lowest_priorities_in_any_grouping(frames):
    capacity, seed = 3000, 5
    parts = [
        PixelSample.from_frame(_features(f), f.disparity_gt, p, capacity=capacity, seed=seed)
        for p, f in enumerate(frames[:5])
    ]
    forward = parts[0] + parts[1] + parts[2] + parts[3] + parts[4]
    grouped = parts[4] + ((parts[2] + parts[0]) + (parts[3] + parts[1]))
    # Brute force: every characterised pixel with its priority, the `capacity` lowest.
    rows = []
    for position, frame in enumerate(frames[:5]):
        keep = characterised_pixels(_features(frame), frame.disparity_gt)
        priority = np.random.default_rng((seed, position)).random(int(keep.sum()))
        rows += [(q, position, pixel) for q, pixel in zip(priority, np.flatnonzero(keep))]
    lowest = sorted(rows)[:capacity]
    expected = sorted((position, pixel) for _, position, pixel in lowest)
    assert forward.n_seen == grouped.n_seen == len(rows) > capacity and forward.n_samples == capacity
    assert not forward.exhaustive
    assert list(zip(forward.frame.tolist(), forward.pixel.tolist())) == expected
    for a, b in (
        (forward.frame, grouped.frame),
        (forward.pixel, grouped.pixel),
        (forward.errors, grouped.errors),
        (forward.priority, grouped.priority),
        (forward.right_half, grouped.right_half),
    ):
        np.testing.assert_array_equal(a, b)
    for name in forward.values:
        np.testing.assert_array_equal(forward.values[name], grouped.values[name])
    # The kept pixels carry their own frame's features and errors.
    frame = frames[2]
    features = _features(frame)
    mine = forward.frame == 2
    np.testing.assert_array_equal(
        forward.values["texture"][mine], features.values["texture"].ravel()[forward.pixel[mine]].astype(np.float32)
    )
    np.testing.assert_array_equal(
        forward.errors[mine],
        (frame.disparity_gt.astype(np.float64) - features.values["disparity_px"]).ravel()[forward.pixel[mine]],
    )
    np.testing.assert_array_equal(forward.right_half, forward.pixel % SHAPE[1] >= SHAPE[1] / 2)


def test_bad_samples_are_refused(frames):
    features = _features(frames[0])
    with pytest.raises(PrismapInputError, match="`max_samples` must be an integer >= 1; got 0"):
        PixelSample.from_frame(features, frames[0].disparity_gt, 0, capacity=0)
    with pytest.raises(PrismapInputError, match=r"differ in shape: \(40, 60\) vs \(40, 59\)"):
        PixelSample.from_frame(features, frames[0].disparity_gt[:, 1:], 0)
    with pytest.raises(PrismapInputError, match="one capacity"):
        PixelSample.from_frame(features, frames[0].disparity_gt, 0, capacity=10) + PixelSample.from_frame(
            features, frames[0].disparity_gt, 1, capacity=20
        )
    with pytest.raises(PrismapInputError, match="`search_frames` must be an integer >= 1; got 0"):
        characterise_matcher(frames, SeededEdgeMatcher(), search_frames=0)


# --- streamed against in-memory ----------------------------------------------------------------------


def test_an_exhaustive_sample_gives_exactly_the_in_memory_model(frames):
    """Every frame searched, every pixel kept: one pass, and the model of all pixels' features in memory."""
    result = characterise_matcher(frames, SeededEdgeMatcher(), **OPTIONS)
    values, errors, fold = _in_memory(frames)
    classes, record = choose_classes(
        values, errors, fold, bin_edges=result.histogram.edges, max_classes=3, max_components=3, seed=0
    )
    models, histograms = fit_classes(
        classes,
        values,
        errors,
        bin_width=1 / 32,
        limit_px=256.0,
        n_frames=N_FRAMES,
        max_components=3,
        criterion="bic",
        tolerance=0.01,
        components=record["components"],
        outlier=outlier_component(result.mixture),
    )
    model = result.model
    assert model.conditioned and model.classes.features == classes.features == ("edge_distance_px",)
    np.testing.assert_array_equal(model.classes.lower, classes.lower)
    np.testing.assert_array_equal(model.classes.upper, classes.upper)
    assert model.class_selection["candidates"] == record["candidates"]
    assert model.class_selection["n_samples"] == model.class_selection["n_search_pixels"] == errors.size
    for mine, theirs, part, reference in zip(model.class_models, models, result.class_histograms, histograms):
        np.testing.assert_array_equal(part.counts, reference.counts)
        assert mine.share == theirs.share and mine.selected_components == theirs.selected_components
        np.testing.assert_array_equal(mine.mixture.sigmas, theirs.mixture.sigmas)
        np.testing.assert_array_equal(mine.mixture.means, theirs.mixture.means)


def test_a_bounded_sample_of_some_frames_streams_exact_class_histograms_and_a_close_model(frames):
    """6 of 12 frames searched, 10000 of their 13338 pixels kept: the class histograms still hold every frame's
    errors exactly, and the model predicts the errors within 0.02 nats per error of the in-memory model."""
    streamed = characterise_matcher(frames, SeededEdgeMatcher(), search_frames=6, max_samples=10000, **OPTIONS)
    record = streamed.model.class_selection
    assert (record["n_search_frames"], record["n_samples"]) == (6, 10000) and record["n_search_pixels"] > 10000
    values, errors, _ = _in_memory(frames)
    classes = streamed.model.classes
    assert classes.features == ("edge_distance_px",)
    label = classes.assign(values, np.ones(errors.size, bool))
    for k, part in enumerate(streamed.class_histograms):
        index = np.floor((errors[label == k] + 256.0) * 32).astype(np.int64)
        np.testing.assert_array_equal(part.counts, np.bincount(index, minlength=part.counts.size))
        assert part.n_frames == N_FRAMES
        assert streamed.model.class_models[k].share == pytest.approx((label == k).mean(), abs=1e-12)
    assert streamed.histogram.n_frames == N_FRAMES
    assert sum(p.n_errors for p in streamed.class_histograms) == errors.size
    exhaustive = characterise_matcher(frames, SeededEdgeMatcher(), **OPTIONS).model

    def nats_per_error(model):
        label = model.classes.assign(values, np.ones(errors.size, bool))
        return (
            sum(model.class_mixtures[k].logpdf(errors[label == k]).sum() for k in range(model.n_classes)) / errors.size
        )

    plain = exhaustive.mixture.logpdf(errors).mean()
    assert streamed.model.n_classes == exhaustive.n_classes == 3
    assert nats_per_error(streamed.model) == pytest.approx(nats_per_error(exhaustive), abs=0.02)
    assert nats_per_error(streamed.model) > plain + 0.1


def test_the_streamed_model_is_the_same_for_a_seed_whatever_the_chunking(frames):
    options = {"search_frames": 5, "max_samples": 7000, **OPTIONS}
    first = characterise_matcher(frames, SeededEdgeMatcher(), **options)
    again = characterise_matcher(frames, SeededEdgeMatcher(), chunk_frames=5, **options)
    assert json.dumps(first.model.to_dict()) == json.dumps(again.model.to_dict())
    other_seed = characterise_matcher(frames, SeededEdgeMatcher(), seed=1, **options)
    assert other_seed.model.class_selection["n_samples"] == 7000
    assert other_seed.model.class_selection["candidates"] != first.model.class_selection["candidates"]


# --- memory ------------------------------------------------------------------------------------------

_MEASURE = textwrap.dedent("""
    import resource, sys
    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))
    sys.path.insert(0, {tests!r})
    import numpy as np
    from support import shifted_pair, write_kitti_stereo
    from prismap.pipeline import characterise_sequence
    from pathlib import Path
    root = Path({root!r})
    if not (root / "image_2").is_dir():
        rng = np.random.default_rng(0)
        write_kitti_stereo(root, [shifted_pair(rng, 120, 320, 6 + i % 5) for i in range({n})], year=2015)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    result = characterise_sequence(root, "sgbm", matcher_params={{"num_disparities": 16}}, frames=({n_use}, None),
                                   max_components=2, max_samples=20000, search_frames=4, progress=False)
    print(result.histogram.n_frames, before, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
""")


def test_peak_memory_does_not_grow_with_the_frames(tmp_path):
    """4 and 40 frames of a KITTI-2015-like folder (120 x 320), under a 3 GiB address-space cap: keeping every
    pixel's features (about 40 bytes each) would add 55 MB for the 36 more frames."""
    root = tmp_path / "training"
    peaks = {}
    for n_use in (36, 0):  # the last 4 frames, then all 40 (the folder is written by the first run)
        code = _MEASURE.format(tests=str(Path(__file__).parent), root=str(root), n=40, n_use=n_use)
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr[-2000:]
        n_frames, _, peak_kib = map(int, out.stdout.split())
        peaks[n_frames] = peak_kib
    assert set(peaks) == {4, 40}
    assert peaks[40] - peaks[4] < 15 * 1024, peaks  # KiB


def test_progress_counts_frames_per_pass_and_announces_the_steps(frames, monkeypatch, capsys):
    monkeypatch.setenv("PRISMAP_PROGRESS", "lines")
    result = characterise_matcher(frames[:4], SeededEdgeMatcher(), search_frames=3, max_components=2, max_classes=2)
    err = capsys.readouterr().err
    assert result.model.conditioned
    assert "characterise seeded-edge: sample for the class search: 3/3 frames (100%)" in err
    assert re.search(r"characterise seeded-edge: choose error classes on \d+ of \d+ pixels: 1/1 steps", err)
    assert "characterise seeded-edge: class histograms: 4/4 frames (100%)" in err
    assert f"characterise seeded-edge: fit {1 + result.model.n_classes} mixture(s) by EM, G = 1..2: 1/1 steps" in err
    characterise_matcher(
        frames[:4], SeededEdgeMatcher(), search_frames=3, max_components=2, max_classes=2, progress=False
    )
    assert capsys.readouterr().err == ""
