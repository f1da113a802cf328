"""Error classes, conditioned characterisation and the version-2 error-model file (and its hostile inputs)."""

import json

import numpy as np
import pytest

from prismap.camera import StereoCamera
from prismap.characterise import (
    NO_CLASS,
    ErrorClasses,
    ErrorHistogram,
    ErrorModel,
    characterise_matcher,
    choose_classes,
    compute_features,
    format_table,
    load_error_model,
    write_error_model,
)
from prismap.characterise._select import fit_classes
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture, fit_mixtures
from prismap.io import StereoFrame
from prismap.stereo import StereoMatcher

NEAR_EDGE = GaussianMixture([0.6, 0.4], [0.0, -2.0], [0.5, 4.0])
FAR_FROM_EDGE = GaussianMixture([0.9, 0.1], [0.0, 0.3], [0.15, 0.8])


def _tree():
    """A small tree over two features: f0 < 2 | f0 >= 2 and f1 < 5 | f0 >= 2 and f1 >= 5."""
    inf = np.inf
    return ErrorClasses(
        ("edge_distance_px", "texture"), [[-inf, -inf], [2.0, -inf], [2.0, 5.0]], [[2.0, inf], [inf, 5.0], [inf, inf]]
    )


def _brute_force(classes, values, valid):
    label = np.full(valid.shape, NO_CLASS, dtype=np.int32)
    for index in np.ndindex(valid.shape):
        if not valid[index]:
            continue
        x = [values[name][index] for name in classes.features]
        if any(np.isnan(v) for v in x):
            continue
        holders = [
            k
            for k in range(classes.n_classes)
            if all(
                classes.lower[k, f] <= v and (v < classes.upper[k, f] or classes.upper[k, f] == np.inf)
                for f, v in enumerate(x)
            )
        ]
        assert len(holders) == 1
        label[index] = holders[0]
    return label


@pytest.mark.parametrize(
    "classes",
    [
        _tree(),
        ErrorClasses.from_edges(("edge_distance_px", "texture"), ([1.5, 4.0], [3.0, 8.0])),
        ErrorClasses.from_edges(("disparity_px",), ([10.0, 20.0, 30.0],)),
        ErrorClasses.from_edges(("edge_distance_px", "disparity_gradient"), ([3.0], [0.05, 0.2])),
    ],
)
def test_classification_agrees_with_a_brute_force_reference(classes):
    rng = np.random.default_rng(4)
    shape = (17, 23)
    values = {
        "edge_distance_px": rng.integers(0, 8, shape).astype(float),
        "texture": rng.uniform(0, 12, shape),
        "disparity_px": rng.uniform(0, 40, shape),
        "disparity_gradient": rng.exponential(0.1, shape),
    }
    values["edge_distance_px"][0, :4] = [np.inf, 2.0, 1.5, 4.0]  # infinity and values on the bounds
    values["texture"][1, :3] = [5.0, 3.0, np.nan]
    values["disparity_gradient"][2, :2] = [np.inf, 0.2]  # no wholly valid neighbourhood, a value on a bound
    valid = rng.random(shape) > 0.1
    label = classes.assign(values, valid)
    assert label.dtype == np.int32 and label.shape == shape
    np.testing.assert_array_equal(label, _brute_force(classes, values, valid))
    assert set(np.unique(label[valid & ~np.isnan(values["texture"])])) <= set(range(classes.n_classes))


