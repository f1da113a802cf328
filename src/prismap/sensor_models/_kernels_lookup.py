"""numba kernels of PRISM's tabulated cell update: table look-ups (cubic Hermite in x with a Taylor term in the
rate) and the combination in linear space except near underflow (the keys that find the tables are
``_kernels_pack.table_keys``).

The tabulated update exponentiates the smaller of ``log C`` and ``log D`` and combines in linear space; its exp
and log are the vectorised :func:`~prismap.sensor_models._kernels_math.exp_into` and
:func:`~prismap.sensor_models._kernels_math.log_into`.
"""

import math

import numba as nb
import numpy as np

from prismap.sensor_models._kernel_args import Geometry, Mixture
from prismap.sensor_models._kernels_direct import combine, log_tail, pass_through_log
from prismap.sensor_models._kernels_failure import blend_cell, blend_ratios_into, floor_depth
from prismap.sensor_models._kernels_march import log_integral
from prismap.sensor_models._kernels_math import exp_into, fast_exp, fast_log, log1mexp, log_into
from prismap.sensor_models._kernels_pack import (
    _C_END,
    _D_SHIFT,
    _LAM,
    _LENGTH,
    _LOG_FAR,
    _LOG_HALF,
    _LOG_QUARTER,
    _LOG_Z,
    _LOG_Z_1,
    _LOG_Z_2,
    _OFFSET,
    _ROW,
    _SHIFT,
    _SPACING,
    _X,
    _Z_END,
    _Z_INFL,
    _Z_START,
)
from prismap.sensor_models._kernels_table import N_SEGMENTS, _log_qg_derivatives

_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}  # never nnan/ninf: NaN marks values not looked up

_FAR_IN_FRONT = -600.0
"""``log(C/Z)`` at a cell's end below which the cell is far in front of the measurement: ``D/Z = 1`` there to far
below float64's precision (:func:`_far_in_front`)."""


@nb.njit(cache=True, nogil=True, inline="always")
def _locate(x, s, seg_x, seg_row, seg_inv, n_seg):
    """Row (from the table's first) of the node left of ``x``, the fraction to the next, and the segment:
    the last of the ``n_seg`` non-empty segments (``seg_x``, ``seg_row``, ``seg_inv``: first x, first row,
    inverse spacing; ``seg_row[n_seg]`` is the table's last row) that starts at or before ``x``, or the first.

    The search starts at segment ``s`` (the previous look-up's): along a ray, where x only grows, it costs
    a comparison or two.
    """
    while s > 0 and x < seg_x[s]:
        s -= 1
    while s + 1 < n_seg and x >= seg_x[s + 1]:
        s += 1
    v = (x - seg_x[s]) * seg_inv[s]
    k = min(max(int(v), 0), seg_row[s + 1] - seg_row[s] - 1)
    return seg_row[s] + k, min(max(v - k, 0.0), 1.0), s


@nb.njit(cache=True, nogil=True, inline="always")
def _interpolate(nodes, o, f, step, col, delta):
    """Column ``col`` at fraction ``f`` between rows ``o`` and ``o + 1``, for a rate ``e^delta`` times the table's.

    The value plus the first-order Taylor term in ``log lambda`` (column ``col + 2``) at each node, cubic
    Hermite in x with their x-derivatives (columns ``col + 1``, ``col + 3``), plus the second-order term
    (column ``col + 4``), linear in x (its factor ``delta^2 / 2`` is at most 1/800 at a half step of the rate
    grid).
    """
    g = 1.0 - f
    half = 0.5 * delta
    y_0 = nodes[o, col] + delta * nodes[o, col + 2]
    y_1 = nodes[o + 1, col] + delta * nodes[o + 1, col + 2]
    s_0 = nodes[o, col + 1] + delta * nodes[o, col + 3]
    s_1 = nodes[o + 1, col + 1] + delta * nodes[o + 1, col + 3]
    return (
        (1.0 + 2.0 * f) * g * g * y_0
        + f * f * (3.0 - 2.0 * f) * y_1
        + f * g * step * (g * s_0 - f * s_1)
        + half * delta * (g * nodes[o, col + 4] + f * nodes[o + 1, col + 4])
    )


