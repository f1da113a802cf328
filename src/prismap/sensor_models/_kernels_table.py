"""numba kernels that build PRISM's tables: one node grid per (measured disparity, surface rate), packed
back to back with a metadata row each (:data:`META_COLUMNS`), with the nodes' derivatives in the rate."""

import math

import numba as nb
import numpy as np

from prismap.sensor_models._kernel_args import Geometry
from prismap.sensor_models._kernels_failure import table_start
from prismap.sensor_models._kernels_influence import INFLUENCE_LEVELS, level_bounds, tight_influence_nodes
from prismap.sensor_models._kernels_march import (
    _exp_term,
    _march,
    _march_x,
    x_of_z,
    z_of_x,
)
from prismap.sensor_models._kernels_math import fast_exp, fast_log, fast_log1mexp, logaddexp

MAX_COARSE = 128
"""Most nodes of a table's coarse front (up to the measured depth): its spacing widens beyond ``coarse_ratio h``
rather than exceed them. There ``log(C/Z) < coarse_below``, near-quadratic in x, and cubic Hermite interpolation
with the asymptotic's slopes stays within the tables' tolerance at any spacing the cap gives (tests)."""

_STEEP = 0.02
"""Bound on ``|phi''| / phi'^2`` (``phi = log(q g)``), the relative error of the endpoint asymptotic of C that
a table's coarse front uses."""

NODE_COLUMNS = 10
"""Columns of a PRISM table node as :func:`prism_table` builds it: log(C/Z), its x-derivative, its first
log(lambda)-derivative and that one's x-derivative, its second log(lambda)-derivative; then the same five for
``D = Z - C`` (from column :data:`_D_COLUMN`)."""
_D_COLUMN = NODE_COLUMNS // 2


@nb.njit(cache=True, nogil=True)
def _log_qg_derivatives(z, lam, shift, geometry, mixture):
    """``phi = log(q g)`` at depth ``z`` and its first and second derivatives in z (1/metre, 1/metre^2).

    Parameters
    ----------
    z : float, metres of depth
        Where, after ``z0``.
    lam : float, per metre of depth
        Surface rate of the prior ``q(z) = lam e^{-lam (z - z0)}``.
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    geometry : Geometry
        ``z0`` and ``fb`` are read (:class:`~prismap.sensor_models._kernel_args.Geometry`).
    mixture : Mixture
        The error mixture (:class:`~prismap.sensor_models._kernel_args.Mixture`).
    """
    z0, fb = geometry.z0, geometry.fb
    log_wn, means, sigmas = mixture
    u = fb / z
    best = -np.inf
    total = 0.0
    slope = 0.0  # sum of weights times d N_j / du / N_j
    bend = 0.0  # sum of weights times d^2 N_j / du^2 / N_j
    for j in range(means.size):
        t = (u - shift - means[j]) / sigmas[j]
        v = log_wn[j] - 0.5 * t * t
        if v > best:
            scale = math.exp(best - v)
            total *= scale
            slope *= scale
            bend *= scale
            best = v
            e = 1.0
        else:
            e = math.exp(v - best)
        total += e
        slope -= e * t / sigmas[j]
        bend += e * (t * t - 1.0) / (sigmas[j] * sigmas[j])
    return _phi_from_sums(z, lam, math.log(lam), best, math.log(total), slope / total, bend / total, z0, fb)


