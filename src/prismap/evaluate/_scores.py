"""Proper scores of a probabilistic map against true occupancy (SENSOR_MODELS.md section 6)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.stats import rankdata

from prismap._validate import as_float_array
from prismap.errors import PrismapInputError

LOG_LOSS_EPS = 1e-6
"""Probabilities are clipped to ``[LOG_LOSS_EPS, 1 - LOG_LOSS_EPS]`` before the log-loss."""

SAFETY_FREE_SHARE = 0.9
"""Share of the truly free voxels the safety score's threshold calls free (see :func:`safety_score`)."""

CONFIDENT = 0.99
"""A map is "confident and wrong" about a truly free voxel at ``P >= CONFIDENT`` and about a truly occupied one
at ``P <= 1 - CONFIDENT``: the extremes a planner trusts most (SENSOR_MODELS.md section 7)."""

LOGIT_BIN_EDGES = np.concatenate([[0.0], 1.0 / (1.0 + np.exp(-np.arange(-9.0, 9.5, 1.5))), [1.0]])
"""Edges of the logit-spaced reliability bins: 0, then ``sigmoid(-9 .. 9)`` in log-odds steps of 1.5, then 1, so
that bins reach the extremes (``P`` below 1.2e-4 and above 1 - 1.2e-4) where equal-width bins hide everything."""

EVIDENCE_EDGES = np.concatenate(
    [-np.logspace(np.log10(2048.0), -1.0, 16)[:-1], [-0.1, 0.1], np.logspace(-1.0, np.log10(2048.0), 16)[1:]]
)
"""Edges (log-odds, nats) of the per-frame evidence histograms: symmetric, logarithmic from 0.1 to 2048 (the map's
fixed-point bound) on each side, one bin ``[-0.1, 0.1)`` around no evidence; values beyond fall in the end bins."""


SCORE_COLUMNS = (
    ("Brier score", "brier", "{:.4f}", "lower"),
    ("log-loss (nats)", "log_loss", "{:.4f}", "lower"),
    ("ECE", "ece", "{:.4f}", "lower"),
    ("ROC AUC", "roc_auc", "{:.4f}", "higher"),
    ("occupied called free", "occupied_called_free", "{:.4f}", "lower"),
    ("free called occupied", "free_called_occupied", "{:.4f}", "lower"),
    ("occupied called free at 90 % free", "safety_occupied_called_free", "{:.4f}", "lower"),
    ("threshold at 90 % free", "safety_threshold", "{:.4f}", None),
)
"""(label, :class:`MapScores` attribute, format, which is better: "lower", "higher" or None for a value
that is not a score) of every column the tables show, in order."""

EXTREME_COLUMNS = (
    ("free at P >= 0.99", "free_confident_occupied", "{:.3%}"),
    ("occupied at P <= 0.01", "occupied_confident_free", "{:.3%}"),
    ("of P >= 0.99: free", "free_share_at_high_p", "{:.2%}"),
    ("of P <= 0.01: occupied", "occupied_share_at_low_p", "{:.2%}"),
)
"""(label, :class:`MapScores` attribute, format) of the scale's extremes: the "confident and wrong" rates and
calibration there (lower is better; NaN where a map puts no voxel)."""