@nb.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _cell_prior(x):
    """``(1 - e^-x, e^-x)`` for ``x >= 0``: below 0.2 a degree-8 series in Estrin form (relative error
    < 1e-11, no dependency chain), else through :func:`fast_exp`; both are computed and one selected, so
    that a loop over cells stays branch-free."""
    q = fast_exp(-x)
    x2 = x * x
    p = x * (
        (1.0 - 0.5 * x)
        + x2 * (1.0 / 6.0 - x * (1.0 / 24.0))
        + x2 * x2 * ((1.0 / 120.0 - x * (1.0 / 720.0)) + x2 * (1.0 / 5040.0 - x * (1.0 / 40320.0)))
    )
    small = x < 0.2
    return (p if small else 1.0 - q), (1.0 - p if small else q)


@nb.njit(cache=True, nogil=True)
def combine_small(l_a, l_c, a_is_d, c_is_d, lam_len):
    """:func:`combine` from the log of the smaller of ``C/Z``, ``D/Z`` at each end (``*_is_d``: it is D's).

    The other one is ``log(1 - e^small)``. Cells far in front of the measurement go through
    :func:`_far_in_front` instead.
    """
    other_a = log1mexp(l_a)
    other_c = log1mexp(l_c)
    return combine(
        other_a if a_is_d else l_a,
        l_a if a_is_d else other_a,
        other_c if c_is_d else l_c,
        l_c if c_is_d else other_c,
        lam_len,
    )


@nb.njit(cache=True, nogil=True)
def _log_c_first(z, steep, lam, shift, h, z_start, geometry, mixture):
    """``log C(z)`` in a table's first interval, or its first two without a steep front (``z_start < z``), from the
    table's start ``z_start`` (``C``'s part before it is below the ray's floor): Gauss-Legendre
    panels of x-width at most ``h``, the first interval's, as the table's march integrated them (8 points here,
    :data:`_MARCH_GL` there: they agree to about 1e-10), or where ``q g`` rises steeply (``steep``: the
    interval is in the coarse front) the endpoint asymptotic with the start's cut, ``C = q g / phi' (1 -
    e^{-phi' (z - z_start)})``, exact for an exponential ``q g``. Without a steep front ``q g`` is not negligible
    at ``z_start``, ``C`` grows like ``z - z_start`` and ``log C`` like ``log(z - z_start)``, which a cubic over the
    second interval misses by up to 0.016 nats.

    Parameters
    ----------
    z : float, metres of depth
        Where, in the table's first interval (or second, without a steep front).
    steep : bool
        The table has a coarse front.
    lam : float, per metre of depth
        The ray's surface rate.
    shift : float, pixels
        The ray's measured disparity plus ``doffs``.
    h : float, x units
        x-width of the table's first interval: the widest panel.
    geometry : Geometry
        Depth range and disparity scales (:class:`~prismap.sensor_models._kernel_args.Geometry`).
    mixture : Mixture
        The error mixture (:class:`~prismap.sensor_models._kernel_args.Mixture`).
    """
    if not steep:
        return log_integral(z_start, z, lam, shift, h, geometry, mixture)
    phi, phi_z, _ = _log_qg_derivatives(z, lam, shift, geometry, mixture)
    return phi - math.log(phi_z) + log1mexp(-phi_z * (z - z_start))


_SKIP = 4
"""``side`` flag of a cell the measurement does not change (empty, or beyond the influence depth)."""

_FLOOR = 8
"""``side`` flag of a cell at its ray's failure floor (:func:`~prismap.sensor_models._kernels_failure.floor_depth`):
not looked up, its failure-free likelihood ratio taken as 0 (thinned: the pass-through chance)."""


@nb.njit(cache=True, nogil=True, inline="always")
def _ray_floor(shift, log_z, log_floor, z_start, geometry, mixture):
    """Depth (metres) up to which a cell's end leaves the cell at its ray's failure floor (:data:`_FLOOR`):
    ``floor_depth`` (``z0`` for a ``log_floor`` of ``-inf``: no floor), or the table's start ``z_start`` if later."""
    return max(floor_depth(shift, log_z, log_floor, geometry.fb, geometry.z0, mixture), z_start)