@nb.njit(cache=True, nogil=True, inline="always")
def _phi_from_sums(z, lam, log_lam, best, log_total, slope, bend, z0, fb):
    """``phi = log(q g)`` and its first two z-derivatives from ``g``'s sums at ``u = fb / z``: ``log g = best +
    log_total``, ``slope = g_u / g`` and ``bend = g_uu / g`` (derivatives in u)."""
    g_u = slope  # d log g / du
    g_uu = bend - g_u * g_u
    u_z = -fb / (z * z)
    phi = log_lam - lam * (z - z0) + best + log_total
    return phi, -lam + g_u * u_z, g_uu * u_z * u_z - 2.0 * g_u * u_z / z


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _log_qg_rows(z, lam, shift, geometry, mixture, phi, phi_z, phi_zz):
    """:func:`_log_qg_derivatives` at every depth of ``z`` ((N,) metres) into ``phi``, ``phi_z``, ``phi_zz``, in
    loops over the depths that LLVM vectorises (each depth's terms against its largest; exps by
    :func:`~prismap.sensor_models._kernels_march._exp_term`, logs by :func:`fast_log`)."""
    z0, fb = geometry.z0, geometry.fb
    log_wn, means, sigmas = mixture
    n = z.size
    terms = np.empty((means.size, n))
    for q in range(n):
        phi[q] = -np.inf  # the largest term, until the end
    for j in range(means.size):
        for q in range(n):
            t = (fb / z[q] - shift - means[j]) / sigmas[j]
            terms[j, q] = log_wn[j] - 0.5 * t * t
            phi[q] = max(phi[q], terms[j, q])
    total = np.zeros(n)
    slope = np.zeros(n)
    bend = np.zeros(n)
    for j in range(means.size):
        inv = 1.0 / sigmas[j]
        for q in range(n):
            t = (fb / z[q] - shift - means[j]) * inv
            e = _exp_term(terms[j, q] - phi[q])
            total[q] += e
            slope[q] -= e * t * inv
            bend[q] += e * (t * t - 1.0) * inv * inv
    log_lam = math.log(lam)
    for q in range(n):
        phi[q], phi_z[q], phi_zz[q] = _phi_from_sums(
            z[q], lam, log_lam, phi[q], fast_log(total[q]), slope[q] / total[q], bend[q] / total[q], z0, fb
        )


@nb.njit(cache=True, nogil=True)
def _steep(x, lam, shift, geometry, mixture, bound):
    """Whether ``q g`` rises steeply at ``x`` (x units): ``phi' > 0`` and ``|phi''| / phi'^2 <= bound``
    (``phi = log(q g)``; the endpoint asymptotic of ``C`` holds to about ``bound``); other parameters as
    :func:`_log_qg_derivatives`'s."""
    _, slope, curvature = _log_qg_derivatives(z_of_x(x, lam, geometry.ku), lam, shift, geometry, mixture)
    return slope > 0.0 and abs(curvature) <= bound * slope * slope


_STEEP_END = _STEEP / 8
"""Steepness bound (as :data:`_STEEP`) up to which a coarse front's last interval reaches: its cubic Hermite
interpolation over a wide interval needs ``log C`` nearer quadratic than the asymptotic's own bound gives (at
``_STEEP`` a far measurement's front cells were 3 % off, 1.7x the tolerance)."""

_BISECTIONS = 12
"""Bisections that place a coarse front's last node where ``C/Z`` reaches ``e^coarse_below`` (to 1/4096 of an
interval)."""

_FIT_MARGIN = 0.5
"""How far below ``coarse_below`` (log) a coarse front's last node is placed once the march's Z is known, so that
the next march's Z, equal to rounding, keeps it."""


@nb.njit(cache=True, nogil=True)
def _log_c_asymptotic(z, lam, shift, geometry, mixture):
    """``log C(z)`` where ``q g`` rises steeply, ``C = q g / (d log(q g)/dz) (1 + O(phi''/phi'^2))``, and its
    derivative in x, ``(phi' - phi''/phi') / (dx/dz)``; parameters as :func:`_log_qg_derivatives`'s (``ku`` of
    ``geometry`` is read too)."""
    phi, phi_z, phi_zz = _log_qg_derivatives(z, lam, shift, geometry, mixture)
    return phi - math.log(phi_z), _front_slope(phi_z, phi_zz, z, lam, geometry.ku)


@nb.njit(cache=True, nogil=True, inline="always")
def _front_slope(phi_z, phi_zz, z, lam, ku):
    """The x-derivative of the asymptotic ``log C`` (:func:`_log_c_asymptotic`) from ``phi``'s z-derivatives:
    ``(phi' - phi''/phi') / (dx/dz)``."""
    return (phi_z - phi_zz / phi_z) / (lam + ku / (z * z))