def test_classes_that_overlap_leave_gaps_or_are_empty_are_refused():
    inf = np.inf
    with pytest.raises(PrismapInputError, match=r"overlap: classes \[0, 1\]"):
        ErrorClasses(("texture",), [[-inf], [2.0]], [[3.0], [inf]])
    with pytest.raises(PrismapInputError, match=r"gap: no class holds texture in \[2, 3\)"):
        ErrorClasses(("texture",), [[-inf], [3.0]], [[2.0], [inf]])
    with pytest.raises(PrismapInputError, match="covered only from 0"):
        ErrorClasses(("texture",), [[0.0], [3.0]], [[3.0], [inf]])
    with pytest.raises(PrismapInputError, match="lower < upper"):
        ErrorClasses(("texture",), [[-inf], [3.0], [3.0]], [[3.0], [3.0], [inf]])
    with pytest.raises(PrismapInputError, match="distinct names"):
        ErrorClasses(("colour",), [[-inf]], [[inf]])
    # a gap in a 2-D tiling: the tree without its last box
    tree = _tree()
    with pytest.raises(PrismapInputError, match="gap: no class holds"):
        ErrorClasses(tree.features, tree.lower[:2], tree.upper[:2])


def _samples(seed, n=60000):
    """Edge distances 0..9 px; errors from NEAR_EDGE below 3 px, from FAR_FROM_EDGE beyond."""
    rng = np.random.default_rng(seed)
    distance = rng.integers(0, 10, n).astype(float)
    texture = rng.uniform(0, 20, n)  # carries no information
    near = distance < 3
    errors = np.where(near, NEAR_EDGE.sample(n, rng), FAR_FROM_EDGE.sample(n, rng))
    return {"edge_distance_px": distance, "texture": texture}, errors, rng.integers(0, 2, n)


def test_held_out_selection_finds_the_informative_feature_and_em_recovers_each_class_mixture():
    values, errors, fold = _samples(0)
    edges = ErrorHistogram.empty().edges
    classes, record = choose_classes(values, errors, fold, bin_edges=edges, max_classes=4, max_components=3)
    assert classes.features == ("edge_distance_px",)
    assert record["conditioned_nats_per_error"] > record["plain_nats_per_error"] + 0.1
    assert record["candidates"][0]["features"] == [] and len(record["candidates"]) > 5
    assert record["components"] == [2] * classes.n_classes  # held-out G finds the true 2 components per class
    models, histograms = fit_classes(
        classes,
        values,
        errors,
        bin_width=1 / 32,
        limit_px=256.0,
        max_components=3,
        criterion="bic",
        tolerance=0.002,
        components=record["components"],
    )
    label = classes.assign(values, np.ones(errors.size, bool))
    assert sum(h.n_errors for h in histograms) == errors.size
    for k, model in enumerate(models):
        # Quantile edges lie between the integer distances, so no class mixes the two truths.
        inside = values["edge_distance_px"][label == k]
        assert (inside < 3).all() or (inside >= 3).all()
        truth = NEAR_EDGE if (inside < 3).all() else FAR_FROM_EDGE
        assert model.share == pytest.approx((label == k).mean())
        fitted = model.mixture
        assert fitted.n_components == 2
        np.testing.assert_allclose(fitted.weights, truth.weights, atol=0.03)
        assert np.all(np.abs(fitted.means - truth.means) <= 0.1 * truth.sigmas + 0.02)
        np.testing.assert_allclose(fitted.sigmas, truth.sigmas, rtol=0.08)


def test_every_class_keeps_an_outlier_floor_fitted_to_its_gross_errors():
    """A class without gross errors still gives one a bounded log-density; a class with them gets their weight."""
    rng = np.random.default_rng(3)
    n = 40000
    values = {"edge_distance_px": rng.integers(0, 10, n).astype(float)}
    wide = GaussianMixture.gaussian(12.0, 2.0)
    near = values["edge_distance_px"] < 3
    core = GaussianMixture.gaussian(0.15)
    errors = np.where(near, core.with_component(0.05, 2.0, 12.0).sample(n, rng), core.sample(n, rng))
    classes = ErrorClasses.from_edges(("edge_distance_px",), ([2.5],))
    models, _ = fit_classes(
        classes,
        values,
        errors,
        bin_width=1 / 32,
        limit_px=256.0,
        max_components=1,
        criterion="bic",
        tolerance=0.01,
        outlier=wide,
    )
    bare, _ = fit_classes(
        classes, values, errors, bin_width=1 / 32, limit_px=256.0, max_components=1, criterion="bic", tolerance=0.01
    )
    far = models[1]
    # no gross error far from edges: the floor is the one pseudo-error's weight, about 1 / N
    assert 0.5 / (~near).sum() < far.outlier["weight"] < 3.0 / (~near).sum()
    assert far.mixture.logpdf(np.array([30.0]))[0] > np.log(0.5 / (~near).sum()) + wide.logpdf(np.array([30.0]))[0]
    assert bare[1].mixture.logpdf(np.array([30.0]))[0] < -300  # without the floor: hundreds of nats
    # near edges (held to G = 1 here) the one Gaussian widens to take some of the 5 % gross errors, the floor the rest
    assert 0.01 < models[0].outlier["weight"] < 0.06