@nb.njit(cache=True, nogil=True)
def ray_floor_depths(tables, log_z, log_floor, model_of_ray, geometry, models):
    """Per ray, :func:`_ray_floor` as :func:`prism_table_lookup` finds it, at most the influence depth: ``(R,)``
    float64. ``tables`` as the look-up's, ``log_z`` ((R,) log) each ray's ``Z`` (``PrismModel._ray_log_z``),
    ``log_floor`` ((R,) log, or (0,): no floor) its floor level, ``model_of_ray`` ((R,) int) its row of ``models`` (a
    :class:`~prismap.sensor_models._kernel_args.MixtureSet`)."""
    table, _, meta, _ = tables
    depth = np.empty(table.size)
    for r in range(table.size):
        t, k = table[r], model_of_ray[r]
        n = models.size[k]
        mixture = Mixture(models.log_wn[k, :n], models.means[k, :n], models.sigmas[k, :n])
        level = log_floor[r] if log_floor.size else -np.inf
        depth[r] = min(
            _ray_floor(meta[t, _SHIFT], log_z[r], level, meta[t, _Z_START], geometry, mixture), meta[t, _Z_INFL]
        )
    return depth


@nb.njit(cache=True, nogil=True, fastmath=_FASTMATH)
def prism_table_lookup(lam, stretch, tables, cells, lo, hi, hq, geometry, mixture, log_floor, l_a, l_c, side, lam_len):
    """First stage of tabulated PRISM on cells ``lo:hi``: per cell end, the log of the smaller of C/Z, D/Z.

    A cell is ``[start[i], end[i] + stretch[r]]`` (``stretch``: the ray's voxel overhang share, depth metres).
    Per ray one table (``table[r]``, the ray's rate ``e^delta[r]`` times the table's). A look-up
    interpolates ``log(C/Z)`` and, only where ``C/Z > 1/2``, ``log(D/Z)`` (``C/Z + D/Z = 1``); past a depth
    of the ray already found to have ``C/Z >= 1/2`` only ``log(D/Z)``, as ``C`` only grows. Writes
    ``l_a[j], l_c[j]`` (cell ``lo + j``) and ``side[j]`` (bit 0: ``l_a`` is D's, bit 1: ``l_c`` is D's, or
    :data:`_SKIP`: no change), and ``lam_len[j]``, the cell's prior rate times its length (of the part in
    ``[z0, z_max]``; a skipped cell's whole length). A cell starting where the previous one of the same ray ended reuses that
    look-up (ray casting emits cells in order; with a stretch no start is a previous end). A cell across
    ``C/Z = 1/2`` (``D`` the smaller at its end only) whose start has ``C/Z >= 1/4`` takes ``D`` at its start
    too, so that its share ``C(c) - C(a) = D(a) - D(c)`` is a difference within one column: with the Taylor
    terms in ``log lambda``, at a half step of the rate grid and where most of ``C`` lies many prior e-folds
    before the measurement, the table's ``C/Z + D/Z`` misses 1 by up to 1e-3, as much as a short cell's share
    there. A start with ``C/Z < 1/4`` keeps its ``C`` (accurate relative to itself, which a ``1 - D/Z`` is not
    near 0): that cell's share is above 1/4, and the miss is small against it. Cells starting
    beyond the influence depth are skipped, cells ending before the ray's failure floor depth (``log_floor``) are
    flagged :data:`_FLOOR` without a look-up; for a cell ending beyond the table (where the remaining
    evidence is below e^-40 of C), ``D(c)`` is integrated on the spot, and so is ``C`` in the table's first
    interval (first two without a steep front, :func:`_log_c_first`): both at the ray's own rate, over the
    ray's ``Z`` (the table's by the nodes' Taylor term, from the meta columns ``log_z_1``, ``log_z_2``), not the
    table's rate and ``Z``. A cell across its ray's floor takes ``C(a) = 0`` in those intervals (without failures the
    floor is the table's start, where it is): that moves its ratio by at most ``q_c^2 C(a) / (Z p_c)``, and ``C(a) <=
    e^(log_floor - 40) Z`` there, so its blended increment by at most ``e^-40 / p_c``.

    Parameters
    ----------
    lam : (R,) float64, per metre of depth
        Each ray's surface rate.
    stretch : (R,) float64, metres of depth
        Added to the end of each of the ray's cells.
    tables : RayTables
        Each ray's table (:class:`~prismap.sensor_models._kernel_args.RayTables`).
    cells : Cells
        The cells ``[start[i], end[i] + stretch[r]]`` (:class:`~prismap.sensor_models._kernel_args.Cells`).
    lo, hi : int
        The cells of this call.
    hq : float, x units
        Panel width of the tail marched beyond a table (:func:`log_tail`).
    geometry : Geometry
        Depth range and disparity scales (:class:`~prismap.sensor_models._kernel_args.Geometry`).
    mixture : Mixture
        The error mixture (:class:`~prismap.sensor_models._kernel_args.Mixture`).
    log_floor : (R,) float64, log, or (0,)
        Each ray's ``log(fail)`` (or ``log`` of the pass-through chance) for
        :func:`~prismap.sensor_models._kernels_failure.floor_depth`; empty: no failure blend, no floor.
    l_a, l_c : (hi - lo,) float64, log
        Written: the smaller of ``log(C/Z)``, ``log(D/Z)`` at each cell's start and end.
    side : (hi - lo,) int8
        Written: which of the two each is, or :data:`_SKIP`, :data:`_FLOOR`.
    lam_len : (hi - lo,) float64
        Written: each cell's prior rate times its length (dimensionless).
    """
    z0, z_max, fb, ku = geometry
    table, delta, meta, nodes = tables
    ray_of_cell, start, end = cells
    r_prev = -1
    c_prev = -1.0
    lcc = 0.0
    c_is_d = 0
    seg_x = np.empty(N_SEGMENTS)
    seg_h = np.empty(N_SEGMENTS)
    seg_inv = np.empty(N_SEGMENTS)
    seg_row = np.empty(N_SEGMENTS + 1, dtype=np.int64)
    lam_t = lam_r = z_end = z_infl = z_start = dl = shift = log_z = log_far = stretch_r = z_floor = 0.0
    floors = log_floor.size > 0
    z_half = np.inf
    off = off_d = c_end = n_seg = s_a = s_c = n_first = 0
    h_first = 0.0
    steep = False
    for i in range(lo, hi):
        j = i - lo
        r = ray_of_cell[i]
        if r != r_prev:
            r_prev = r
            c_prev = -1.0
            t = table[r]
            dl = delta[r]
            lam_t = meta[t, _LAM]
            n_seg = 0  # the non-empty segments, in order
            for k in range(N_SEGMENTS):
                first = int(meta[t, _ROW + k])
                if (int(meta[t, _ROW + k + 1]) if k + 1 < N_SEGMENTS else int(meta[t, _LENGTH]) - 1) > first:
                    seg_x[n_seg] = meta[t, _X + k]
                    seg_row[n_seg] = first
                    seg_h[n_seg] = meta[t, _SPACING + k]
                    seg_inv[n_seg] = 1.0 / seg_h[n_seg]
                    n_seg += 1
            seg_row[n_seg] = int(meta[t, _LENGTH]) - 1
            steep = int(meta[t, _ROW + 1]) > 0  # a coarse front: C from its endpoint asymptotic there
            n_first = 1 if steep else 2  # intervals whose C is integrated on the spot
            h_first = seg_h[0]
            s_a = s_c = 0
            z_half = np.inf  # least depth of the ray known to have C/Z >= 1/2
            z_end = meta[t, _Z_END]
            z_infl = meta[t, _Z_INFL]
            shift = meta[t, _SHIFT]
            lam_r = lam[r]
            log_z = meta[t, _LOG_Z] + dl * (meta[t, _LOG_Z_1] + 0.5 * dl * meta[t, _LOG_Z_2])  # the ray's
            log_far = meta[t, _LOG_FAR]
            off = int(meta[t, _OFFSET])  # node k's C at row off + k (k <= c_end), D at off_d + k
            off_d = off + int(meta[t, _D_SHIFT])
            c_end = int(meta[t, _C_END])
            stretch_r = stretch[r]
            z_start = meta[t, _Z_START]  # cells ending before it are at the floor (the table has no nodes there)
            z_floor = _ray_floor(shift, log_z, log_floor[r] if floors else -np.inf, z_start, geometry, mixture)
        a = max(start[i], z0)
        c = min(end[i] + stretch_r, z_max)
        if c <= a or a >= z_infl:
            side[j] = _SKIP
            l_a[j] = l_c[j] = 0.0
            lam_len[j] = lam[r] * max(end[i] + stretch_r - start[i], 0.0)
            c_prev = -1.0
            continue
        lam_len[j] = lam[r] * (c - a)
        if c <= z_floor:
            side[j] = _FLOOR
            l_a[j] = l_c[j] = 0.0
            c_prev = -1.0
            continue
        if a == c_prev:
            l_a[j] = lcc
            a_is_d = c_is_d
        else:
            k, f, s_a = _locate(lam_t * a - ku / a, s_a, seg_x, seg_row, seg_inv, n_seg)
            a_is_d = 1
            if k >= c_end or (a >= z_half and k > 0):  # C is increasing: past a depth with C/Z >= 1/2, D is
                # the smaller; from c_end on it is for every rate of the table, and only D is kept
                l_a[j] = _interpolate(nodes, off_d + k, f, seg_h[s_a], 0, dl)
                z_half = min(z_half, a)
            else:
                if k < n_first:  # log C is -inf at the table's start: integrated on the spot (_log_c_first),
                    # but 0 before the ray's floor (see the docstring)
                    lca = -np.inf
                    if a > z_floor:
                        lca = _log_c_first(a, steep, lam_r, shift, h_first, z_start, geometry, mixture) - log_z
                else:
                    lca = _interpolate(nodes, off + k, f, seg_h[s_a], 0, dl)
                if lca < _LOG_HALF:
                    a_is_d = 0
                    l_a[j] = lca
                else:
                    l_a[j] = _interpolate(nodes, off_d + k, f, seg_h[s_a], 0, dl)
                    z_half = min(z_half, a)
        if c > z_end:
            lcc = log_tail(c, log_z, lam_r, shift, log_far, hq, geometry, mixture) - log_z
            c_is_d = 1
        else:
            k, f, s_c = _locate(lam_t * c - ku / c, s_c, seg_x, seg_row, seg_inv, n_seg)
            c_is_d = 1
            if k >= c_end or (c >= z_half and k > 0):
                lcc = _interpolate(nodes, off_d + k, f, seg_h[s_c], 0, dl)
                z_half = min(z_half, c)
            else:
                if k < n_first:
                    lcc = _log_c_first(c, steep, lam_r, shift, h_first, z_start, geometry, mixture) - log_z
                else:
                    lcc = _interpolate(nodes, off + k, f, seg_h[s_c], 0, dl)
                if lcc < _LOG_HALF:
                    c_is_d = 0
                else:
                    lcc = _interpolate(nodes, off_d + k, f, seg_h[s_c], 0, dl)
                    z_half = min(z_half, c)
        if c_is_d and not a_is_d and l_a[j] >= _LOG_QUARTER:  # across C/Z = 1/2: see the docstring
            k, f, s_a = _locate(lam_t * a - ku / a, s_a, seg_x, seg_row, seg_inv, n_seg)
            l_a[j] = _interpolate(nodes, off_d + k, f, seg_h[s_a], 0, dl)
            a_is_d = 1
        l_c[j] = lcc
        side[j] = a_is_d + 2 * c_is_d
        c_prev = c