@nb.njit(cache=True, nogil=True, inline="always")
def _rate_derivatives(ratio_1, ratio_2, far, lam, z_far):
    """First and second derivatives of ``log Q`` in ``log lam`` from the ratios of Q's moments to Q, ``M_1 / Q``
    and ``M_2 / Q`` (metres, metres^2), and ``far = F / Q``.

    ``Q = J + F``: ``J = int lam e^{-lam s} g`` has moments ``M_k``; the far term ``F = e^{-lam L} g_far``
    (``L = z_far``; 0 when absent) carries no factor ``lam``. For one mass at ``s``,
    ``J' = J (1 - lam s)`` and ``J'' = J (1 - 3 lam s + lam^2 s^2)``; ``F' = -lam L F``,
    ``F'' = (lam^2 L^2 - lam L) F``.
    """
    m1 = lam * ratio_1
    m2 = lam * lam * ratio_2
    lam_l = lam * z_far
    j = 1.0 - far
    m1 -= far * lam_l
    m2 -= far * lam_l * lam_l
    first = j - m1 - far * lam_l
    second = j - 3.0 * m1 + m2 + far * (lam_l * lam_l - lam_l)
    return first, second - first * first


@nb.njit(cache=True, nogil=True)
def _log_rate_derivatives(log_m, log_far, lam, z_far):
    """:func:`_rate_derivatives` from the logs of Q's moments ``log_m`` (3,) and of its far term ``log_far``."""
    return _rate_derivatives(
        math.exp(log_m[1] - log_m[0]), math.exp(log_m[2] - log_m[0]), math.exp(log_far - log_m[0]), lam, z_far
    )


@nb.njit(cache=True, nogil=True, inline="always")
def _rate_columns(slope, first, second, z_1, z_2, lam_s):
    """A node's three rate columns for ``log(Q/Z)`` (Q is C or D): its first log(lam)-derivative, that one's
    x-derivative, and its second log(lam)-derivative.

    ``first``, ``second`` are Q's own (:func:`_rate_derivatives`), ``z_1``, ``z_2`` Z's, ``slope`` is
    ``d log Q/dx`` and ``lam_s = lam (z - z0)``. As ``dQ/dz = +-q g`` and ``d log(q g)/d log lam = 1 - lam s``
    at fixed z, ``d first/dx = slope (1 - lam s - first)`` (Z's derivatives do not depend on z): the exact
    slope, so that the first-order term is cubic Hermite in x like the value, and a short cell's share
    ``C(c) - C(a)`` follows the rate where ``log C`` grows slowly (in front of the measurement), where the
    secant slope of a linear interpolation is off by up to 25 % of it.
    """
    return first - z_1, slope * (1.0 - lam_s - first), second - z_2


@nb.njit(cache=True, nogil=True, inline="always")
def _exp_difference_into(out, log_a, log_b):
    """``out = exp(log_a - log_b)`` ((N,) each) by :func:`fast_exp`, in one loop that vectorises."""
    for q in range(out.size):
        out[q] = fast_exp(log_a[q] - log_b[q])


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _node_columns(columns, z, log_c, log_d, front_slope, log_qg, log_z, z_1, z_2, log_far_w, z_far, lam, geometry):
    """Fill ``columns`` ((:data:`NODE_COLUMNS`, N): the nodes' columns, each contiguous, so that the loop over the
    nodes vectorises) from the logs of ``C`` and ``D`` and their moments at the nodes ``z`` ((N,) metres of depth;
    ``log_c``, ``log_d`` (3, N)) and ``log_qg`` ((N,), ``log(q g)``).

    The x-slope of ``log C`` is ``front_slope`` where that is a number (the coarse front's asymptotic), else
    ``q g / C`` over ``dx/dz``; a node with ``C = 0`` has 0 in C's derivative columns. ``log_z``, ``z_1``,
    ``z_2``: ``log Z`` and its derivatives in ``log lam``; ``log_far_w``, ``z_far``: D's far term
    (:func:`_rate_derivatives`); the other parameters as :func:`prism_table`'s.
    """
    z0, ku = geometry.z0, geometry.ku
    n = z.size
    exps = np.empty((7, n))  # the loops of exps apart from the arithmetic: each vectorises
    _exp_difference_into(exps[0], log_c[1], log_c[0])
    _exp_difference_into(exps[1], log_c[2], log_c[0])
    _exp_difference_into(exps[2], log_qg, log_c[0])
    _exp_difference_into(exps[3], log_d[1], log_d[0])
    _exp_difference_into(exps[4], log_d[2], log_d[0])
    _exp_difference_into(exps[5], log_qg, log_d[0])
    for q in range(n):
        exps[6, q] = fast_exp(log_far_w - log_d[0, q])
    for q in range(n):
        lam_s = lam * (z[q] - z0)
        dx_dz = lam + ku / (z[q] * z[q])
        first, second = _rate_derivatives(exps[0, q], exps[1, q], 0.0, lam, z_far)
        slope = front_slope[q] if front_slope[q] == front_slope[q] else exps[2, q] / dx_dz
        col_2, col_3, col_4 = _rate_columns(slope, first, second, z_1, z_2, lam_s)
        c_on = log_c[0, q] > -np.inf
        columns[0, q] = log_c[0, q] - log_z
        columns[1, q] = slope if c_on else 0.0
        columns[2, q] = col_2 if c_on else 0.0
        columns[3, q] = col_3 if c_on else 0.0
        columns[4, q] = col_4 if c_on else 0.0
        first, second = _rate_derivatives(exps[3, q], exps[4, q], exps[6, q], lam, z_far)
        slope = -exps[5, q] / dx_dz
        columns[_D_COLUMN, q] = log_d[0, q] - log_z
        columns[_D_COLUMN + 1, q] = slope
        columns[_D_COLUMN + 2, q], columns[_D_COLUMN + 3, q], columns[_D_COLUMN + 4, q] = _rate_columns(
            slope, first, second, z_1, z_2, lam_s
        )