def test_errors_independent_of_the_features_keep_the_plain_model():
    rng = np.random.default_rng(1)
    n = 40000
    values = {"texture": rng.uniform(0, 20, n)}
    errors = FAR_FROM_EDGE.sample(n, rng)
    classes, record = choose_classes(
        values, errors, rng.integers(0, 2, n), bin_edges=ErrorHistogram.empty().edges, max_classes=3, max_components=2
    )
    assert classes.features == () and record["conditioned_nats_per_error"] == record["plain_nats_per_error"]


# --- conditioned characterisation of a matcher -----------------------------------------------------

CAMERA = StereoCamera(500.0, 80.0, 60.0, 0.1)


class EdgeFailingMatcher(StereoMatcher):
    """True disparity (a step every 20 columns) minus a wide error within 2 columns of a step, a narrow one beyond."""

    name = "edge-failing"

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)

    def compute(self, left, right):
        truth = _step_disparity(left.shape)
        columns = np.arange(left.shape[1]) % 20
        near = np.broadcast_to((columns < 2) | (columns >= 18), left.shape)
        noise = np.where(
            near,
            np.clip(NEAR_EDGE.sample(left.size, self.rng), -0.9, 0.9).reshape(left.shape),
            FAR_FROM_EDGE.sample(left.size, self.rng).reshape(left.shape) * 0.5,
        )
        return (truth - noise).astype(np.float32)

    def params(self):
        return {"name": self.name}


