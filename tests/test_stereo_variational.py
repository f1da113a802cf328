"""The variational matcher: recovery of known disparities, its solver and kernels, its input checks."""

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg
from scipy import ndimage

from prismap.errors import PrismapInputError
from prismap.stereo import _kernels, make_matcher
from prismap.stereo._variational import VariationalMatcher, _v_cycle

HEIGHT, WIDTH = 96, 128
MARGIN = 8  # pixels kept away from the image borders when comparing with the truth
# Smooth scenes: a stronger smoothness weight than the default averages the uint8 quantisation noise
# (with fi = 50 the worst interior pixel is off by 0.11-0.18 px, the mean by 0.02).
SMOOTH = {"max_disparity": 16.0, "fi": 200.0}


def _texture(rng, height, width):
    """A smooth random grey texture (0-255 range), Gaussian-filtered white noise."""
    noise = ndimage.gaussian_filter(rng.standard_normal((height, width)), 2.0)
    return 128.0 + 60.0 * noise / noise.std()


def _pair(offset_px, slope_x, slope_y, seed=0):
    """Left and right uint8 images of a texture seen with disparity ``offset + slope_x x + slope_y y``.

    The left image samples the texture at (y, x); the right pixel (y, u) sees the left point x with
    ``x - d(x, y) = u``, i.e. ``x = (u + offset + slope_y y) / (1 - slope_x)``.
    """
    rng = np.random.default_rng(seed)
    pad = 40
    texture = _texture(rng, HEIGHT, WIDTH + 2 * pad)
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    left = ndimage.map_coordinates(texture, [rows, cols + pad], order=3)
    source = (cols + offset_px + slope_y * rows) / (1.0 - slope_x)
    right = ndimage.map_coordinates(texture, [rows, source + pad], order=3)
    truth = offset_px + slope_x * cols + slope_y * rows

    def as_uint8(image):
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)

    return as_uint8(left), as_uint8(right), truth


def _interior_error(disparity, truth, largest_px):
    """Largest |error| (pixels) away from the borders and the left strip the right image cannot see."""
    rows = slice(MARGIN, HEIGHT - MARGIN)
    cols = slice(int(np.ceil(largest_px)) + MARGIN, WIDTH - MARGIN)
    return float(np.max(np.abs(disparity[rows, cols] - truth[rows, cols])))


def test_constant_disparity_is_recovered_within_a_tenth_of_a_pixel():
    left, right, truth = _pair(7.3, 0.0, 0.0)
    disparity = VariationalMatcher(**SMOOTH).compute(left, right)
    assert disparity.dtype == np.float32 and disparity.shape == (HEIGHT, WIDTH)
    assert np.all(np.isfinite(disparity))
    assert _interior_error(disparity, truth, 7.3) < 0.1


@pytest.mark.parametrize("penalization", ["tichonov", "charbonnier", "perona-malik"])
@pytest.mark.parametrize("cycle", ["v", "none"])
def test_planar_disparity_is_recovered_by_every_penaliser_and_solver(penalization, cycle):
    left, right, truth = _pair(6.0, 0.03, 0.02)  # 6 .. 11.7 px across the image
    options = dict(SMOOTH, penalization=penalization, cycle=cycle, n_sweeps=6 if cycle == "v" else 20)
    disparity = VariationalMatcher(**options).compute(left, right)
    assert np.all(np.isfinite(disparity))
    assert _interior_error(disparity, truth, truth.max()) < 0.1
    # converged: twice the warps move no interior pixel by more than half the accuracy bar
    longer = VariationalMatcher(**dict(options, n_iter=6)).compute(left, right)
    assert _interior_error(longer, disparity, truth.max()) < 0.05


def test_initial_disparity_replaces_the_search_and_stays_at_the_truth():
    left, right, truth = _pair(6.0, 0.03, 0.02)
    matcher = VariationalMatcher(**SMOOTH)
    disparity = matcher.compute(left, right, initial_disparity=truth + 0.4)
    assert _interior_error(disparity, truth, truth.max()) < 0.1


def test_grey_and_rgb_input_give_one_disparity():
    left, right, _ = _pair(7.3, 0.0, 0.0)
    matcher = VariationalMatcher(max_disparity=16.0)
    grey = matcher.compute(left, right)
    rgb = matcher.compute(np.repeat(left[:, :, None], 3, axis=2), np.repeat(right[:, :, None], 3, axis=2))
    np.testing.assert_array_equal(grey, rgb)