_FAR_RATIO = 4
"""A table's march past its influence node: panels about this many times the fine width (:func:`_march`)."""

MAX_RUNS = 12
"""Most leading runs of a table's march (:func:`_march_runs`); beyond, the march stays fine to its end."""

N_SEGMENTS = MAX_RUNS + 3
"""Segments of a table's node grid, each uniform in x: the coarse front, the march's leading runs, its fine run to
the influence node, and the back (empty ones where a table has fewer runs). The look-up kernels compile it (and
the metadata columns) in: numba's cache does not see a change here, so clear ``__pycache__`` after one."""


@nb.njit(cache=True, nogil=True)
def _march_runs(x_split, shift, lam, geometry, spec):
    """The leading runs of a table's march from ``x_split``: ``(counts, widths)``, each (:data:`MAX_RUNS`,), the
    spacing profile's pieces (``spec.edges``, ``spec.ratios``: ``_prism_spacing.spacing_profile``) placed on the
    table's x axis; fine panels follow to the end.

    A piece of ratio ``r > 1`` is spaced ``r h`` where an interval spans at most ``wide_efolds`` prior e-folds,
    and fine beyond; a gap (ratio 0) is two panels whatever the prior (``q g`` is negligible there). Runs
    coarser than fine end at a whole panel before their piece does (and 4 panels before ``z_max``), fine ones
    a whole panel after it (at most 2 fine steps before ``z_max``), so coarse spacing never reaches into a finer
    piece. Parameters as :func:`prism_table`'s; ``x_split`` in x units.
    """
    z0, z_max, fb, ku = geometry
    h, edges, ratios, wide_efolds = spec.h, spec.edges, spec.ratios, spec.wide_efolds
    x_end = x_of_z(z_max, lam, ku)
    counts = np.zeros(MAX_RUNS, dtype=np.int64)
    widths = np.full(MAX_RUNS, h)
    n_runs = 0
    x = x_split
    targets = np.empty(2)
    spacing = np.empty(2)
    for m in range(ratios.size):
        u = shift + edges[m + 1]  # the piece's least true disparity: its far end
        x_piece = x_end if u <= fb / z_max else min(x_of_z(fb / u, lam, ku), x_end)
        if x_piece <= x:
            continue
        n_parts = 1
        targets[0], spacing[0] = x_piece, h
        if ratios[m] == 0:  # two panels across the gap, if it is wider than 4 fine ones
            targets[0] = min(x_piece, x_end - 2.0 * h)
            spacing[0] = max(0.5 * (targets[0] - x), h)
        elif ratios[m] > 1:
            spacing[0] = ratios[m] * h
            x_lam = x_end
            if spacing[0] > wide_efolds:  # an interval spans dz = H / (lam + ku / z^2)
                x_lam = min(x_end, x_of_z(math.sqrt(ku / (lam * (spacing[0] / wide_efolds - 1.0))), lam, ku))
            targets[0] = min(x_piece, x_lam, x_end - 4.0 * spacing[0])
            targets[1], spacing[1] = x_piece, h
            n_parts = 2
        for p in range(n_parts):
            if spacing[p] > h:
                k = 2 if ratios[m] == 0 and spacing[p] > 2.0 * h else int((targets[p] - x) / spacing[p])
            else:
                k = int(math.ceil((min(targets[p], x_end - 2.0 * h) - x) / h))
            if k <= 0:
                continue
            if n_runs > 0 and widths[n_runs - 1] == spacing[p]:
                counts[n_runs - 1] += k
            elif n_runs < MAX_RUNS:
                counts[n_runs] = k
                widths[n_runs] = spacing[p]
                n_runs += 1
            else:
                return counts, widths  # no room: fine from here
            x += k * spacing[p]
    return counts, widths