def _step_disparity(shape):
    """8 px steps every 20 columns on a ramp of 0.1 px per row (so the disparity says little of the error)."""
    rows, columns = np.mgrid[0 : shape[0], 0 : shape[1]]
    return 10.0 + 8.0 * ((columns // 20) % 2) + 0.1 * rows


def _frames(n=2, shape=(120, 160)):
    rng = np.random.default_rng(7)
    return [
        StereoFrame(
            rng.integers(0, 256, shape).astype(np.uint8),
            rng.integers(0, 256, shape).astype(np.uint8),
            CAMERA,
            disparity_gt=_step_disparity(shape).astype(np.float32),
            name=f"step {i}",
        )
        for i in range(n)
    ]


def test_conditioned_characterisation_of_a_matcher_that_fails_at_edges(tmp_path):
    result = characterise_matcher(_frames(), EdgeFailingMatcher(3), max_components=3, max_classes=3)
    model = result.model
    record = model.class_selection
    assert record["held_out"].startswith("two folds: frames of even / odd index")
    assert model.conditioned and "edge_distance_px" in model.classes.features
    assert record["conditioned_nats_per_error"] > record["plain_nats_per_error"]
    assert sum(h.n_errors for h in result.class_histograms) == result.histogram.n_errors
    assert sum(m.share for m in model.class_models) == pytest.approx(1.0)
    # The class nearest the edges holds the wide errors.
    sigmas = [m.mixture.std() for m in model.class_models]
    nearest = int(np.argmin(model.classes.lower[:, list(model.classes.features).index("edge_distance_px")]))
    assert sigmas[nearest] == max(sigmas)
    # classify() on a run's features gives the classes the characterisation used.
    frame = _frames(1)[0]
    disparity = EdgeFailingMatcher(3).compute(frame.left, frame.right)
    disparity[0, 0] = np.nan
    label = model.classify(compute_features(frame.left, frame.right, disparity))
    assert label[0, 0] == NO_CLASS and (label[1:] >= 0).all()
    path = tmp_path / "model.json"
    write_error_model(model, path)
    loaded = load_error_model(path)
    np.testing.assert_array_equal(loaded.classify(compute_features(frame.left, None, disparity)), label)
    for a, b in zip(loaded.class_mixtures, model.class_mixtures):
        np.testing.assert_array_equal(a.sigmas, b.sigmas)
    table = format_table(loaded)
    assert "## Error classes" in table and "edge_distance_px" in table
    assert table.count("\n| ") >= 3 + model.n_classes


# --- the version-2 file ----------------------------------------------------------------------------


def _conditioned_model():
    values, errors, _ = _samples(2, n=20000)
    classes = ErrorClasses.from_edges(("edge_distance_px",), ([2.5],))
    models, _ = fit_classes(
        classes,
        values,
        errors,
        bin_width=1 / 32,
        limit_px=256.0,
        max_components=2,
        criterion="bic",
        tolerance=0.01,
        outlier=GaussianMixture.gaussian(4.0, -2.0),
    )
    histogram = ErrorHistogram.from_errors(errors)
    fits = fit_mixtures(histogram.edges, histogram.counts, max_components=2)
    return ErrorModel(
        "sgbm",
        {"block_size": 5},
        "synthetic",
        1 / 32,
        tuple(fits),
        2,
        {"criterion": "bic"},
        histogram.statistics(),
        classes=classes,
        class_models=models,
        feature_settings={"edge_threshold_px": 1.0, "texture_window_px": 7},
        class_selection={"held_out": "test"},
    )


def test_version_2_round_trips_and_version_1_loads_as_one_class(tmp_path):
    model = _conditioned_model()
    path = tmp_path / "v2.json"
    write_error_model(model, path)
    data = json.loads(path.read_text())
    assert data["format_version"] == 3 and data["features"]["names"] == ["edge_distance_px"]
    assert data["classes"][0]["bounds"] == {"edge_distance_px": [None, 2.5]}
    loaded = load_error_model(path)
    assert loaded.n_classes == 2 and loaded.conditioned
    np.testing.assert_array_equal(loaded.classes.upper, model.classes.upper)
    assert [m.share for m in loaded.class_models] == [m.share for m in model.class_models]
    for mine, theirs in zip(loaded.class_mixtures, model.class_mixtures):  # the outlier component included
        assert mine.n_components == 3
        np.testing.assert_array_equal(mine.weights, theirs.weights)
    v1 = {key: value for key, value in data.items() if key not in ("features", "classes", "class_selection")}
    v1["format_version"] = 1
    (tmp_path / "v1.json").write_text(json.dumps(v1))
    plain = load_error_model(tmp_path / "v1.json")
    assert plain.n_classes == 1 and not plain.conditioned
    np.testing.assert_array_equal(plain.class_mixtures[0].sigmas, model.mixture.sigmas)
    features = compute_features(np.zeros((3, 4)), None, np.array([[1.0, np.nan, 2.0, 2.0]] * 3))
    np.testing.assert_array_equal(plain.classify(features), [[0, -1, 0, 0]] * 3)


def _deep(depth):
    return "[" * depth + "]" * depth


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(bin_width_px=[0.03]), "`bin_width_px` must be a number; got list"),
        (lambda d: d.update(selected_components="2"), "`selected_components` must be a whole number; got '2'"),
        (lambda d: d["models"][0].update(log_likelihood=1e400), "`log_likelihood` must be a finite number"),
        (lambda d: d.update(bin_width_px=1e300), r"`bin_width_px` must be a finite number in \(0, 8\]"),
        (lambda d: d["models"][1].update(n_components=3), "`n_components` is 3 but `weights` has 2"),
        (lambda d: d["models"][1].update(n_components=2.7), "`n_components` must be a whole number; got 2.7"),
        (lambda d: d["models"][1].update(weights=[[0.5], [0.5]]), "`weights` must be a list of numbers"),
        (lambda d: d["models"][0].update(converged="yes"), "`converged` must be true or false"),
        (lambda d: d.update(format_version=1.9), "unsupported format_version 1.9"),
        (lambda d: d["classes"][1]["bounds"].update(edge_distance_px=[2.0, None]), "classes overlap"),
        (lambda d: d["classes"][1]["bounds"].update(edge_distance_px=[3.0, None]), "classes leave a gap"),
        (
            lambda d: d["classes"][0].update(share=0.0),
            r"error class 0 \(edge_distance_px in \[-inf, 2.5\)\) has no pixels",
        ),
        (lambda d: d["classes"][0]["statistics"].update(n_errors=0), "error class 0 .* has no pixels"),
        (lambda d: d["classes"][1].update(share=0.9), "shares of the error classes must sum to 1"),
        (lambda d: d["classes"][0].update(selected_components=3), "no 3-component fit"),
        (lambda d: d["features"].update(names=["edge_distance_px", "colour"]), r"unknown feature\(s\) \['colour'\]"),
        (
            lambda d: d["classes"][0]["bounds"].update(edge_distance_px="low"),
            "must be \\[lower or null, upper or null\\]",
        ),
        (
            lambda d: d["classes"][0]["outlier"].update(weight=1.5),
            r"classes\[0\]: `outlier.weight` must be a finite number",
        ),
        (
            lambda d: d["classes"][1]["outlier"].update(sigma=0),
            r"classes\[1\]: `outlier.sigma` must be a finite number",
        ),
        (lambda d: d["classes"][1]["outlier"].pop("mean"), r"`outlier`: missing field\(s\) \['mean'\]"),
    ],
)
def test_hostile_version_2_files_get_one_clear_error(tmp_path, edit, message):
    data = _conditioned_model().to_dict()
    edit(data)
    path = tmp_path / "model.json"
    path.write_text(json.dumps(data))
    with pytest.raises(PrismapInputError, match=message) as info:
        load_error_model(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (_deep(10_000), "nested too deeply"),
        ('{"format": "prismap-error-model", "format_version": ' + "9" * 5000 + "}", "not valid JSON"),
    ],
)
def test_unparseable_error_model_json_is_one_clear_error(tmp_path, text, message):
    path = tmp_path / "model.json"
    path.write_text(text)
    with pytest.raises(PrismapInputError, match=message):
        load_error_model(path)


