"""Confidence features of a computed disparity against brute-force numpy references on small images."""

import cv2
import numpy as np
import pytest

from prismap.characterise import FEATURE_UNITS, compute_features, discontinuity_mask, disparity_gradient
from prismap.errors import PrismapInputError


def _disparity(seed=0, shape=(11, 13)):
    rng = np.random.default_rng(seed)
    d = np.full(shape, 10.0)
    d[:, 7:] = 20.0  # a vertical depth edge
    d += rng.uniform(-0.3, 0.3, shape)  # sub-threshold ripples
    d[2, 3] = np.nan  # one invalid pixel
    return d


def _edges_by_loops(d, threshold):
    h, w = d.shape
    edges = np.zeros((h, w), bool)
    for v in range(h):
        for u in range(w):
            if not np.isfinite(d[v, u]):
                edges[v, u] = True
                continue
            for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                q = (v + dv, u + du)
                if 0 <= q[0] < h and 0 <= q[1] < w and abs(d[q] - d[v, u]) > threshold:
                    edges[v, u] = True
    return edges


def test_discontinuities_and_edge_distance_match_brute_force():
    d = _disparity()
    edges = _edges_by_loops(d, 1.0)
    np.testing.assert_array_equal(discontinuity_mask(d, edge_threshold_px=1.0), edges)
    assert edges[:, 6].all() and edges[:, 7].all() and edges[2, 3] and edges.sum() == 2 * 11 + 1
    features = compute_features(np.zeros(d.shape, np.uint8), None, d)
    edge_pixels = np.argwhere(edges)
    for v, u in np.ndindex(d.shape):
        expected = np.sqrt(((edge_pixels - (v, u)) ** 2).sum(axis=1)).min()
        assert features.values["edge_distance_px"][v, u] == pytest.approx(expected, abs=1e-12)


def test_a_frame_without_edges_is_infinitely_far_from_one():
    features = compute_features(np.zeros((4, 5), np.uint8), None, np.full((4, 5), 3.0))
    assert np.isposinf(features.values["edge_distance_px"]).all()


def test_texture_is_the_windowed_rms_sobel_gradient():
    rng = np.random.default_rng(1)
    grey = rng.integers(0, 256, (9, 12)).astype(np.uint8)
    window = 5
    image = np.pad(grey.astype(float), 1, mode="reflect")  # numpy "reflect" is OpenCV's REFLECT_101
    smooth, diff = np.array([1.0, 2.0, 1.0]), np.array([-1.0, 0.0, 1.0])
    gx = np.zeros(grey.shape)
    gy = np.zeros(grey.shape)
    for v, u in np.ndindex(grey.shape):
        patch = image[v : v + 3, u : u + 3]
        gx[v, u] = smooth @ patch @ diff / 8.0
        gy[v, u] = diff @ patch @ smooth / 8.0
    energy = np.pad(gx**2 + gy**2, window // 2, mode="reflect")
    expected = np.array([[np.sqrt(energy[v : v + window, u : u + window].mean()) for u in range(12)] for v in range(9)])
    features = compute_features(grey, grey, np.ones(grey.shape), texture_window_px=window)
    np.testing.assert_allclose(features.values["texture"], expected, rtol=1e-10, atol=1e-10)
    # A linear ramp of slope 3 grey levels per pixel has texture 3 away from the border.
    ramp = np.tile(3.0 * np.arange(20), (10, 1))
    texture = compute_features(ramp, None, np.ones(ramp.shape)).values["texture"]
    np.testing.assert_allclose(texture[4:-4, 4:-4], 3.0, rtol=1e-12)


def test_disparity_gradient_is_the_windowed_mean_sobel_magnitude_over_wholly_valid_neighbourhoods():
    rng = np.random.default_rng(3)
    d = rng.uniform(5.0, 15.0, (9, 12))
    d[4, 5] = np.nan
    d[0, 11] = np.nan
    window = 5
    padded = np.pad(d, 1, mode="reflect")  # numpy "reflect" is OpenCV's REFLECT_101
    smooth, diff = np.array([1.0, 2.0, 1.0]), np.array([-1.0, 0.0, 1.0])
    magnitude = np.zeros(d.shape)
    defined = np.zeros(d.shape, bool)
    for v, u in np.ndindex(d.shape):
        patch = padded[v : v + 3, u : u + 3]
        if np.isfinite(patch).all():
            defined[v, u] = True
            magnitude[v, u] = np.hypot(smooth @ patch @ diff / 8.0, diff @ patch @ smooth / 8.0)
    r = window // 2
    m_pad, w_pad = np.pad(magnitude, r, mode="reflect"), np.pad(defined.astype(float), r, mode="reflect")
    expected = np.array(
        [
            [
                m_pad[v : v + window, u : u + window].sum() / w_pad[v : v + window, u : u + window].sum()
                for u in range(12)
            ]
            for v in range(9)
        ]
    )
    got = compute_features(np.zeros(d.shape), None, d, texture_window_px=window).values["disparity_gradient"]
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12)
    # A plane d = 0.3 u - 0.4 v + 20 has gradient 0.5 px/px away from the border, and next to a hole too.
    v, u = np.mgrid[0:20, 0:30]
    plane = 0.3 * u - 0.4 * v + 20.0
    plane[10, 15] = np.nan
    np.testing.assert_allclose(disparity_gradient(plane, window_px=7)[4:-4, 4:-4], 0.5, rtol=1e-12)
    # No wholly valid 3x3 neighbourhood in the window: infinitely rough.
    sparse = np.full((6, 6), np.nan)
    sparse[::2, ::2] = 1.0
    assert np.isposinf(disparity_gradient(sparse, window_px=3)).all()