@nb.njit(cache=True, nogil=True, error_model="numpy")  # no fastmath: it inlines fast_exp
def prism_table_combine(lo, hi, l_a, l_c, e_a, e_c, side, lam_len, post, ratio, fix_index, fix_value, pass_through):
    """Second stage on cells ``lo:hi``: posterior (into ``post[lo:hi]``) and ``ratio[j]``, the increment's exp.

    ``e_a``, ``e_c`` are ``exp(l_a)``, ``exp(l_c)`` of :func:`prism_table_lookup` (:func:`exp_into`), so
    ``C/Z`` and ``D/Z`` at both ends are at hand in linear space: ``P Z = p_c C(a) + C(c) - C(a)``,
    ``(1 - P) Z = (1 - p_c) C(a) + D(c)`` and the increment is ``log(ratio)`` with
    ``ratio = P (1 - p_c) / ((1 - P) p_c)``, ``p_c = 1 - e^-lam_len``; a :data:`_FLOOR` cell's ``ratio`` is 0,
    thinned by ``pass_through``. A first, branch-free pass (it
    vectorises) does every cell so; a second one redoes the cells it marked (``ratio`` -1): skipped cells
    (``ratio = 1``, the posterior the prior's) and cells near underflow (a log below -600 or
    ``lam_len > 40``), which go through :func:`combine_small`, those far in front of the measurement gathered
    into :func:`_far_in_front` (a fifth of a long outdoor ray's cells: one by one, with the C library's exp and
    logs, they cost more than the first pass): ``ratio = 1``, listed in ``fix_index`` (offset from ``lo``) and
    ``fix_value``. Returns how many.

    Parameters
    ----------
    lo, hi : int
        The cells of this call.
    l_a, l_c : (hi - lo,) float64, log
        :func:`prism_table_lookup`'s smaller of ``log(C/Z)``, ``log(D/Z)`` at each cell's start and end.
    e_a, e_c : (hi - lo,) float64
        Their exps.
    side : (hi - lo,) int8
        :func:`prism_table_lookup`'s flags: bit 0 ``l_a`` is D's, bit 1 ``l_c`` is D's, or :data:`_SKIP`, :data:`_FLOOR`.
    lam_len : (hi - lo,) float64
        Each cell's prior rate times its length (dimensionless).
    post : (C,) float64
        Written at ``lo:hi``: the posterior occupancy of each cell.
    ratio : (hi - lo,) float64
        Written: the increment's exp, 1 for the cells listed in ``fix_index``.
    fix_index : (hi - lo,) int64
        Written: the cells (offset from ``lo``) whose increment is ``fix_value`` instead.
    fix_value : (hi - lo,) float64, log-odds
        Written: their increments.
    pass_through : float in [0, 1)
        The chance ``m`` that a ray passes an occupied cell, ``ratio -> m + (1 - m) ratio``
        (:func:`pass_through_log`; 0: never, bit for bit).
    """
    for j in range(hi - lo):
        s = side[j]
        p_c, q_c = _cell_prior(lam_len[j])
        c_a = 1.0 - e_a[j] if s & 1 else e_a[j]
        c_c = 1.0 - e_c[j] if s & 2 else e_c[j]
        d_a = e_a[j] if s & 1 else 1.0 - e_a[j]  # the looked-up side as it is: D(c)/Z below 1e-16 of q_c C(a)/Z
        d_c = e_c[j] if s & 2 else 1.0 - e_c[j]  # would vanish in 1 - (1 - D/Z)
        # the cell's share C(c) - C(a) from the side that is small (accurate) at c
        delta = max(c_c - c_a, 0.0) if c_c < 0.5 else max(d_a - d_c, 0.0)
        num = p_c * c_a + delta
        den = q_c * c_a + d_c
        ok = (
            (s != _SKIP)
            & (min(l_a[j], l_c[j]) >= -600.0)
            & (lam_len[j] <= 40.0)
            & (num > 0.0)
            & (den > 0.0)
            & (p_c > 0.0)
        )
        thinned = pass_through + (1.0 - pass_through) * ((num * q_c) / (den * p_c))  # = the ratio when m = 0
        post[lo + j] = num / (num + den) if pass_through == 0.0 else p_c * thinned / (p_c * thinned + q_c)
        ratio[j] = pass_through if s == _FLOOR else (thinned if ok else -1.0)
    n_fix = 0
    far = np.empty(hi - lo, dtype=np.int64)  # cells far in front of the measurement (see below)
    n_far = 0
    for j in range(hi - lo):
        if ratio[j] >= 0.0:
            continue
        ratio[j] = 1.0
        if side[j] == _SKIP:
            post[lo + j] = -math.expm1(-lam_len[j])
            continue
        if not side[j] & 2 and l_c[j] < _FAR_IN_FRONT and lam_len[j] > 0.0:
            far[n_far] = j
            n_far += 1
            continue
        post[lo + j], fix_value[n_fix] = combine_small(l_a[j], l_c[j], side[j] & 1, side[j] & 2, lam_len[j])
        if pass_through > 0.0:
            post[lo + j], fix_value[n_fix] = pass_through_log(fix_value[n_fix], lam_len[j], pass_through)
        fix_index[n_fix] = j
        n_fix += 1
    if n_far:
        _far_in_front(far[:n_far], lo, l_a, l_c, side, lam_len, post, fix_value[n_fix : n_fix + n_far])
        for k in range(n_far):
            j = far[k]
            if pass_through > 0.0:
                post[lo + j], fix_value[n_fix] = pass_through_log(fix_value[n_fix], lam_len[j], pass_through)
            fix_index[n_fix] = j
            n_fix += 1
    return n_fix


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _far_in_front(cells, lo, l_a, l_c, side, lam_len, post, increment):
    """The cells ``cells`` (offsets from ``lo``) far in front of the measurement: ``log(C/Z)`` below
    :data:`_FAR_IN_FRONT` at the end (``l_c`` C's; ``l_a`` C's or, where ``side`` bit 0 says so, D's), so ``D/Z = 1``
    to float64's precision and ``P Z = C(c) - e^{-lam_len} C(a)``, ``(1 - P) Z = Z``: two transcendentals fewer than
    :func:`combine_small`, in a loop that vectorises over the gathered cells. Writes ``post[lo + cell]`` and ``increment``
    ((len(cells),) float64, log-odds, in the order of ``cells``). ``1 - e^-x`` by :func:`_cell_prior` (its series
    where it would cancel), exp and log by :func:`fast_exp`, :func:`fast_log`."""
    n = cells.size
    end, rate_len, gap, posterior = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        j = cells[k]
        end[k] = l_c[j]
        rate_len[k] = lam_len[j]
        l_ca = log1mexp(l_a[j]) if side[j] & 1 else l_a[j]
        gap[k] = lam_len[j] - min(l_ca - l_c[j], 0.0)  # log(C(c) / (e^-lam_len C(a))) >= lam_len > 0
    for k in range(n):
        log_num = end[k] + fast_log(_cell_prior(gap[k])[0])
        increment[k] = log_num - rate_len[k] - fast_log(_cell_prior(rate_len[k])[0])
        posterior[k] = fast_exp(log_num)
    for k in range(n):
        post[lo + cells[k]] = posterior[k]