@dataclass(frozen=True)
class MapScores:
    """Per-voxel scores of predicted occupancy probabilities against the truth.

    Attributes
    ----------
    n_voxels, n_occupied, n_free : int
        Evaluated voxels, and how many of them are truly occupied / free.
    brier : float
        Mean of ``(P - y)^2``; 0 is perfect, 0.25 is a constant 0.5.
    log_loss : float, nats
        Mean of ``-y ln P - (1 - y) ln(1 - P)`` with ``P`` clipped to ``[1e-6, 1 - 1e-6]``, so a
        confident wrong voxel costs at most ``ln(1e6) = 13.8`` nats instead of infinity.
    ece : float
        Expected calibration error: ``sum_b (n_b / N) |mean P in b - occupied fraction in b|``
        over the reliability bins.
    roc_auc : float
        Probability that a random occupied voxel gets a higher ``P`` than a random free one
        (ties count one half); NaN when the truth has one class only.
    occupied_called_free : float
        Fraction of truly occupied voxels with ``P < 0.5`` (the unsafe error); NaN without any.
    free_called_occupied : float
        Fraction of truly free voxels with ``P > 0.5``; NaN without any.
    safety_occupied_called_free : float
        Threshold-free safety score: fraction of truly occupied voxels called free (``P <= t``) at the
        threshold ``t`` that calls 90 % of the truly free voxels free (:func:`safety_score`); NaN without
        occupied or without free voxels.
    safety_threshold : float
        That threshold ``t``, a probability; NaN without free voxels.
    free_confident_occupied : float
        "Confident and wrong" about free space: fraction of truly free voxels with ``P >= 0.99``
        (:data:`CONFIDENT`); NaN without any.
    occupied_confident_free : float
        "Confident and wrong" about obstacles: fraction of truly occupied voxels with ``P <= 0.01``; NaN without
        any.
    free_share_at_high_p : float
        Calibration at the top of the scale: of the voxels at ``P >= 0.99``, the fraction truly free. A
        calibrated map keeps it at most 1 %; NaN when no voxel is that sure (a timid map is never wrong here).
    occupied_share_at_low_p : float
        Of the voxels at ``P <= 0.01``, the fraction truly occupied (calibrated: at most 1 %); NaN without any.
    bin_edges : (B + 1,) float64
        Edges of the equal-width reliability bins on ``[0, 1]``.
    bin_counts : (B,) int64
        Voxels per bin (the last bin includes ``P = 1``).
    bin_mean_probability, bin_occupied_fraction : (B,) float64
        Mean predicted ``P`` and observed occupied fraction per bin; NaN in empty bins.
    hist_edges : (H + 1,) float64
        Edges of the ``P`` histograms on ``[0, 1]``.
    hist_free, hist_occupied : (H,) int64
        Counts of ``P`` among truly free and truly occupied voxels (thesis fig. 6.7).
    logit_bin_edges : (L + 1,) float64
        :data:`LOGIT_BIN_EDGES`: reliability bins equal in log-odds, reaching ``P`` = 0 and 1.
    logit_bin_counts : (L,) int64
    logit_bin_mean_probability, logit_bin_occupied_fraction : (L,) float64
        As ``bin_*`` on the logit-spaced bins (NaN in empty bins).
    evidence_edges : (E + 1,) float64, nats
        :data:`EVIDENCE_EDGES`.
    evidence_one_view : (E,) int64
        Histogram of the log-odds increment of the voxels one frame observed (``l - logit(p0)``: exactly that
        frame's evidence); zeros when :func:`score_map` got no ``evidence``.
    evidence_per_view : (E,) int64
        Histogram of every observed voxel's mean increment per frame, ``(l - logit(p0)) / n``.
    """

    n_voxels: int
    n_occupied: int
    n_free: int
    brier: float
    log_loss: float
    ece: float
    roc_auc: float
    occupied_called_free: float
    free_called_occupied: float
    safety_occupied_called_free: float
    safety_threshold: float
    bin_edges: np.ndarray
    bin_counts: np.ndarray
    bin_mean_probability: np.ndarray
    bin_occupied_fraction: np.ndarray
    hist_edges: np.ndarray
    hist_free: np.ndarray
    hist_occupied: np.ndarray
    free_confident_occupied: float = float("nan")
    occupied_confident_free: float = float("nan")
    free_share_at_high_p: float = float("nan")
    occupied_share_at_low_p: float = float("nan")
    logit_bin_edges: np.ndarray = field(default_factory=lambda: LOGIT_BIN_EDGES.copy())
    logit_bin_counts: np.ndarray = field(default_factory=lambda: np.zeros(len(LOGIT_BIN_EDGES) - 1, np.int64))
    logit_bin_mean_probability: np.ndarray = field(default_factory=lambda: np.full(len(LOGIT_BIN_EDGES) - 1, np.nan))
    logit_bin_occupied_fraction: np.ndarray = field(default_factory=lambda: np.full(len(LOGIT_BIN_EDGES) - 1, np.nan))
    evidence_edges: np.ndarray = field(default_factory=lambda: EVIDENCE_EDGES.copy())
    evidence_one_view: np.ndarray = field(default_factory=lambda: np.zeros(len(EVIDENCE_EDGES) - 1, np.int64))
    evidence_per_view: np.ndarray = field(default_factory=lambda: np.zeros(len(EVIDENCE_EDGES) - 1, np.int64))

    def to_dict(self) -> dict[str, Any]:
        """Plain Python types for JSON: arrays become lists and NaN becomes ``None``."""
        out = {}
        for name, value in self.__dict__.items():
            if isinstance(value, np.ndarray):
                out[name] = [_plain(v) for v in value.tolist()]
            else:
                out[name] = _plain(value)
        return out