@nb.njit(cache=True, nogil=True, inline="always")
def _coarse_spacing(x0, x_measured, spec):
    """x-spacing of a coarse front from ``x0`` (x units): ``coarse_ratio h``, or wider where that would put more than
    :data:`MAX_COARSE` nodes before the measured depth's ``x_measured``."""
    return max(spec.coarse_ratio * spec.h, (x_measured - x0) / MAX_COARSE)


_START_TRIES = 3
"""Placements :func:`_first_x` tries for a table's start before the failure floor."""


@nb.njit(cache=True, nogil=True)
def _first_x(z_floor, x_measured, shift, lam, geometry, spec, mixture):
    """x (x units) of a table's first node: far enough before ``z_floor`` (:func:`table_start`, metres) that the
    intervals a look-up integrates on the spot (``_kernels_lookup._log_c_first``: the coarse front's first, or the
    march's first two without one) end at or before it, where every ray's cells are at their floor, and after
    ``near_m`` (``geometry.z0``); ``near_m`` itself when the floor is there. Each try places the start that far
    before the floor for the intervals a start there has, up to :data:`_START_TRIES` times; parameters as
    :func:`prism_table`'s, ``x_measured`` its coarse front's end."""
    z_near, _, _, ku = geometry
    x_near = x_of_z(z_near, lam, ku)
    x_floor = x_of_z(z_floor, lam, ku)
    x0 = x_floor
    if z_floor <= z_near:
        return x_near
    for _ in range(_START_TRIES):
        h_coarse = _coarse_spacing(x0, x_measured, spec)
        if _steep(x0 + h_coarse, lam, shift, geometry, mixture, _STEEP):  # a coarse front (phi' needs no z0)
            reach = h_coarse
        else:
            counts, widths = _march_runs(x0, shift, lam, geometry, spec)
            reach = 2.0 * (widths[0] if counts[0] > 0 else spec.h)
        if x0 + reach <= x_floor or x0 == x_near:
            break
        x0 = max(x_floor - reach, x_near)
    return x0