def test_a_run_that_cannot_compute_the_features_is_refused():
    model = _conditioned_model()
    model.check_usable("sgbm", left_right_check=False)
    with pytest.raises(PrismapInputError, match="fitted to matcher 'sgbm'; this run uses 'bm'"):
        model.check_usable("bm", left_right_check=True)
    inf = np.inf
    lr_classes = ErrorClasses(("lr_disagreement_px",), [[-inf], [0.5]], [[0.5], [inf]])
    lr_model = ErrorModel(
        model.matcher,
        {},
        "",
        model.bin_width,
        model.fits,
        2,
        classes=lr_classes,
        class_models=model.class_models,
        feature_settings=model.feature_settings,
    )
    lr_model.check_usable("sgbm", left_right_check=True)
    with pytest.raises(PrismapInputError, match="needs the matcher's left-right check"):
        lr_model.check_usable("sgbm", left_right_check=False)
    features = compute_features(np.zeros((3, 3)), None, np.ones((3, 3)))
    with pytest.raises(PrismapInputError, match=r"need feature\(s\) \['lr_disagreement_px'\]"):
        lr_model.classify(features)
    other = compute_features(np.zeros((3, 3)), None, np.ones((3, 3)), edge_threshold_px=2.0)
    with pytest.raises(PrismapInputError, match="features were computed with"):
        model.classify(other)
    # a plain model goes with any matcher
    ErrorModel("sgbm", {}, "", model.bin_width, model.fits, 2).check_usable("bm", left_right_check=False)