def _share(truth, selected):
    """Fraction of the ``selected`` voxels where ``truth`` holds; NaN when none is selected."""
    return float(np.mean(truth[selected])) if selected.any() else float("nan")


def _plain(value):
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def score_map(
    probability: npt.ArrayLike,
    occupied: npt.ArrayLike,
    *,
    n_bins: int = 10,
    n_hist_bins: int = 20,
    evidence: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> MapScores:
    """Score predicted occupancy probabilities of a set of voxels against the truth.

    Parameters
    ----------
    probability : (N,) float, in [0, 1]
        Predicted ``P(occupied)`` of each evaluated voxel (unknown voxels carry the prior ``p0``:
        see :func:`align_to_ground_truth`).
    occupied : (N,) bool
        True occupancy of the same voxels (0/1 integers are accepted).
    n_bins : int, keyword-only
        Equal-width reliability bins for the calibration error and diagram.
    n_hist_bins : int, keyword-only
        Equal-width bins of the ``P`` histograms of free and occupied voxels.
    evidence : (increments, counts) or None, keyword-only
        The map's observed voxels: ``(M,)`` float log-odds gathered from the frames (``l - logit(p0)``, nats)
        and ``(M,)`` int frames that observed each (>= 1), for the per-frame evidence histograms
        (:func:`evidence_histograms`); None leaves them zero.

    Returns
    -------
    MapScores

    Raises
    ------
    PrismapInputError
        Shapes differ, the set is empty, ``P`` leaves ``[0, 1]`` or is NaN, ``occupied`` is not
        binary, or a bin count is not a positive integer.
    """
    p = as_float_array(probability, "probability", ndim=1, allow_nan=False)
    y = _as_binary(occupied, "occupied")
    if y.shape != p.shape:
        raise PrismapInputError(f"`occupied` must have the shape of `probability` {p.shape}; got {y.shape}")
    if p.size == 0:
        raise PrismapInputError("`probability` is empty: there are no voxels to score")
    if p.min() < 0.0 or p.max() > 1.0:
        raise PrismapInputError(f"`probability` must lie in [0, 1]; got values in [{p.min()}, {p.max()}]")
    n_bins = _check_count(n_bins, "n_bins")
    n_hist_bins = _check_count(n_hist_bins, "n_hist_bins")

    n_occupied = int(y.sum())
    n_free = int(p.size - n_occupied)
    log_loss = np.mean(log_loss_per_voxel(p, y))

    bin_edges = np.linspace(0.0, 1.0, n_bins + 1)
    bin_counts, bin_mean, bin_fraction = _reliability(
        p, y, np.minimum((p * n_bins).astype(np.int64), n_bins - 1), n_bins
    )
    n_logit = len(LOGIT_BIN_EDGES) - 1
    logit_index = np.clip(np.searchsorted(LOGIT_BIN_EDGES, p, side="right") - 1, 0, n_logit - 1)
    logit_counts, logit_mean, logit_fraction = _reliability(p, y, logit_index, n_logit)
    one_view, per_view = (
        (np.zeros(len(EVIDENCE_EDGES) - 1, np.int64),) * 2 if evidence is None else evidence_histograms(*evidence)
    )
    filled = bin_counts > 0
    ece = float(np.sum(bin_counts[filled] * np.abs(bin_mean[filled] - bin_fraction[filled])) / p.size)

    hist_edges = np.linspace(0.0, 1.0, n_hist_bins + 1)
    safety, threshold = safety_score(p, y)
    return MapScores(
        n_voxels=int(p.size),
        n_occupied=n_occupied,
        n_free=n_free,
        brier=float(np.mean((p - y) ** 2)),
        log_loss=float(log_loss),
        ece=ece,
        roc_auc=roc_auc(p, y),
        occupied_called_free=float(np.mean(p[y] < 0.5)) if n_occupied else float("nan"),
        free_called_occupied=float(np.mean(p[~y] > 0.5)) if n_free else float("nan"),
        safety_occupied_called_free=safety,
        safety_threshold=threshold,
        free_confident_occupied=float(np.mean(p[~y] >= CONFIDENT)) if n_free else float("nan"),
        occupied_confident_free=float(np.mean(p[y] <= 1.0 - CONFIDENT)) if n_occupied else float("nan"),
        free_share_at_high_p=_share(~y, p >= CONFIDENT),
        occupied_share_at_low_p=_share(y, p <= 1.0 - CONFIDENT),
        bin_edges=bin_edges,
        bin_counts=bin_counts.astype(np.int64),
        bin_mean_probability=bin_mean,
        bin_occupied_fraction=bin_fraction,
        hist_edges=hist_edges,
        hist_free=np.histogram(p[~y], bins=hist_edges)[0].astype(np.int64),
        hist_occupied=np.histogram(p[y], bins=hist_edges)[0].astype(np.int64),
        logit_bin_edges=LOGIT_BIN_EDGES.copy(),
        logit_bin_counts=logit_counts,
        logit_bin_mean_probability=logit_mean,
        logit_bin_occupied_fraction=logit_fraction,
        evidence_edges=EVIDENCE_EDGES.copy(),
        evidence_one_view=one_view,
        evidence_per_view=per_view,
    )


def log_loss_per_voxel(p, y):
    """Each voxel's log-loss (nats): ``-log P`` where occupied, ``-log(1 - P)`` where free, ``P`` clipped to
    ``[LOG_LOSS_EPS, 1 - LOG_LOSS_EPS]``; :func:`score_map`'s ``log_loss`` is their mean."""
    clipped = np.clip(p, LOG_LOSS_EPS, 1.0 - LOG_LOSS_EPS)
    return -np.where(y, np.log(clipped), np.log1p(-clipped))


def _reliability(p, y, index, n_bins):
    """Counts, mean ``P`` and occupied fraction of the bins ``index`` puts each voxel in (NaN where empty)."""
    counts = np.bincount(index, minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(index, weights=p, minlength=n_bins) / counts
        fraction = np.bincount(index, weights=y, minlength=n_bins) / counts
    return counts.astype(np.int64), mean, fraction


def evidence_histograms(
    increments: npt.ArrayLike, counts: npt.ArrayLike
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """Histograms on :data:`EVIDENCE_EDGES` of the evidence frames gave the map's voxels.

    Parameters
    ----------
    increments : (M,) float, nats
        Each observed voxel's log-odds minus the prior's, ``l - logit(p0)``: the sum of its frames' increments.
    counts : (M,) int, >= 1
        Frames that observed each voxel.

    Returns
    -------
    one_view : (E,) int64
        Of the voxels one frame observed: that frame's increment exactly.
    per_view : (E,) int64
        Of every voxel: its mean increment per frame, ``increments / counts``.
    """
    total = as_float_array(increments, "increments", ndim=1, allow_nan=False)
    views = np.asarray(counts)
    if views.shape != total.shape or (views.size and (not np.issubdtype(views.dtype, np.integer) or views.min() < 1)):
        raise PrismapInputError(
            f"`counts` must be {total.shape} integers >= 1 (frames per observed voxel); got shape "
            f"{views.shape}, dtype {views.dtype}"
        )
    edges = EVIDENCE_EDGES
    inner = np.clip(total, edges[0], edges[-1])
    one_view = np.histogram(inner[views == 1], bins=edges)[0].astype(np.int64)
    per_view = np.histogram(np.clip(total / np.maximum(views, 1), edges[0], edges[-1]), bins=edges)[0].astype(np.int64)
    return one_view, per_view


def safety_score(
    probability: npt.ArrayLike, occupied: npt.ArrayLike, *, free_share: float = SAFETY_FREE_SHARE
) -> tuple[float, float]:
    """Share of truly occupied voxels called free at the threshold that calls ``free_share`` of the free ones free.

    A voxel is called free when ``P <= t``. The threshold ``t`` is the smallest such that at least
    ``free_share`` of the truly free voxels are called free: the ``k``-th smallest ``P`` of the free voxels,
    ``k = ceil(free_share n_free)``. Every voxel with ``P == t`` is called free, so occupied voxels tied
    with the free voxels the threshold must pass count against the map (a map that cannot separate them
    is not safe). Unlike the fraction called free at ``P < 0.5``, the score does not depend on the map's
    prior or on its calibration: any strictly increasing transform of ``P`` leaves it unchanged.

    Parameters
    ----------
    probability : (N,) float, in [0, 1]
        Predicted ``P(occupied)`` of each evaluated voxel.
    occupied : (N,) bool
        True occupancy of the same voxels.
    free_share : float in (0, 1], keyword-only

    Returns
    -------
    score : float
        Fraction of the truly occupied voxels with ``P <= t``; NaN without occupied or without free voxels.
    threshold : float
        ``t``; NaN without free voxels (no threshold is defined).
    """
    p = as_float_array(probability, "probability", ndim=1, allow_nan=False)
    y = _as_binary(occupied, "occupied")
    if y.shape != p.shape:
        raise PrismapInputError(f"`occupied` must have the shape of `probability` {p.shape}; got {y.shape}")
    share = float(free_share)
    if not 0.0 < share <= 1.0:
        raise PrismapInputError(f"`free_share` must lie in (0, 1]; got {free_share!r}")
    free = p[~y]
    if free.size == 0:
        return float("nan"), float("nan")
    k = max(1, math.ceil(Fraction(repr(share)) * free.size))  # exact: 0.9 * 70 is 63.00000000000001 in floats
    threshold = float(np.partition(free, k - 1)[k - 1])
    n_occupied = int(y.sum())
    score = float(np.count_nonzero(p[y] <= threshold) / n_occupied) if n_occupied else float("nan")
    return score, threshold


def roc_auc(score: npt.ArrayLike, positive: npt.ArrayLike) -> float:
    """Area under the ROC curve from ranks (Mann-Whitney U), ties counted one half.

    Parameters
    ----------
    score : (N,) float
        Higher means "more likely positive".
    positive : (N,) bool

    Returns
    -------
    float
        ``(sum of positive ranks - n_pos (n_pos + 1) / 2) / (n_pos n_neg)`` with average ranks for
        ties; NaN when either class is absent (the AUC is undefined).
    """
    s = as_float_array(score, "score", ndim=1, allow_nan=False)
    y = _as_binary(positive, "positive")
    if y.shape != s.shape:
        raise PrismapInputError(f"`positive` must have the shape of `score` {s.shape}; got {y.shape}")
    n_pos = int(y.sum())
    n_neg = y.size - n_pos
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(s)
    return float((ranks[y].sum() - n_pos * (n_pos + 1) / 2.0) / (n_pos * n_neg))


def _as_binary(value, name):
    array = np.asarray(value)
    if array.ndim != 1:
        raise PrismapInputError(f"`{name}` must be 1-D; got shape {array.shape}")
    if array.dtype == bool:
        return array
    if array.size and not (np.issubdtype(array.dtype, np.number) and np.all((array == 0) | (array == 1))):
        raise PrismapInputError(f"`{name}` must be boolean (or 0/1); got dtype {array.dtype} with other values")
    return array.astype(bool)


def _check_count(value, name):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise PrismapInputError(f"`{name}` must be a positive integer; got {value!r}")
    return int(value)
