"""A variational stereo matcher in the manner of OpenCV 2.4's ``cv::StereoVar`` (Kosov et al. 2009)."""

import cv2
import numpy as np

from prismap._validate import check_positive
from prismap.errors import PrismapInputError
from prismap.stereo import _kernels
from prismap.stereo._base import StereoMatcher

_PENALTIES = {
    "tichonov": _kernels.PENALTY_TICHONOV,
    "charbonnier": _kernels.PENALTY_CHARBONNIER,
    "perona-malik": _kernels.PENALTY_PERONA_MALIK,
}
_CYCLES = ("v", "none")
_COARSEST_GRID_PX = 8  # the multigrid hierarchy stops once a side would drop below this


class VariationalMatcher(StereoMatcher):
    """Dense sub-pixel disparity by minimising a brightness-constancy + smoothness energy, coarse to fine.

    The energy of a disparity map ``d`` (pixels) of the left image is

        E(d) = sum_x (I_r(x - d(x)) - I_l(x))^2 + fi * sum_{x ~ y} psi((d(x) - d(y))^2)

    over 4-neighbour pairs, with ``I`` the grey images (0-255, Gaussian-smoothed). On each level of an
    image pyramid (coarsest first) the data term is linearised around the current disparity
    (a "warp"), the smoothness penaliser's weights are lagged at that disparity (Tichonov: quadratic;
    Charbonnier and Perona-Malik: edge-preserving, recomputed each warp), and the resulting sparse
    linear system is solved approximately with Jacobi sweeps, either plain or as a multigrid V-cycle
    (Galerkin coarsening with 2x2 aggregation). The disparity is clamped to the search range after
    every warp and optionally median-filtered, as StereoVar's ``USE_MEDIAN_FILTERING`` does.

    Large disparities lie outside the basin of a linearisation, so the coarsest level starts from a
    cheap winner-take-all block-matching search over the (scaled) disparity range, or from the
    ``initial_disparity`` given to :meth:`compute`. Output is dense: pixels without a match (left
    border occlusions, textureless areas) take the value the smoothness term propagates there.

    Parameters
    ----------
    levels : int, default 3
        Pyramid levels including full resolution (StereoVar: 3).
    pyr_scale : float, default 0.5
        Size ratio between consecutive levels, in (0, 1) (StereoVar: 0.5).
    n_iter : int, default 5
        Warps (re-linearisations) per level (StereoVar: 5).
    n_sweeps : int, default 6
        Jacobi sweeps per warp. With ``cycle="v"`` they are split between pre- and post-smoothing of
        one V-cycle at every multigrid grid; with ``cycle="none"`` they are plain sweeps.
    min_disparity, max_disparity : float, default 0 and 64, pixels at full resolution
        Disparity range: searched on the coarsest level and clamped to on every level.
    poly_n : int, default 5
        Size (odd, pixels) of the Gaussian kernel smoothing each pyramid level before matching.
    poly_sigma : float, default 1.0
        Standard deviation (pixels) of that Gaussian; 0 disables the smoothing.
    fi : float, default 25.0
        Smoothness weight, relative to squared intensity gradients of 0-255 images (StereoVar: 25).
    lambda_ : float, default 0.3, pixels
        Edge threshold of the Charbonnier and Perona-Malik penalisers: neighbour disparity differences
        well above it are smoothed less (StereoVar's ``lambda``; unused by Tichonov).
    penalization : {"tichonov", "charbonnier", "perona-malik"}, default "charbonnier"
    cycle : {"v", "none"}, default "v"
        Multigrid V-cycle or plain Jacobi sweeps.
    median_radius : int, default 1
        Radius (pixels) of the median filter applied after each warp; 0 disables it.
    search_radius : int, default 2
        Half-width (pixels, coarsest level) of the block-matching window of the initial search.

    References
    ----------
    .. [1] S. Kosov, T. Thormaehlen, H.-P. Seidel, "Accurate real-time disparity estimation with
       variational methods", ISVC 2009, :DOI:`10.1007/978-3-642-10331-5_74`.
    """

    name = "variational"

    def __init__(
        self,
        *,
        levels=3,
        pyr_scale=0.5,
        n_iter=5,
        n_sweeps=6,
        min_disparity=0.0,
        max_disparity=64.0,
        poly_n=5,
        poly_sigma=1.0,
        fi=25.0,
        lambda_=0.3,
        penalization="charbonnier",
        cycle="v",
        median_radius=1,
        search_radius=2,
    ):
        self.levels = _check_int(levels, "levels", minimum=1)
        pyr_scale = float(pyr_scale)
        if not 0.0 < pyr_scale < 1.0:
            raise PrismapInputError(f"`pyr_scale` must lie in (0, 1); got {pyr_scale!r}")
        self.pyr_scale = pyr_scale
        self.n_iter = _check_int(n_iter, "n_iter", minimum=1)
        self.n_sweeps = _check_int(n_sweeps, "n_sweeps", minimum=1)
        self.min_disparity = float(min_disparity)
        self.max_disparity = float(max_disparity)
        if not (np.isfinite(self.min_disparity) and np.isfinite(self.max_disparity)):
            raise PrismapInputError(
                f"disparity range must be finite; got min {min_disparity!r}, max {max_disparity!r}"
            )
        if self.min_disparity >= self.max_disparity:
            raise PrismapInputError(
                f"`min_disparity` must be below `max_disparity`; got {min_disparity!r} >= {max_disparity!r}"
            )
        self.poly_n = _check_int(poly_n, "poly_n", minimum=1)
        if self.poly_n % 2 == 0:
            raise PrismapInputError(f"`poly_n` must be odd; got {poly_n!r}")
        self.poly_sigma = float(poly_sigma)
        if not (np.isfinite(self.poly_sigma) and self.poly_sigma >= 0.0):
            raise PrismapInputError(f"`poly_sigma` must be a finite number >= 0; got {poly_sigma!r}")
        self.fi = check_positive(fi, "fi")
        self.lambda_ = check_positive(lambda_, "lambda_")
        if penalization not in _PENALTIES:
            raise PrismapInputError(f"`penalization` must be one of {list(_PENALTIES)}; got {penalization!r}")
        self.penalization = penalization
        if cycle not in _CYCLES:
            raise PrismapInputError(f"`cycle` must be one of {list(_CYCLES)}; got {cycle!r}")
        self.cycle = cycle
        self.median_radius = _check_int(median_radius, "median_radius", minimum=0)
        if self.median_radius > 2:
            raise PrismapInputError(f"`median_radius` must be 0, 1 or 2; got {median_radius!r}")
        self.search_radius = _check_int(search_radius, "search_radius", minimum=0)

    def params(self):
        """The matcher's parameters as a JSON-serialisable dict (names as in the constructor)."""
        return {
            "levels": self.levels,
            "pyr_scale": self.pyr_scale,
            "n_iter": self.n_iter,
            "n_sweeps": self.n_sweeps,
            "min_disparity": self.min_disparity,
            "max_disparity": self.max_disparity,
            "poly_n": self.poly_n,
            "poly_sigma": self.poly_sigma,
            "fi": self.fi,
            "lambda_": self.lambda_,
            "penalization": self.penalization,
            "cycle": self.cycle,
            "median_radius": self.median_radius,
            "search_radius": self.search_radius,
        }

    def compute(self, left, right, *, initial_disparity=None):
        """Disparity of ``left`` against ``right``.

        Parameters
        ----------
        left, right : (H, W) or (H, W, 3) uint8
            Rectified pair, grey or RGB, of one shape.
        initial_disparity : (H, W) float, pixels, optional
            Starting disparity (finite everywhere); resampled to the coarsest level, where it replaces
            the block-matching search.

        Returns
        -------
        (H, W) float32, pixels
            Dense disparity of the left image (every pixel finite, within the disparity range).
        """
        left_grey = _as_grey(left, "left")
        right_grey = _as_grey(right, "right")
        if left_grey.shape != right_grey.shape:
            raise PrismapInputError(
                f"`left` and `right` must have one shape; got {np.shape(left)} and {np.shape(right)}"
            )
        height, width = left_grey.shape
        start = None
        if initial_disparity is not None:
            start = np.asarray(initial_disparity)
            if start.shape != (height, width) or not np.issubdtype(start.dtype, np.number):
                raise PrismapInputError(
                    f"`initial_disparity` must be a numeric ({height}, {width}) array like `left`; "
                    f"got shape {start.shape}, dtype {start.dtype}"
                )
            start = start.astype(np.float32)
            if not np.all(np.isfinite(start)):
                raise PrismapInputError("`initial_disparity` must be finite everywhere; it contains NaN or inf")

        pyramid = self._pyramid(left_grey, right_grey)
        disparity = None
        for left_level, right_level in reversed(pyramid):
            level_h, level_w = left_level.shape
            scale = level_w / width
            lo, hi = self.min_disparity * scale, self.max_disparity * scale
            if disparity is None:
                disparity = self._start(left_level, right_level, start, scale, lo, hi)
            else:
                ratio = level_w / disparity.shape[1]
                disparity = cv2.resize(disparity, (level_w, level_h), interpolation=cv2.INTER_LINEAR) * ratio
            disparity = self._refine(left_level, right_level, disparity, lo, hi)
        return np.ascontiguousarray(disparity, dtype=np.float32)

    def _pyramid(self, left, right):
        """[(left, right)] from full resolution down, each smoothed by the ``poly_n``/``poly_sigma`` Gaussian."""
        levels = []
        current_left, current_right = left, right
        for level in range(self.levels):
            if level > 0:
                size = (
                    max(int(round(left.shape[1] * self.pyr_scale**level)), 2),
                    max(int(round(left.shape[0] * self.pyr_scale**level)), 2),
                )
                current_left = cv2.resize(current_left, size, interpolation=cv2.INTER_AREA)
                current_right = cv2.resize(current_right, size, interpolation=cv2.INTER_AREA)
            levels.append((self._smooth(current_left), self._smooth(current_right)))
        return levels

    def _smooth(self, image):
        if self.poly_sigma == 0.0 or self.poly_n == 1:
            return image
        return cv2.GaussianBlur(image, (self.poly_n, self.poly_n), self.poly_sigma, borderType=cv2.BORDER_REPLICATE)

    def _start(self, left, right, start, scale, lo, hi):
        """Coarsest-level starting disparity: the resampled initial disparity, or a block-matching search."""
        if start is not None:
            resized = cv2.resize(start, (left.shape[1], left.shape[0]), interpolation=cv2.INTER_AREA) * scale
            return np.clip(resized, lo, hi).astype(np.float32)
        found = _kernels.block_matching_search(left, right, int(np.ceil(lo)), int(np.floor(hi)), self.search_radius)
        return np.clip(found, lo, hi).astype(np.float32)

    def _refine(self, left, right, disparity, lo, hi):
        """``n_iter`` warps of one level: linearise, lag the smoothness weights, solve, clamp, filter."""
        right_dx = np.empty_like(right)
        right_dx[:, 1:-1] = 0.5 * (right[:, 2:] - right[:, :-2])
        right_dx[:, 0] = right[:, 1] - right[:, 0]
        right_dx[:, -1] = right[:, -1] - right[:, -2]
        height, width = left.shape
        a = np.empty_like(left)
        b = np.empty_like(left)
        wh = np.empty((height, width - 1), dtype=np.float32)
        wv = np.empty((height - 1, width), dtype=np.float32)
        penalty = _PENALTIES[self.penalization]
        for _ in range(self.n_iter):
            _kernels.linearise_data_term(left, right, right_dx, disparity, a, b)
            _kernels.smoothness_weights(disparity, self.fi, self.lambda_, penalty, wh, wv)
            if self.cycle == "v":
                disparity = _v_cycle(disparity, a, b, wh, wv, self.n_sweeps)
            else:
                disparity = _kernels.jacobi(disparity, a, b, wh, wv, self.n_sweeps, 1.0)
            np.clip(disparity, lo, hi, out=disparity)
            if self.median_radius:
                disparity = cv2.medianBlur(disparity, 2 * self.median_radius + 1)
        return disparity


