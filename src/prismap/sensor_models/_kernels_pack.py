"""PRISM's tables as the table cache holds them: each node's one side a look-up may read, packed back to back with
a row of metadata per table (:func:`prism_tables`, from :func:`~prismap.sensor_models._kernels_table.prism_table`),
and the keys that find them (:func:`table_keys`).
"""

import math

import numba as nb
import numpy as np

from prismap.sensor_models._kernels_influence import INFLUENCE_LEVELS
from prismap.sensor_models._kernels_table import _D_COLUMN, N_SEGMENTS, prism_table

TABLE_COLUMNS = _D_COLUMN
"""Columns of a row of the table cache: one side's five (C's or D's), 20 bytes in float32. A look-up reads ``C``
where ``C/Z`` may be below 1/2 and ``D`` where it may be above 1/4 (``_kernels_lookup.prism_table_lookup``), so a
packed table (:func:`prism_tables`) keeps C's rows up to the first interval past which ``C/Z >= 1/2`` for every
rate that shares the table, and D's from the last interval before which ``C/Z < 1/4`` for all of them: a band of
a few rows has both."""
_LOG_HALF = -0.6931471805599453
_LOG_QUARTER = 2.0 * _LOG_HALF
_SIDE_MARGIN = 0.05
"""Log units added to both ends of the band where a packed table keeps both sides (:func:`_side_rows`), beyond
the bound on the interpolated ``log(C/Z)``: float32 rounding and the look-up's exact C in a table's first interval or two."""


_PACK_ROWS = 192
"""Rows a table :func:`prism_tables` makes room for at first (a street table has 100 to 170)."""

META_COLUMNS = (
    "lam",
    *(f"x_{k}" for k in range(N_SEGMENTS)),
    *(f"row_{k}" for k in range(N_SEGMENTS)),
    *(f"h_{k}" for k in range(N_SEGMENTS)),
    "z_end",
    *(f"z_infl_{k}" for k in range(INFLUENCE_LEVELS)),
    *(f"z_tight_{k}" for k in range(INFLUENCE_LEVELS)),
    "log_z",
    "log_z_1",
    "log_z_2",
    "z_start",
    "shift",
    "log_far",
    "offset",
    "length",
    "c_end",
    "d_shift",
    "stored",
)
"""Columns of the per-table metadata matrix that :func:`prism_table_lookup` reads (one row per table): the
rate, :func:`prism_table`'s meta (per segment its first x, first row and spacing, then ``z_end``, the influence
depths of each level (``z_infl_k``, ``z_tight_k``: ``_kernels_influence``), ``log Z`` and its two derivatives in
``log lam``, ``z_start``), then the shift, far term, the first row of its packed rows in the cache's ``nodes``,
its node count, the first interval where only D is kept (C's rows ``0..c_end`` come first), the place of D's rows
(node ``k``'s at ``offset + d_shift + k``) and the rows it packs (:data:`TABLE_COLUMNS`)."""
_LAM, _X, _ROW, _SPACING = 0, 1, 1 + N_SEGMENTS, 1 + 2 * N_SEGMENTS
_Z_END = 1 + 3 * N_SEGMENTS
_Z_INFL = _Z_END + 1  # level k's influence depths at _Z_INFL + k (cells of any length), _Z_TIGHT + k (short cells)
_Z_TIGHT = _Z_INFL + INFLUENCE_LEVELS
(
    _LOG_Z,
    _LOG_Z_1,
    _LOG_Z_2,
    _Z_START,
    _SHIFT,
    _LOG_FAR,
    _OFFSET,
    _LENGTH,
    _C_END,
    _D_SHIFT,
    _STORED,
) = range(_Z_TIGHT + INFLUENCE_LEVELS, _Z_TIGHT + INFLUENCE_LEVELS + 11)


_SIDE_PIECES = 8
"""Pieces of an interval on which :func:`_side_rows` bounds the interpolated ``log(C/Z)``."""