@nb.njit(cache=True, nogil=True)
def prism_table(shift, lam, log_far, geometry, spec, mixture):
    """The table of one (d^, lam): a node per march panel, every ``coarse_ratio``-th one where C/Z is tiny.

    Node columns (see :data:`NODE_COLUMNS`): ``log(C/Z)``, ``d log(C/Z)/dx``, the first and second
    derivatives of ``log(C/Z)`` in ``log lam`` (from the moments, :func:`_rate_derivatives`), the first one
    followed by its x-derivative (:func:`_rate_columns`), and the same five for ``D = Z - C``. Nodes are uniform
    in x on each of :data:`N_SEGMENTS` segments: the coarse front up to ``x_split``, spaced at most
    ``coarse_ratio h`` (or wider, where that would put more than :data:`MAX_COARSE` nodes before the measured
    depth), evenly so that its last node lies where ``C/Z`` reaches ``e^coarse_below`` or ``q g`` stops rising
    steeply at :data:`_STEEP_END` (to 1/4096 of an interval by bisection); the march's leading runs
    (:func:`_march_runs`: the mixture's spacing profile); fine nodes to a node past the influence depth (beyond
    which only the cells that straddle it look up); then four equal intervals to the end of the march. The
    march's panels are the node intervals (:data:`_MARCH_GL`-point Gauss-Legendre is exact far below the tolerance
    on half a narrowest sigma, and where only wider components matter on a quarter of the narrowest of them), and
    past the influence node, where only the four back intervals remain, :data:`_FAR_RATIO` times wider
    (:func:`_march`).

    Before ``x_split`` ``q g`` rises steeply (``|phi''| / phi'^2 < _STEEP``, ``phi = log(q g)``) and
    ``C/Z < e^coarse_below``: there ``C`` is its endpoint (Laplace) asymptotic ``q g / (q g)'`` (relative
    error about ``phi''/phi'^2``), all its mass at ``z``; quadrature starts at ``x_split``. Where the march's
    ``Z`` shows the front reaching above ``e^coarse_below``, the front is placed again (once, with
    :data:`_FIT_MARGIN` to spare) and the march repeated.

    Parameters
    ----------
    shift : float, pixels
        The table's measured disparity plus ``doffs``.
    lam : float, per metre of depth
        The table's surface rate.
    log_far : float, log(1/pixel)
        Log density of the far measurement: ``g`` averaged over true disparities below ``fb / z_max``.
    geometry : Geometry
        Depth range and disparity scales (:class:`~prismap.sensor_models._kernel_args.Geometry`).
    spec : TableSpec
        Node spacing and the influence cut (:class:`~prismap.sensor_models._kernel_args.TableSpec`): the names
        above (``h``, ``coarse_ratio``, ...) are its fields.
    mixture : Mixture
        The error mixture (:class:`~prismap.sensor_models._kernel_args.Mixture`).

    Returns
    -------
    nodes : (N, NODE_COLUMNS) float64, log and its derivatives in x and log lam
    meta : (3 N_SEGMENTS + 5 + 2 INFLUENCE_LEVELS,) float64
        Per segment its first x, its first row and its spacing; then ``z_end`` (last node), the influence depths
        of each level for cells of any length and of bounded length (``_kernels_influence``; level 0 of the
        first is ``z_infl``),
        ``log Z`` and its first and second derivatives in ``log lam`` (a ray's ``log Z`` by the Taylor
        term of the nodes, for the look-ups that integrate on the spot at the ray's own rate), and ``z_start``.

    A table starts at ``z_start`` (:func:`~prismap.sensor_models._kernels_failure.table_start`), ``z0`` for a model
    without matcher failures: cells ending before are at their ray's failure floor and never looked up, and the
    nodes are those of a prior whose survival starts there, ``C(z) = int_z_start^z q g`` up to the constant
    ``e^{lam (z_start - z0)}`` that ``Z`` shares, so ``C/Z`` and its derivatives are the model's to far below the
    tolerance (the part of ``C`` before ``z_start`` is below ``e^-40`` of ``Z``); ``log Z`` and its derivatives
    are the model's, from ``z0``.
    """
    z_near, z_max, fb, ku = geometry
    h, log_eps_bound, lam_slack, _, coarse_below = spec[:5]
    x_end = x_of_z(z_max, lam, ku)
    # The coarse front ends before the measured depth; at most MAX_COARSE nodes up to there (a class with a
    # 0.01 px component puts the measurement hundreds of thousands of x units after near_m).
    x_measured = x_of_z(min(z_max, fb / shift), lam, ku) if shift > 0.0 else x_end
    x0 = _first_x(
        table_start(shift, lam, log_far, geometry, spec, mixture), x_measured, shift, lam, geometry, spec, mixture
    )
    z0 = z_of_x(x0, lam, ku)
    geometry = Geometry(z0, z_max, fb, ku)  # the prior's survival from the table's start (see Returns)
    h_coarse = _coarse_spacing(x0, x_measured, spec)
    n_steep = 0  # coarse nodes after z0 where q g is steep
    while x0 + (n_steep + 2) * h_coarse < x_end and _steep(
        x0 + (n_steep + 1) * h_coarse, lam, shift, geometry, mixture, _STEEP
    ):
        n_steep += 1
    if 0 < n_steep < MAX_COARSE and x0 + (n_steep + 2) * h_coarse < x_end:
        # The steep part ends within the next interval: the front's nodes, evenly a little closer, reach it
        lo, hi = x0 + n_steep * h_coarse, x0 + (n_steep + 1) * h_coarse
        for _ in range(_BISECTIONS):
            mid = 0.5 * (lo + hi)
            if _steep(mid, lam, shift, geometry, mixture, _STEEP_END):
                lo = mid
            else:
                hi = mid
        if lo > x0 + n_steep * h_coarse:
            n_steep += 1
            h_coarse = (lo - x0) / n_steep
    log_c_start = np.empty(3)
    n_coarse = n_steep
    log_z = np.nan
    refit = True
    while True:  # once, or twice (or three times) if the first Z shows the steep part reaching above e^coarse_below
        x_split = x0 + n_coarse * h_coarse
        z_split = z_of_x(x_split, lam, ku) if n_coarse > 0 else z0
        log_c_start[:] = -np.inf  # no front: C starts at 0 in z0 (a refit may drop the whole front)
        if n_coarse > 0:
            log_c = _log_c_asymptotic(z_split, lam, shift, geometry, mixture)[0]
            log_s = math.log(z_split - z0)
            for k in range(3):
                log_c_start[k] = log_c + k * log_s
        counts, widths = _march_runs(x_split, shift, lam, geometry, spec)
        z, log_c, log_d, log_z, log_far_w, i_infl, i_far, h_far = _march(
            shift,
            lam,
            log_far,
            z_split,
            log_c_start,
            counts,
            widths,
            h,
            level_bounds(log_eps_bound),
            lam_slack,
            (counts[0] if widths[0] != h else 0) + 2,  # not within a coarse first run
            _FAR_RATIO,
            geometry,
            mixture,
        )
        fit = n_coarse
        while fit > 0 and not (  # NaN: q g falls there (a bump of g before the front's end), no asymptotic
            _log_c_asymptotic(z_of_x(x0 + fit * h_coarse, lam, ku), lam, shift, geometry, mixture)[0] - log_z
            < coarse_below
        ):
            fit -= 1
        if fit == n_coarse:
            break
        n_coarse = fit
        if fit > 0 and refit:  # the front's last node, a little closer, where C/Z reaches e^coarse_below
            refit = False
            lo, hi = x0 + fit * h_coarse, x0 + (fit + 1) * h_coarse
            for _ in range(_BISECTIONS):
                mid = 0.5 * (lo + hi)
                log_c = _log_c_asymptotic(z_of_x(mid, lam, ku), lam, shift, geometry, mixture)[0]
                if log_c - log_z < coarse_below - _FIT_MARGIN:
                    lo = mid
                else:
                    hi = mid
            if lo > x0 + fit * h_coarse:
                n_coarse = fit + 1
                h_coarse = (lo - x0) / n_coarse
    n = z.size - 1
    starts = np.zeros(MAX_RUNS + 1, dtype=np.int64)  # first node of each leading run, then of the fine run after
    starts[1:] = np.cumsum(counts)
    widths = np.concatenate((widths, np.full(1, h)))
    last = MAX_RUNS
    while starts[last] >= n:
        last -= 1
    uniform = starts[last]  # first node of the uniform run of panels that ends the march
    for r in range(last - 1, -1, -1):
        if starts[r] < starts[r + 1]:
            if widths[r] != widths[last]:
                break
            uniform = starts[r]
    # fine up to a node past the influence depth, then 4 equal intervals to the end (on the march's nodes)
    first_back = max(min(i_infl[0] + 1, n), uniform)
    back_width = widths[last]
    if i_far >= 0:  # the march's far panels: 4 equal intervals of them from i_far
        first_back = i_far
        back_width = h_far
    back = (n - first_back) // 4
    n_back = 4 if back > 0 else 0
    i_back = n - n_back * back
    z_far = z_max - z0 if log_far_w > -np.inf else z[-1] - z0
    log_total = np.empty(3)
    for k in range(3):
        log_total[k] = logaddexp(log_c[-1, k], log_d[-1, k])
    z_1, z_2 = _log_rate_derivatives(log_total, log_far_w, lam, z_far)
    n_rows = n_coarse + i_back + 1 + n_back
    z_rows = np.empty(n_rows)
    c_rows = np.empty((3, n_rows))  # logs of C and its moments at each node, one moment a row (vectorised loops)
    d_rows = np.empty((3, n_rows))
    march_node = np.empty(n_rows - n_coarse, dtype=np.int64)  # row n_coarse + j: the march's node march_node[j]
    for j in range(march_node.size):
        march_node[j] = j if j <= i_back else i_back + (j - i_back) * back
    z_rows[0] = z0
    for row in range(1, n_coarse + 1):
        z_rows[row] = z_of_x(x0 + row * h_coarse, lam, ku)
    for j in range(1, march_node.size):
        z_rows[n_coarse + j] = z[march_node[j]]
    log_qg = np.empty(n_rows)
    phi_z = np.empty(n_rows)
    phi_zz = np.empty(n_rows)
    _log_qg_rows(z_rows, lam, shift, geometry, mixture, log_qg, phi_z, phi_zz)
    # The coarse front (rows 1 to n_coarse): C by its endpoint asymptotic (:func:`_log_c_asymptotic`), all its mass
    # at the node; its x-slope also at x_split, where the march takes over C.
    front_slope = np.full(n_rows, np.nan)
    for row in range(1, n_coarse + 1):
        front_slope[row] = _front_slope(phi_z[row], phi_zz[row], z_rows[row], lam, ku)
    for k in range(3):
        c_rows[k, 0] = -np.inf
        for row in range(1, n_coarse):
            c_rows[k, row] = log_qg[row] - fast_log(phi_z[row]) + k * fast_log(z_rows[row] - z0)
        for row in range(n_coarse):  # D = everything minus the (tiny) C
            d_rows[k, row] = log_total[k] + fast_log1mexp(c_rows[k, row] - log_total[k])
        for j in range(march_node.size):
            c_rows[k, n_coarse + j] = log_c[march_node[j], k]
            d_rows[k, n_coarse + j] = log_d[march_node[j], k]
    columns = np.empty((NODE_COLUMNS, n_rows))
    _node_columns(
        columns, z_rows, c_rows, d_rows, front_slope, log_qg, log_z, z_1, z_2, log_far_w, z_far, lam, geometry
    )
    nodes = columns.T
    nodes[0, 2:_D_COLUMN] = nodes[1, 2:_D_COLUMN]
    meta = np.empty(3 * N_SEGMENTS + 5 + 2 * INFLUENCE_LEVELS)
    x_march = x_of_z(z[0], lam, ku)
    meta[0], meta[N_SEGMENTS], meta[2 * N_SEGMENTS] = x0, 0, h_coarse
    for r in range(MAX_RUNS + 1):
        i = min(starts[r], i_back)
        meta[1 + r] = _march_x(i, x_march, counts, widths[:MAX_RUNS], h)
        meta[N_SEGMENTS + 1 + r] = n_coarse + i
        meta[2 * N_SEGMENTS + 1 + r] = widths[r]
    meta[N_SEGMENTS - 1] = _march_x(i_back, x_march, counts, widths[:MAX_RUNS], h)
    meta[2 * N_SEGMENTS - 1] = n_coarse + i_back
    meta[3 * N_SEGMENTS - 1] = max(back, 1) * back_width
    cut = lam * (z0 - z_near)  # Z from z_near: e^-cut times the table's (C(z0) is below its floor)
    meta[3 * N_SEGMENTS] = z[n]
    meta[3 * N_SEGMENTS + 1 : 3 * N_SEGMENTS + 1 + INFLUENCE_LEVELS] = z[i_infl]
    i_tight = tight_influence_nodes(z, log_c, log_far, lam, lam_slack, log_eps_bound, shift, geometry, mixture)
    meta[3 * N_SEGMENTS + 1 + INFLUENCE_LEVELS : 3 * N_SEGMENTS + 1 + 2 * INFLUENCE_LEVELS] = z[i_tight]
    meta[3 * N_SEGMENTS + 1 + 2 * INFLUENCE_LEVELS :] = log_z - cut, z_1 - cut, z_2 - cut, z0
    return nodes, meta