def test_features_carry_names_units_validity_and_the_optional_lr_disagreement():
    d = _disparity()
    lr = np.abs(np.random.default_rng(2).normal(size=d.shape))
    plain = compute_features(np.zeros(d.shape), None, d)
    checked = compute_features(np.zeros(d.shape), None, d, lr)
    assert plain.names == ("edge_distance_px", "texture", "disparity_gradient", "disparity_px")
    assert checked.names == ("edge_distance_px", "texture", "disparity_gradient", "lr_disagreement_px", "disparity_px")
    assert set(checked.names) <= set(FEATURE_UNITS)
    np.testing.assert_array_equal(checked.values["lr_disagreement_px"], lr)
    np.testing.assert_array_equal(checked.values["disparity_px"], d)
    np.testing.assert_array_equal(checked.valid, np.isfinite(d))
    assert checked.settings == {"edge_threshold_px": 1.0, "texture_window_px": 7}


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda d: compute_features(np.zeros((3, 3)), None, d), "left_grey"),
        (lambda d: compute_features(np.zeros(d.shape), np.zeros((2, 2)), d), "right_grey"),
        (lambda d: compute_features(np.zeros(d.shape), None, d, np.zeros((2, 2))), "lr_disagreement"),
        (lambda d: compute_features(np.zeros(d.shape), None, d, texture_window_px=4), "texture_window_px"),
        (lambda d: compute_features(np.zeros(d.shape), None, d, edge_threshold_px=0), "edge_threshold_px"),
        (lambda d: disparity_gradient(d, window_px=2), "texture_window_px"),
        (lambda d: compute_features(np.zeros(d.shape), None, d[0]), "disparity"),
    ],
)
def test_bad_input_names_the_argument(call, message):
    with pytest.raises(PrismapInputError, match=message):
        call(_disparity())


def test_only_the_features_asked_for_are_computed_and_they_are_the_full_ones():
    """A mapping run computes only the features its classes use (``ErrorModel.classify_frame``): the same values as
    when every feature is computed, ``disparity_px`` always, settings checked all the same, unknown names refused."""
    d = _disparity()
    grey = np.random.default_rng(3).integers(0, 255, d.shape).astype(np.uint8)
    full = compute_features(grey, None, d)
    some = compute_features(grey, None, d, names=("texture",))
    assert some.names == ("texture", "disparity_px")
    np.testing.assert_array_equal(some.values["texture"], full.values["texture"])
    assert compute_features(grey, None, d, np.ones(d.shape), names=()).names == ("disparity_px",)
    with pytest.raises(PrismapInputError, match=r"unknown feature\(s\) \['slant'\]"):
        compute_features(grey, None, d, names=("texture", "slant"))
    with pytest.raises(PrismapInputError, match="texture_window_px"):
        compute_features(grey, None, d, names=("edge_distance_px",), texture_window_px=4)


@pytest.mark.parametrize("feature", ["edge_distance_px", "texture", "disparity_gradient"])
def test_a_frames_classes_are_those_of_all_its_features(feature):
    """``ErrorModel.classify_frame`` computes only its classes' feature and labels every pixel as the classes do
    with every feature computed."""
    from support import conditioned_error_model

    d = _disparity()
    left = np.random.default_rng(5).integers(0, 255, (*d.shape, 3)).astype(np.uint8)
    grey = cv2.cvtColor(left, cv2.COLOR_RGB2GRAY)
    every = compute_features(grey, grey, d)
    values = every.values[feature][every.valid & np.isfinite(every.values[feature])]
    model = conditioned_error_model(feature=feature, edges=tuple(np.quantile(values, [0.3, 0.7])))
    labels = model.classify_frame(left, left, d)
    np.testing.assert_array_equal(labels, model.classify(every))
    assert len(np.unique(labels[labels >= 0])) == 3