@nb.njit(cache=True, nogil=True)
def _side_rows(nodes, table_meta, delta_max):
    """``(c_end, d_first)`` of a table (:func:`prism_table`'s ``nodes``, ``meta``): the first interval from which
    every interpolated ``log(C/Z)`` is at least ``log(1/2)``, and the first at which one may reach ``log(1/4)``,
    for every rate offset ``|delta| <= delta_max`` (``_kernels_lookup._interpolate``), :data:`_SIDE_MARGIN` to
    spare. The first interval is C's own integral, bounded above by node 1; a bound that is not a number keeps
    both sides.

    On an interval of x-width ``h`` the cubic Hermite form is its chord ``y_0 + f dy`` plus
    ``f (1 - f)^2 (h s_0 - dy) - f^2 (1 - f) (h s_1 - dy)``; on each of :data:`_SIDE_PIECES` pieces of ``f`` the
    chord's and the two factors' largest values bound it. Each value and slope is widened by its Taylor term in
    ``delta``, and the second-order term adds ``delta^2 / 2`` times the larger of its two nodes.
    """
    n = nodes.shape[0]
    m = _SIDE_PIECES
    rise = np.empty(m)  # per piece: largest f (1 - f)^2 (at most 4/27, at f = 1/3) and f^2 (1 - f) (at f = 2/3)
    fall = np.empty(m)
    for p in range(m):
        f_a, f_b = p / m, (p + 1) / m
        rise[p] = max(f_a * (1.0 - f_a) ** 2, f_b * (1.0 - f_b) ** 2, 4.0 / 27.0 if f_a <= 1.0 / 3.0 <= f_b else 0.0)
        fall[p] = max(f_a * f_a * (1.0 - f_a), f_b * f_b * (1.0 - f_b), 4.0 / 27.0 if f_a <= 2.0 / 3.0 <= f_b else 0.0)
    low = np.empty(n - 1)
    high = np.empty(n - 1)
    second = 0.5 * delta_max * delta_max
    segment = 0
    for k in range(n - 1):
        while segment + 1 < N_SEGMENTS and table_meta[N_SEGMENTS + segment + 1] <= k:
            segment += 1
        h = table_meta[2 * N_SEGMENTS + segment]
        y_0, y_1 = nodes[k, 0], nodes[k + 1, 0]
        dy = y_1 - y_0
        wobble = delta_max * (abs(nodes[k + 1, 2] - nodes[k, 2]) + h * max(abs(nodes[k, 3]), abs(nodes[k + 1, 3])))
        bend_0 = abs(h * nodes[k, 1] - dy) + wobble
        bend_1 = abs(h * nodes[k + 1, 1] - dy) + wobble
        spread = (
            delta_max * max(abs(nodes[k, 2]), abs(nodes[k + 1, 2]))
            + second * max(abs(nodes[k, 4]), abs(nodes[k + 1, 4]))
            + _SIDE_MARGIN
        )
        low[k] = np.inf
        high[k] = -np.inf
        for p in range(m):
            chord_a, chord_b = y_0 + dy * (p / m), y_0 + dy * ((p + 1) / m)
            bend = rise[p] * bend_0 + fall[p] * bend_1
            low[k] = min(low[k], min(chord_a, chord_b) - bend - spread)
            high[k] = max(high[k], max(chord_a, chord_b) + bend + spread)
    if n > 1:
        high[0] = nodes[1, 0] + delta_max * abs(nodes[1, 2]) + second * abs(nodes[1, 4]) + _SIDE_MARGIN
    c_end = n - 1
    while c_end > 1 and low[c_end - 1] >= _LOG_HALF:  # NaN: not shown to be above, C kept
        c_end -= 1
    d_first = 0
    while d_first < n - 1 and high[d_first] < _LOG_QUARTER:  # NaN: not shown to be below, D kept
        d_first += 1
    return c_end, min(d_first, c_end)