def test_output_is_dense_and_inside_the_range_on_a_blank_pair():
    blank = np.full((40, 60), 90, dtype=np.uint8)
    disparity = VariationalMatcher(min_disparity=2.0, max_disparity=9.0).compute(blank, blank)
    assert np.all(np.isfinite(disparity))
    assert disparity.min() >= 2.0 and disparity.max() <= 9.0


def test_motorcycle_is_dense_and_at_most_a_quarter_of_pixels_are_bad():
    skimage_data = pytest.importorskip("skimage.data")
    left, right, truth = skimage_data.stereo_motorcycle()
    disparity = make_matcher("variational", max_disparity=64.0).compute(left, right)
    assert np.all(np.isfinite(disparity))
    valid = np.isfinite(truth)
    bad_1px = np.mean(np.abs(truth[valid] - disparity[valid]) > 1.0)
    assert bad_1px <= 0.25  # measured 0.191 with the defaults


def test_params_round_trip_through_the_registry():
    matcher = VariationalMatcher(levels=2, penalization="perona-malik", gamma=0.0, sgm_p2=0.0)
    again = make_matcher("variational", **matcher.params())
    assert again.params() == matcher.params()
    assert matcher.params()["penalization"] == "perona-malik"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"levels": 0}, "`levels` must be an integer >= 1; got 0"),
        ({"levels": 2.5}, "`levels` must be an integer >= 1; got 2.5"),
        ({"min_disparity": 20.0, "max_disparity": 10.0}, "`min_disparity` must be below `max_disparity`"),
        ({"max_disparity": float("inf")}, "`max_disparity` must be a finite number; got inf"),
        ({"pyr_scale": 1.0}, "`pyr_scale` must lie in (0, 1); got 1.0"),
        ({"pyr_scale": 0.0}, "`pyr_scale` must lie in (0, 1); got 0.0"),
        ({"penalization": "huber"}, "`penalization` must be one of"),
        ({"cycle": "w"}, "`cycle` must be one of"),
        ({"poly_n": 4}, "`poly_n` must be odd; got 4"),
        ({"gamma": -1.0}, "`gamma` must be a finite number >= 0; got -1.0"),
        ({"census_radius": 4}, "`census_radius` must be 1, 2 or 3; got 4"),
        ({"sgm_p1": 30.0, "sgm_p2": 10.0}, "`sgm_p1` must not exceed `sgm_p2`"),
    ],
)
def test_bad_parameters_are_named(options, message):
    with pytest.raises(PrismapInputError) as error:
        VariationalMatcher(**options)
    assert message in str(error.value)


@pytest.mark.parametrize(
    ("left", "right", "message"),
    [
        (np.zeros((20, 30), np.uint8), np.zeros((20, 31), np.uint8), "`left` and `right` must have one shape"),
        (
            np.zeros((20, 30), np.float32),
            np.zeros((20, 30), np.uint8),
            "`left` must be an (H, W) grey or (H, W, 3) RGB uint8 image; got shape (20, 30), dtype float32",
        ),
        (
            np.zeros((20, 30), np.uint8),
            np.zeros((2, 20, 30), np.uint8),
            "`right` must be an (H, W) grey or (H, W, 3) RGB uint8 image; got shape (2, 20, 30), dtype uint8",
        ),
        (np.zeros(30, np.uint8), np.zeros(30, np.uint8), "`left` must be an (H, W) grey or (H, W, 3) RGB uint8 image"),
    ],
)
def test_bad_images_are_named(left, right, message):
    with pytest.raises(PrismapInputError) as error:
        VariationalMatcher().compute(left, right)
    assert message in str(error.value)


def test_bad_initial_disparity_is_named():
    image = np.zeros((20, 30), np.uint8)
    with pytest.raises(PrismapInputError, match=r"`initial_disparity` must be a numeric \(20, 30\) array"):
        VariationalMatcher().compute(image, image, initial_disparity=np.zeros((20, 31)))
    with pytest.raises(PrismapInputError, match="contains NaN or inf"):
        VariationalMatcher().compute(image, image, initial_disparity=np.full((20, 30), np.nan))


# --- the solver and the kernels against slow numpy references --------------------------------------