_SMOOTHING_OMEGA = 0.8  # damped Jacobi: plain Jacobi leaves the checkerboard error mode undamped


def _v_cycle(x, a, b, wh, wv, n_sweeps):
    """One multigrid V-cycle on ``a x + L_w x = b``: pre-smooth, coarse-grid correction, post-smooth.

    The coarse system is the Galerkin product ``P^T A P`` for piecewise-constant prolongation ``P`` on
    2x2 blocks, which keeps the same form (data coefficients and edge weights), so one kernel serves
    every grid. Recurses until a side would drop below ``_COARSEST_GRID_PX``.
    """
    pre = max(n_sweeps // 2, 1)
    post = max(n_sweeps - pre, 1)
    x = _kernels.jacobi(x, a, b, wh, wv, pre, _SMOOTHING_OMEGA)
    height, width = x.shape
    if min(height, width) >= 2 * _COARSEST_GRID_PX:
        r = _kernels.residual(x, a, b, wh, wv)
        a_c = _kernels.restrict_sum(a)
        wh_c, wv_c = _kernels.coarsen_edges(wh, wv, height, width)
        correction = _v_cycle(np.zeros_like(a_c), a_c, _kernels.restrict_sum(r), wh_c, wv_c, n_sweeps)
        _kernels.add_prolonged(x, correction)
    return _kernels.jacobi(x, a, b, wh, wv, post, _SMOOTHING_OMEGA)


def _check_int(value, name, *, minimum):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise PrismapInputError(f"`{name}` must be an integer >= {minimum}; got {value!r}")
    return int(value)


def _as_grey(image, name):
    """(H, W) float32 grey 0-255 from a grey or RGB uint8 image, or raise naming ``name``."""
    array = np.asarray(image)
    if array.dtype != np.uint8 or not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] == 3)):
        raise PrismapInputError(
            f"`{name}` must be a (H, W) or (H, W, 3) uint8 image; got shape {array.shape}, dtype {array.dtype}"
        )
    if min(array.shape[:2]) < 2:
        raise PrismapInputError(f"`{name}` must be at least 2x2 pixels; got shape {array.shape}")
    if array.ndim == 3:
        array = cv2.cvtColor(np.ascontiguousarray(array), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(array, dtype=np.float32)