@nb.njit(cache=True, nogil=True, error_model="numpy")  # the inlined blend divides
def prism_table_cells(
    lam, stretch, tables, cells, runs, hq, block, pass_through, ok, fail, log_floor, geometry, models
):
    """Tabulated PRISM on every cell ``[start[i], end[i] + stretch[r]]``: posterior and increment, (C,) each.

    Blocks of ``block`` cells go through :func:`prism_table_lookup`, :func:`exp_into` (both ends),
    :func:`prism_table_combine`, where the error model has matcher failures the blend with each cell's prior
    (:func:`~prismap.sensor_models._kernels_failure.blend_ratios_into` on the likelihood ratios, ``blend_cell``
    on the increments :func:`prism_table_combine` lists), and :func:`log_into`; the scratch arrays of a block stay
    in the core's cache and the GIL stays released for the whole call. With failures, the cells before a ray's
    failure floor depth (``floor_depth`` from ``log_floor``) skip the look-up: their blend is that of a failure-free
    ratio of 0 (a long outdoor ray's first two fifths).

    The cells come in ``runs`` of one model each (:class:`~prismap.sensor_models._kernel_args.ClassRuns`, rows of
    ``models``, a :class:`~prismap.sensor_models._kernel_args.MixtureSet`: a conditioned model's classes in one
    call), each looked up with its model's mixture and ``ku``; the tables, failure posteriors and floors are per ray.

    Parameters
    ----------
    lam, stretch, tables, cells, hq
        As :func:`prism_table_lookup`'s, for all the cells.
    runs : ClassRuns
        The cells' runs and each run's row of ``models``.
    geometry : Geometry
        ``z0``, ``z_max`` and ``fb``, shared; its ``ku`` is each run's from ``models``.
    models : MixtureSet
        The error mixtures.
    block : int
        Cells per round (their scratch arrays stay in the core's cache).
    pass_through : float in [0, 1)
        See :func:`prism_table_combine`.
    ok, fail : (R,) float64, or (0,) each
        Each ray's posterior of a good match, ``rho``, and of a matcher failure, ``1 - rho``
        (:func:`~prismap.sensor_models.log_failure_posterior`, exponentiated); empty: no failures, no blend. A
        cell's prior in the blend is that of its part in ``[z0, z_max]``.
    log_floor : (R,) float64, log, or (0,)
        Each ray's floor level for :func:`prism_table_lookup`: ``log(1 - rho)``, or ``log`` of the pass-through chance
        where there is one (the thinned ratio at the floor); empty with ``ok`` and ``fail``.

    Returns
    -------
    post : (C,) float64
        Posterior occupancy of each cell.
    inc : (C,) float64, log-odds
        ``logit(post) - logit(prior)``.
    """
    ray_of_cell, start, end = cells
    n = start.size
    post = np.empty(n)
    inc = np.empty(n)
    size = max(min(n, block), 1)
    l_a, l_c, e_a, e_c = np.empty(size), np.empty(size), np.empty(size), np.empty(size)
    lam_len, ratio, fix_value = np.empty(size), np.empty(size), np.empty(size)
    side = np.empty(size, dtype=np.int8)
    fix_index = np.empty(size, dtype=np.int64)
    z0, z_max = geometry.z0, geometry.z_max
    blend = ok.size > 0
    n_blend = size if blend else 0  # each cell's ray's rate, ok and fail, and its end with the stretch
    rate_cell, ok_cell, fail_cell, end_cell = np.empty(n_blend), np.empty(n_blend), np.empty(n_blend), np.empty(n_blend)
    run = 0
    for lo in range(0, n, size):
        hi = min(lo + size, n)
        m = hi - lo
        part = lo
        while part < hi:  # the block's runs, each through the look-up with its model
            while runs.first_cell[run + 1] <= part:
                run += 1
            k, end_part, j = runs.model[run], min(hi, runs.first_cell[run + 1]), part - lo
            size_k = models.size[k]
            prism_table_lookup(
                lam,
                stretch,
                tables,
                cells,
                part,
                end_part,
                hq,
                Geometry(z0, z_max, geometry.fb, models.ku[k]),
                Mixture(models.log_wn[k, :size_k], models.means[k, :size_k], models.sigmas[k, :size_k]),
                log_floor,
                l_a[j:],
                l_c[j:],
                side[j:],
                lam_len[j:],
            )
            part = end_part
        exp_into(l_a, e_a, m)
        exp_into(l_c, e_c, m)
        n_fix = prism_table_combine(
            lo, hi, l_a, l_c, e_a, e_c, side, lam_len, post, ratio, fix_index, fix_value, pass_through
        )
        if blend:
            for j in range(m):
                r = ray_of_cell[lo + j]
                rate_cell[j], ok_cell[j], fail_cell[j], end_cell[j] = lam[r], ok[r], fail[r], end[lo + j] + stretch[r]
            blend_ratios_into(post[lo:hi], ratio, rate_cell, start[lo:hi], end_cell, z0, z_max, ok_cell, fail_cell, m)
        log_into(ratio, inc[lo:hi], m)
        for k in range(n_fix):
            j = fix_index[k]
            if blend:
                post[lo + j], inc[lo + j] = blend_cell(
                    fix_value[k], rate_cell[j], start[lo + j], end_cell[j], z0, z_max, ok_cell[j], fail_cell[j]
                )
            else:
                inc[lo + j] = fix_value[k]
    return post, inc