def _system(seed, height=21, width=26):
    """A random instance of ``a x + sum_q w_pq (x_p - x_q) = b`` (some pixels without data)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.0, 4.0, (height, width)).astype(np.float32)
    a[rng.random((height, width)) < 0.3] = 0.0
    b = rng.normal(0.0, 10.0, (height, width)).astype(np.float32)
    wh = rng.uniform(0.1, 3.0, (height, width - 1)).astype(np.float32)
    wv = rng.uniform(0.1, 3.0, (height - 1, width)).astype(np.float32)
    x = rng.normal(0.0, 3.0, (height, width)).astype(np.float32)
    return x, a, b, wh, wv


def _system_matrix(a, wh, wv):
    """The sparse (H W, H W) matrix of the system: diag(a) plus the weighted graph Laplacian."""
    height, width = a.shape
    index = np.arange(height * width).reshape(height, width)
    rows, cols, vals = [index.ravel()], [index.ravel()], [a.ravel().astype(np.float64)]
    for p, q, w in ((index[:, :-1], index[:, 1:], wh), (index[:-1, :], index[1:, :], wv)):
        p, q, w = p.ravel(), q.ravel(), w.ravel().astype(np.float64)
        rows += [p, q, p, q]
        cols += [p, q, q, p]
        vals += [w, w, -w, -w]
    return scipy.sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(height * width,) * 2
    )


def test_jacobi_sweep_matches_a_numpy_reference():
    x, a, b, wh, wv = _system(1)
    x[0, 0] = 5.0
    a[0, 0] = 0.0
    omega = 0.8
    matrix = _system_matrix(a, wh, wv)
    diagonal = matrix.diagonal().reshape(x.shape)
    off_diagonal_times_x = (matrix @ x.ravel().astype(np.float64)).reshape(x.shape) - diagonal * x
    expected = (1.0 - omega) * x + omega * (b - off_diagonal_times_x) / diagonal
    out = np.empty_like(x)
    _kernels.jacobi_sweep(x, a, b, wh, wv, np.float32(omega), out)
    np.testing.assert_allclose(out, expected, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(
        _kernels.residual(x, a, b, wh, wv),
        b - (matrix @ x.ravel().astype(np.float64)).reshape(x.shape),
        rtol=1e-5,
        atol=1e-3,
    )


def test_v_cycles_converge_to_the_direct_solution():
    x, a, b, wh, wv = _system(2, height=40, width=52)
    exact = scipy.sparse.linalg.spsolve(_system_matrix(a, wh, wv).tocsc(), b.ravel().astype(np.float64))
    residuals = []
    for _ in range(40):
        x = _v_cycle(x, a, b, wh, wv, 6)
        residuals.append(np.abs(_kernels.residual(x, a, b, wh, wv)).max())
    assert residuals[-1] < 1e-3 * residuals[0]
    np.testing.assert_allclose(x.ravel(), exact, atol=1e-3 * np.abs(exact).max())


def _keys_cubic(row, positions):
    """Keys' cubic convolution (a = -0.5) of ``row`` at ``positions``, edge samples replicated.

    Kernel ``W(s) = 1.5|s|^3 - 2.5|s|^2 + 1`` for ``|s| <= 1``, ``-0.5|s|^3 + 2.5|s|^2 - 4|s| + 2`` for
    ``1 < |s| < 2``; the base sample is ``min(floor(u), n - 2)``, so ``u = n - 1`` uses offset 1.
    """

    def kernel(s):
        s = np.abs(s)
        return np.where(s <= 1, 1.5 * s**3 - 2.5 * s**2 + 1, np.where(s < 2, -0.5 * s**3 + 2.5 * s**2 - 4 * s + 2, 0))

    base = np.minimum(np.floor(positions), len(row) - 2).astype(int)
    return sum(kernel(positions - (base + m)) * row[np.clip(base + m, 0, len(row) - 1)] for m in (-1, 0, 1, 2))


def test_linearised_data_term_matches_a_numpy_reference():
    rng = np.random.default_rng(3)
    channels, height, width = 3, 7, 15
    left = rng.uniform(0, 255, (channels, height, width)).astype(np.float32)
    right = rng.uniform(0, 255, (channels, height, width)).astype(np.float32)
    right_dx = rng.normal(0, 20, (channels, height, width)).astype(np.float32)
    disparity = rng.uniform(-1.0, 6.0, (height, width)).astype(np.float32)  # some matches fall outside
    eps2 = np.float32(15.0**2)
    a = np.empty((height, width), np.float32)
    b = np.empty((height, width), np.float32)
    _kernels.linearise_data_term(left, right, right_dx, disparity, eps2, a, b)
    columns = np.arange(width)[None, :] - disparity.astype(np.float64)
    inside = (columns >= 0) & (columns <= width - 1)
    clipped = np.clip(columns, 0, width - 1)
    expected_a = np.zeros((height, width))
    expected_b = np.zeros((height, width))
    for c in range(channels):
        for i in range(height):
            warped = _keys_cubic(right[c, i].astype(np.float64), clipped[i])
            grad = _keys_cubic(right_dx[c, i].astype(np.float64), clipped[i])
            r = warped - left[c, i]
            weight = 1.0 / np.sqrt(1.0 + r**2 / eps2)
            expected_a[i] += weight * grad**2
            expected_b[i] += weight * (grad**2 * disparity[i] + grad * r)
    np.testing.assert_allclose(a, np.where(inside, expected_a, 0.0), rtol=1e-4, atol=1e-2)
    np.testing.assert_allclose(b, np.where(inside, expected_b, 0.0), rtol=1e-4, atol=1e-1)


def test_census_costs_and_path_aggregation_match_numpy_references():
    rng = np.random.default_rng(4)
    height, width, radius = 9, 12, 1
    left = rng.integers(0, 255, (height, width)).astype(np.float32)
    right = rng.integers(0, 255, (height, width)).astype(np.float32)

    def census(image):
        padded = np.pad(image, radius, mode="edge")
        bits = [
            padded[radius + di : radius + di + height, radius + dj : radius + dj + width] < image
            for di in range(-radius, radius + 1)
            for dj in range(-radius, radius + 1)
            if (di, dj) != (0, 0)
        ]
        return np.stack(bits)  # (8, H, W) booleans

    cl, cr = census(left), census(right)
    d_min, n_disp, outside = -1, 5, np.float32(4.0)
    expected = np.full((height, width, n_disp), outside, np.float32)
    for k in range(n_disp):
        for j in range(width):
            if 0 <= j - (d_min + k) < width:
                expected[:, j, k] = np.sum(cl[:, :, j] != cr[:, :, j - (d_min + k)], axis=0)
    cost = _kernels.census_cost_volume(
        _kernels.census_transform(left, radius), _kernels.census_transform(right, radius), d_min, n_disp, outside
    )
    np.testing.assert_array_equal(cost, expected)

    p1, p2 = np.float32(2.0), np.float32(7.0)
    total = np.zeros_like(cost, dtype=np.float64)
    for di, dj in [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]:
        path = np.zeros_like(total)
        order_i = range(height) if di >= 0 else range(height - 1, -1, -1)
        order_j = range(width) if dj >= 0 else range(width - 1, -1, -1)
        for i in order_i:
            for j in order_j:
                pi, pj = i - di, j - dj
                if not (0 <= pi < height and 0 <= pj < width):
                    path[i, j] = cost[i, j]
                    continue
                prev = path[pi, pj]
                step = np.minimum(np.r_[np.inf, prev[:-1]], np.r_[prev[1:], np.inf]) + p1
                path[i, j] = cost[i, j] + np.minimum(np.minimum(prev, step), prev.min() + p2) - prev.min()
        total += path
    np.testing.assert_allclose(_kernels.aggregate_paths(cost, p1, p2), total, rtol=1e-6)


def test_winner_take_all_fits_the_parabola_through_the_minimum():
    cost = np.array([[[5.0, 2.0, 1.0, 4.0, 6.0], [1.0, 3.0, 4.0, 5.0, 6.0]]], dtype=np.float32)
    disparity = _kernels.winner_take_all(cost, 3)
    # parabola through (1, 2), (2, 1), (3, 4): vertex at 2 + 0.5 (2 - 4) / (2 - 2 + 4) = 1.75
    np.testing.assert_allclose(disparity, [[3 + 1.75, 3.0]], rtol=1e-6)


def test_smoothness_weights_match_the_penalisers():
    rng = np.random.default_rng(5)
    disparity = rng.normal(0, 1, (6, 8)).astype(np.float32)
    fi, lam = 3.0, 0.5
    s_h, s_v = np.diff(disparity, axis=1), np.diff(disparity, axis=0)
    for penalty, psi in [
        (_kernels.PENALTY_TICHONOV, lambda s: np.ones_like(s)),
        (_kernels.PENALTY_CHARBONNIER, lambda s: 1.0 / np.sqrt(1.0 + s**2 / lam**2)),
        (_kernels.PENALTY_PERONA_MALIK, lambda s: 1.0 / (1.0 + s**2 / lam**2)),
    ]:
        wh = np.empty((6, 7), np.float32)
        wv = np.empty((5, 8), np.float32)
        _kernels.smoothness_weights(disparity, fi, lam, penalty, wh, wv)
        np.testing.assert_allclose(wh, fi * psi(s_h), rtol=1e-5)
        np.testing.assert_allclose(wv, fi * psi(s_v), rtol=1e-5)
