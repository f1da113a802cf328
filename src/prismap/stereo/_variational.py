"""A variational stereo matcher in the manner of OpenCV 2.4's ``cv::StereoVar`` (Kosov et al. 2009)."""

import cv2
import numpy as np

from prismap._validate import check_integer, check_positive, check_real
from prismap.errors import PrismapInputError
from prismap.stereo import _kernels
from prismap.stereo._base import StereoMatcher, check_stereo_pair, to_grey

_PENALTIES = {
    "tichonov": _kernels.PENALTY_TICHONOV,
    "charbonnier": _kernels.PENALTY_CHARBONNIER,
    "perona-malik": _kernels.PENALTY_PERONA_MALIK,
}
_CYCLES = ("v", "none")
_PARAMETERS = (
    "levels",
    "pyr_scale",
    "n_iter",
    "n_sweeps",
    "min_disparity",
    "max_disparity",
    "poly_n",
    "poly_sigma",
    "fi",
    "lambda_",
    "penalization",
    "cycle",
    "median_radius",
    "gamma",
    "data_epsilon",
    "census_radius",
    "sgm_p1",
    "sgm_p2",
)
_COARSEST_GRID_PX = 8  # the multigrid hierarchy stops once a side would drop below this


class VariationalMatcher(StereoMatcher):
    """Dense sub-pixel disparity by minimising a constancy + smoothness energy, coarse to fine.

    The energy of a disparity map ``d`` (pixels) of the left image is

        E(d) = sum_x sum_k psi_D((F_k^r(x - d(x)) - F_k^l(x))^2) + fi * sum_{x ~ y} psi_S((d(x) - d(y))^2)

    over 4-neighbour pairs. The features ``F`` are the grey image (0-255) and, with ``gamma > 0``, its
    x and y derivatives scaled by ``sqrt(gamma)`` (gradient constancy: robust to the exposure
    difference between the two cameras). ``psi_D`` is quadratic, or Charbonnier with ``data_epsilon``.
    On each pyramid level the data term is linearised around the current disparity (a "warp"), the
    penalisers' weights are lagged there (``psi_S``: Tichonov is quadratic, Charbonnier and
    Perona-Malik preserve edges), and the sparse linear system is solved approximately by Jacobi
    sweeps, plain or as a multigrid V-cycle (Galerkin coarsening, 2x2 aggregation). After every warp
    the disparity is clamped to the search range and optionally median-filtered (StereoVar's
    ``USE_MEDIAN_FILTERING``).

    Large disparities lie outside the basin of a linearisation, so the coarsest level starts from a
    global search: census-transform matching costs over the (scaled) disparity range, aggregated
    along 8 paths as in semi-global matching, winner-take-all with a parabolic sub-pixel fit. With more
    than one level that searched start is not refined on its own level (on Motorcycle refining it there
    loses accuracy): the warps run on the finer levels. An ``initial_disparity`` given to
    :meth:`compute` replaces the search and is refined on every level. Output is dense: pixels without
    a match (left-border occlusions, textureless areas) take the value the smoothness term propagates.

    Parameters
    ----------
    levels : int, default 3
        Pyramid levels including full resolution (StereoVar: 3).
    pyr_scale : float, default 0.5
        Size ratio between consecutive levels, in (0, 1) (StereoVar: 0.5).
    n_iter : int, default 3
        Warps (re-linearisations) per level (StereoVar: 5).
    n_sweeps : int, default 6
        Jacobi sweeps per warp. With ``cycle="v"`` they are split between pre- and post-smoothing of
        one V-cycle at every multigrid grid; with ``cycle="none"`` they are plain sweeps.
    min_disparity, max_disparity : float, default 0 and 64, pixels at full resolution
        Disparity range: searched on the coarsest level and clamped to on every level.
    poly_n : int, default 5
        Size (odd, pixels) of a Gaussian kernel smoothing each pyramid level before matching.
    poly_sigma : float, default 0.0
        Standard deviation (pixels) of that Gaussian; 0 (default) disables the smoothing, which on
        Motorcycle costs accuracy (bad-1px 19 % unsmoothed, 27 % with sigma 1).
    fi : float, default 50.0
        Smoothness weight, relative to squared feature derivatives of 0-255 images (StereoVar: 25).
    lambda_ : float, default 0.3, pixels
        Edge threshold of the Charbonnier and Perona-Malik penalisers: neighbour disparity differences
        well above it are smoothed less (StereoVar's ``lambda``; unused by Tichonov).
    penalization : {"tichonov", "charbonnier", "perona-malik"}, default "charbonnier"
        Smoothness penaliser ``psi_S``.
    cycle : {"v", "none"}, default "v"
        Multigrid V-cycle or plain Jacobi sweeps.
    median_radius : int, default 1
        Radius (pixels, 0-2) of the median filter applied after the search and each warp; 0 disables it.
    gamma : float, default 5.0
        Weight (>= 0) of the gradient-constancy features; 0 leaves brightness constancy alone.
    data_epsilon : float, default 0.0, grey levels
        Scale of the Charbonnier data penaliser (residuals well above it count less, as occlusions
        should); 0 keeps the quadratic data term of StereoVar.
    census_radius : int, default 2, pixels
        Half-width (1-3) of the census window of the coarsest-level search.
    sgm_p1, sgm_p2 : float, default 3 and 24, census bits
        Semi-global penalties of a 1-pixel and of a larger disparity step between path neighbours in
        the search (``0 <= sgm_p1 <= sgm_p2``); ``sgm_p2 = 0`` skips the aggregation (plain
        winner-take-all on the census costs).

    References
    ----------
    .. [1] S. Kosov, T. Thormaehlen, H.-P. Seidel, "Accurate real-time disparity estimation with
       variational methods", ISVC 2009, :DOI:`10.1007/978-3-642-10331-5_74`.
    .. [2] T. Brox, A. Bruhn, N. Papenberg, J. Weickert, "High accuracy optical flow estimation based
       on a theory for warping", ECCV 2004 (gradient constancy, lagged robust weights).
    .. [3] H. Hirschmuller, "Stereo processing by semiglobal matching and mutual information",
       IEEE TPAMI 30(2), 2008, :DOI:`10.1109/TPAMI.2007.1166`.
    """

    name = "variational"

    def __init__(
        self,
        *,
        levels=3,
        pyr_scale=0.5,
        n_iter=3,
        n_sweeps=6,
        min_disparity=0.0,
        max_disparity=64.0,
        poly_n=5,
        poly_sigma=0.0,
        fi=50.0,
        lambda_=0.3,
        penalization="charbonnier",
        cycle="v",
        median_radius=1,
        gamma=5.0,
        data_epsilon=0.0,
        census_radius=2,
        sgm_p1=3.0,
        sgm_p2=24.0,
    ):
        self.levels = _check_count(levels, "levels", minimum=1)
        pyr_scale = check_real(pyr_scale, "pyr_scale")
        if not 0.0 < pyr_scale < 1.0:
            raise PrismapInputError(f"`pyr_scale` must lie in (0, 1); got {pyr_scale!r}")
        self.pyr_scale = pyr_scale
        self.n_iter = _check_count(n_iter, "n_iter", minimum=1)
        self.n_sweeps = _check_count(n_sweeps, "n_sweeps", minimum=1)
        self.min_disparity = check_real(min_disparity, "min_disparity")
        self.max_disparity = check_real(max_disparity, "max_disparity")
        if self.min_disparity >= self.max_disparity:
            raise PrismapInputError(
                f"`min_disparity` must be below `max_disparity`; got {min_disparity!r} >= {max_disparity!r}"
            )
        self.poly_n = _check_count(poly_n, "poly_n", minimum=1)
        if self.poly_n % 2 == 0:
            raise PrismapInputError(f"`poly_n` must be odd; got {poly_n!r}")
        self.poly_sigma = check_real(poly_sigma, "poly_sigma", minimum=0.0)
        self.fi = check_positive(fi, "fi")
        self.lambda_ = check_positive(lambda_, "lambda_")
        if penalization not in _PENALTIES:
            raise PrismapInputError(f"`penalization` must be one of {list(_PENALTIES)}; got {penalization!r}")
        self.penalization = penalization
        if cycle not in _CYCLES:
            raise PrismapInputError(f"`cycle` must be one of {list(_CYCLES)}; got {cycle!r}")
        self.cycle = cycle
        self.median_radius = _check_count(median_radius, "median_radius", minimum=0)
        if self.median_radius > 2:
            raise PrismapInputError(f"`median_radius` must be 0, 1 or 2; got {median_radius!r}")
        self.gamma = check_real(gamma, "gamma", minimum=0.0)
        self.data_epsilon = check_real(data_epsilon, "data_epsilon", minimum=0.0)
        self.census_radius = _check_count(census_radius, "census_radius", minimum=1)
        if self.census_radius > 3:
            raise PrismapInputError(f"`census_radius` must be 1, 2 or 3; got {census_radius!r}")
        self.sgm_p1 = check_real(sgm_p1, "sgm_p1", minimum=0.0)
        self.sgm_p2 = check_real(sgm_p2, "sgm_p2", minimum=0.0)
        if self.sgm_p2 > 0.0 and self.sgm_p1 > self.sgm_p2:
            raise PrismapInputError(f"`sgm_p1` must not exceed `sgm_p2`; got {sgm_p1!r} > {sgm_p2!r}")

    def params(self):
        """The matcher's parameters as a JSON-serialisable dict (names as in the constructor)."""
        return {name: getattr(self, name) for name in _PARAMETERS}

    def compute(self, left, right, *, initial_disparity=None):
        """Disparity of ``left`` against ``right``.

        Parameters
        ----------
        left, right : (H, W) or (H, W, 3) uint8
            Rectified pair, grey or RGB, of one shape.
        initial_disparity : (H, W) float, pixels, optional
            Starting disparity (finite everywhere); resampled to the coarsest level, where it replaces
            the census search.

        Returns
        -------
        (H, W) float32, pixels
            Dense disparity of the left image (every pixel finite, within the disparity range).
        """
        left, right = check_stereo_pair(left, right)
        left_grey, right_grey = _grey_float(left), _grey_float(right)
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
            level_h, level_w = left_level.shape[1:]
            scale = level_w / width
            lo, hi = self.min_disparity * scale, self.max_disparity * scale
            if disparity is None:
                disparity = self._start(left_level, right_level, start, scale, lo, hi)
                if start is None and len(pyramid) > 1:
                    continue  # the searched start is better than its own coarse-level refinement
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
                    max(round(left.shape[1] * self.pyr_scale**level), 2),
                    max(round(left.shape[0] * self.pyr_scale**level), 2),
                )
                current_left = cv2.resize(current_left, size, interpolation=cv2.INTER_AREA)
                current_right = cv2.resize(current_right, size, interpolation=cv2.INTER_AREA)
            levels.append((self._features(current_left), self._features(current_right)))
        return levels

    def _features(self, image):
        """(K, H, W) float32 features of one level: the (smoothed) grey image, then its weighted derivatives."""
        if self.poly_sigma > 0.0 and self.poly_n > 1:
            image = cv2.GaussianBlur(
                image, (self.poly_n, self.poly_n), self.poly_sigma, borderType=cv2.BORDER_REPLICATE
            )
        channels = [image]
        if self.gamma > 0.0:
            root = np.float32(np.sqrt(self.gamma))
            channels += [root * _derivative(image, 1), root * _derivative(image, 0)]
        return np.stack(channels)

    def _start(self, left, right, start, scale, lo, hi):
        """Coarsest-level starting disparity: the resampled initial disparity, or the census semi-global search."""
        if start is not None:
            resized = cv2.resize(start, (left.shape[2], left.shape[1]), interpolation=cv2.INTER_AREA) * scale
            return np.clip(resized, lo, hi).astype(np.float32)
        census = [_kernels.census_transform(image[0], self.census_radius) for image in (left, right)]
        d_min = int(np.floor(lo))
        n_disp = int(np.ceil(hi)) - d_min + 1
        bits = (2 * self.census_radius + 1) ** 2 - 1
        cost = _kernels.census_cost_volume(census[0], census[1], d_min, n_disp, np.float32(bits / 2))
        if self.sgm_p2 > 0.0:
            cost = _kernels.aggregate_paths(cost, np.float32(self.sgm_p1), np.float32(self.sgm_p2))
        found = _kernels.winner_take_all(cost, d_min)
        if self.median_radius:
            found = cv2.medianBlur(found, 2 * self.median_radius + 1)
        return np.clip(found, lo, hi).astype(np.float32)

    def _refine(self, left, right, disparity, lo, hi):
        """``n_iter`` warps of one level: linearise, lag the smoothness weights, solve, clamp, filter."""
        right_dx = _derivative(right, 2)
        height, width = left.shape[1:]
        a = np.empty((height, width), dtype=np.float32)
        b = np.empty((height, width), dtype=np.float32)
        wh = np.empty((height, width - 1), dtype=np.float32)
        wv = np.empty((height - 1, width), dtype=np.float32)
        penalty = _PENALTIES[self.penalization]
        for _ in range(self.n_iter):
            _kernels.linearise_data_term(left, right, right_dx, disparity, np.float32(self.data_epsilon**2), a, b)
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


def _derivative(array, axis):
    """Central difference of ``array`` along ``axis`` (one-sided at the ends), same shape."""
    out = np.empty_like(array)
    inner = [slice(None)] * array.ndim
    ahead, behind = list(inner), list(inner)
    inner[axis], ahead[axis], behind[axis] = slice(1, -1), slice(2, None), slice(None, -2)
    out[tuple(inner)] = 0.5 * (array[tuple(ahead)] - array[tuple(behind)])
    for end, a, b in ((0, 1, 0), (-1, -1, -2)):
        index = [slice(None)] * array.ndim
        ia, ib = list(index), list(index)
        index[axis], ia[axis], ib[axis] = end, a, b
        out[tuple(index)] = array[tuple(ia)] - array[tuple(ib)]
    return out


def _check_count(value, name, *, minimum):
    return check_integer(value, name, expected=f"an integer >= {minimum}", condition=lambda n: n >= minimum)


def _grey_float(image):
    """(H, W) float32 grey 0-255 of a validated uint8 image, at least 2x2 pixels."""
    if min(image.shape[:2]) < 2:
        raise PrismapInputError(f"images must be at least 2x2 pixels; got shape {image.shape}")
    return to_grey(image).astype(np.float32)