@nb.njit(cache=True, nogil=True)
def prism_tables(shifts, lams, log_fars, geometry, spec, mixture):
    """:func:`prism_table` of every ``(shifts[k], lams[k], log_fars[k])``, packed for the table cache.

    Returns ``nodes`` (N, :data:`TABLE_COLUMNS`) float32, every table's packed rows back to back (its C rows to
    ``c_end``, then its D rows from ``d_first``, :func:`_side_rows`; their rounding is far below
    ``TABLE_TOLERANCE``), and ``meta`` (K, ``len(META_COLUMNS)``) float64, one row per table (``offset``: its
    first row in ``nodes``). One call builds a batch without a Python step per table, each
    table packed as soon as it is built (its float64 rows reuse the memory of the one before: holding a whole
    batch in float64 first doubles its memory and page faults), into room for :data:`_PACK_ROWS` rows a table
    that grows by half when full; ``nodes`` may be a view of that room.

    Parameters
    ----------
    shifts : (K,) float64, pixels
        Each table's measured disparity plus ``doffs``.
    lams : (K,) float64, per metre of depth
        Each table's surface rate.
    log_fars : (K,) float64, log(1/pixel)
        Each table's far-measurement log density.
    geometry, spec, mixture
        As :func:`prism_table`'s, shared by all the tables.
    """
    n_tables = shifts.size
    meta = np.empty((n_tables, _STORED + 1))
    packed = np.empty((_PACK_ROWS * n_tables, TABLE_COLUMNS), dtype=np.float32)
    delta_max = math.log1p(spec.lam_slack)  # the rays sharing a table: rates within e^(+-lambda_step / 2) of it
    total = 0
    for k in range(n_tables):
        nodes, table_meta = prism_table(shifts[k], lams[k], log_fars[k], geometry, spec, mixture)
        n = nodes.shape[0]
        c_end, d_first = _side_rows(nodes, table_meta, delta_max)
        rows = c_end + 1 + n - d_first
        if total + rows > packed.shape[0]:
            grown = np.empty(
                (max(total + rows, packed.shape[0] + packed.shape[0] // 2), TABLE_COLUMNS), dtype=np.float32
            )
            grown[:total] = packed[:total]
            packed = grown
        packed[total : total + c_end + 1] = nodes[: c_end + 1, :_D_COLUMN]
        packed[total + c_end + 1 : total + rows] = nodes[d_first:, _D_COLUMN:]
        meta[k, _LAM] = lams[k]
        meta[k, _X:_SHIFT] = table_meta
        meta[k, _SHIFT] = shifts[k]
        meta[k, _LOG_FAR] = log_fars[k]
        meta[k, _OFFSET] = total
        meta[k, _LENGTH] = n
        meta[k, _C_END] = c_end
        meta[k, _D_SHIFT] = c_end + 1 - d_first
        meta[k, _STORED] = rows
        total += rows
    return packed[:total], meta


@nb.njit(cache=True, nogil=True)
def compact_rows(nodes, starts, lengths):
    """Move the runs of rows ``starts[k] : starts[k] + lengths[k]`` (increasing, disjoint) of ``nodes`` to its front,
    back to back in that order, in place: each row moves to a row no later than its own, so a forward copy reads
    every row before any write reaches it."""
    to = 0
    for k in range(starts.size):
        first = starts[k]
        for i in range(lengths[k]):
            for c in range(nodes.shape[1]):
                nodes[to + i, c] = nodes[first + i, c]
        to += lengths[k]


@nb.njit(cache=True, nogil=True)
def rate_key_centre(key_l, lambda_step):
    """``log(lambda_table / lambda)`` of rate key ``key_l`` (a scalar or an int array): the centre of its bin of
    ``log|r|`` (:func:`table_keys`)."""
    return (key_l + 0.5) * lambda_step


@nb.njit(cache=True, nogil=True)
def table_keys(disparity, log_norm, tag, disparity_step, lambda_step, key_l_span):
    """PRISM's table key of every ray, the distinct keys (first-seen order), by open addressing, and every ray's
    ``delta = log(lambda_ray / lambda_table)``.

    ``key = tag + rint(d / disparity_step) * key_l_span + min(floor(log|r| / lambda_step), key_l_span - 1)``
    (``tag`` (R,) int64: the ray's model's, for models that share one cache, ``_prism.KEY_TAG_SPAN`` apart): a rate
    key is a bin ``[k, k + 1) lambda_step`` of ``log|r|`` (``>= 0``) and its table sits at the bin's centre, so
    ``|delta| <= lambda_step / 2`` and a camera's rays of norm 1 to ``e^(n lambda_step)`` meet ``n`` rate keys.
    Returns ``unique (K,) int64``, ``inverse (R,) int64`` (``unique[inverse] = key``) and ``delta (R,)``; a hash
    table instead of a sort: O(R) for the ~300 k rays of a frame and their ~2 k keys.
    """
    n = disparity.size
    size = 64
    while size < 2 * n:
        size *= 2
    mask = size - 1
    slots = np.full(size, -1, dtype=np.int64)
    unique = np.empty(n, dtype=np.int64)
    inverse = np.empty(n, dtype=np.int64)
    delta = np.empty(n)
    k = 0
    for i in range(n):
        key_l = min(np.int64(math.floor(log_norm[i] / lambda_step)), key_l_span - 1)
        delta[i] = log_norm[i] - rate_key_centre(key_l, lambda_step)
        key = tag[i] + np.int64(np.rint(disparity[i] / disparity_step)) * key_l_span + key_l
        h = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(32)) & mask
        while slots[h] >= 0 and unique[slots[h]] != key:
            h = (h + 1) & mask
        if slots[h] < 0:
            slots[h] = k
            unique[k] = key
            k += 1
        inverse[i] = slots[h]
    return unique[:k], inverse, delta
