"""How PRISM's tables space their nodes for a given error mixture: fine where the evidence changes, coarse where
only the widest error component produces the measurement (see docs/SENSOR_MODELS.md, "The tables").

Node spacings are in the integration coordinate ``x`` (one unit per prior e-fold or narrowest sigma of disparity).
"""

import numpy as np

_TABLE_STEP = 0.5  # table node spacing in x, also the width of its march's panels
_COARSE_RATIO = 64  # node spacing 32 in x where log(C/Z) < _COARSE_BELOW (near-quadratic in x) and past influence
_COARSE_WIDE_SIGMAS = 0.125  # coarse-front node spacing may reach this many widest sigmas (see coarse_ratio)
_COARSE_BELOW = -40.0
_BROAD_SHARE = -20.0  # log share of the largest component density below which a component does not matter
_WIDE_SIGMAS = 0.25  # node spacing, this many sigmas of the narrowest component that matters (spacing_profile)
_WINDOW_SIGMAS = 12.0  # a component matters within this many of its sigmas of its mean (beyond: below e^-72)
_MAX_PIECES = 12  # most pieces of a spacing profile (spacing_profile); the tables' segments follow from it


def coarse_ratio(mixture):
    """Fine nodes per node of a PRISM table's coarse front (where ``C/Z < e^_COARSE_BELOW``).

    There the measurement is far behind, only the widest error component produces it and ``log(q g)`` is nearly
    quadratic in ``x``: :data:`_COARSE_RATIO`, or, when the mixture's sigmas span more than that allows, nodes
    :data:`_COARSE_WIDE_SIGMAS` widest sigmas of disparity apart (a characterised class with a component of
    0.01 px beside outliers of 33 px would otherwise put thousands of nodes between ``near_m`` and the
    measurement's first evidence). Mixtures whose widest sigma is below 256 narrowest ones keep
    :data:`_COARSE_RATIO`.
    """
    sd = mixture.sigmas
    return max(_COARSE_RATIO, int(_COARSE_WIDE_SIGMAS * sd.max() / (sd.min() * _TABLE_STEP)))


def spacing_profile(mixture):
    """How a PRISM table spaces its march's nodes along the error ``e = d_true - d^`` (pixels), piece by piece.

    Component ``j`` matters at ``e`` where it lies within :data:`_WINDOW_SIGMAS` of its sigmas of its mean and its
    density is at least ``e^_BROAD_SHARE`` of the largest component density there. Where some components matter,
    nodes are ``ratio`` fine steps apart: a quarter of the narrowest mattering sigma (:data:`_WIDE_SIGMAS`; one
    fine step, half the narrowest sigma of the mixture, for components less than twice it), so far in front of
    and behind the measurement, where only an outlier component produces it, nodes follow the outliers. Where
    none matters, between two components' windows, ``C`` and ``D`` are constant far below the tables' tolerance:
    a gap (``ratio`` 0), spaced like the coarse front. In front of every window the first window's spacing
    holds, behind every window one fine step. At most :data:`_MAX_PIECES` pieces: beyond, the shortest is
    merged into the finer of its neighbours.

    Parameters
    ----------
    mixture : GaussianMixture
        Disparity error ``e = d_true - d_computed`` (pixels).

    Returns
    -------
    edges : (M + 1,) float64, pixels
        Piece boundaries, descending from ``inf`` to ``-inf`` (the order of a table's nodes: front to back).
    ratios : (M,) int64
        Each piece's node spacing in fine steps, 0 for a gap; no two neighbours equal.
    """
    log_w = np.log(mixture.weights / mixture.sigmas)
    mu, sd = mixture.means, mixture.sigmas
    ratio_of = np.maximum(np.minimum((_WIDE_SIGMAS * sd / (sd.min() * _TABLE_STEP)).astype(np.int64), _COARSE_RATIO), 1)
    cuts = [mu - _WINDOW_SIGMAS * sd, mu + _WINDOW_SIGMAS * sd]
    for i in range(mu.size):  # where two components' log densities differ by 0 or _BROAD_SHARE
        for j in range(i + 1, mu.size):
            a = 0.5 / sd[j] ** 2 - 0.5 / sd[i] ** 2
            b = mu[i] / sd[i] ** 2 - mu[j] / sd[j] ** 2
            for level in (0.0, _BROAD_SHARE, -_BROAD_SHARE):
                c = log_w[i] - log_w[j] - 0.5 * (mu[i] / sd[i]) ** 2 + 0.5 * (mu[j] / sd[j]) ** 2 - level
                cuts.append(np.roots([a, b, c]) if a != 0.0 else ([-c / b] if b != 0.0 else []))
    cuts = np.concatenate([np.real(np.atleast_1d(np.asarray(c, dtype=complex))[np.isreal(c)]) for c in cuts])
    inner = np.unique(cuts[np.isfinite(cuts)])[::-1]
    edges = np.concatenate([[np.inf], inner, [-np.inf]])
    probe = np.concatenate([[inner[0] + 1.0], 0.5 * (inner[:-1] + inner[1:]), [inner[-1] - 1.0]])
    log_dens = log_w - 0.5 * ((probe[:, None] - mu) / sd) ** 2
    matters = (np.abs(probe[:, None] - mu) <= _WINDOW_SIGMAS * sd) & (
        log_dens >= log_dens.max(axis=1, keepdims=True) + _BROAD_SHARE
    )
    ratios = np.where(matters, ratio_of, _COARSE_RATIO + 1).min(axis=1)
    ratios[ratios > _COARSE_RATIO] = 0
    windowed = np.flatnonzero(ratios)
    ratios[: windowed[0]] = ratios[windowed[0]]  # in front of every window: the first window's spacing
    ratios[windowed[-1] + 1 :] = 1  # behind them: fine
    edges, ratios = _merged(edges, ratios)
    while ratios.size > _MAX_PIECES:
        k = int(np.argmin(np.diff(-edges)[1:-1])) + 1  # the shortest finite piece
        finer = min((r if r else _COARSE_RATIO + 1) for r in ratios[max(k - 1, 0) : k + 2 : 2])
        ratios[k] = finer
        edges, ratios = _merged(edges, ratios)
    return edges, ratios


def _merged(edges, ratios):
    """``edges``, ``ratios`` without the boundaries between neighbouring pieces of equal ratio."""
    keep = np.concatenate([[True], ratios[1:] != ratios[:-1], [True]])
    return edges[keep], ratios[keep[:-1]]
