"""How a voxel's stored evidence is read as a probability when a matcher's failures repeat across views.

The map stores per voxel the log-odds sum ``l = logit(p0) + S`` (``S`` the sum of the frames' increments)
and the number ``n`` of frames that observed it; both add, so chunked (Dask), merged and checkpointed maps are
identical. Independent fusion reads ``P = sigmoid(l)``. :class:`PersistentFailure` reads the same two sums
under a per-voxel hidden "the matcher fails here" state that persists from view to view (a stationary
two-state Markov chain of rate ``r`` and persistence ``q``; docs/SENSOR_MODELS.md, "Fusion when failures
repeat"): a view in the failure state carries no evidence, and the probability is the average over the
number ``k`` of failed views of ``sigmoid(logit(p0) + (1 - k / n) S)``. Two readings keep every voxel within
the probabilities one view can reach under that state, ``[r p0, 1 - r (1 - p0)]``: no number of views is more
certain than one, because a failure that stays is indistinguishable from repeated true evidence.
:class:`FailureMixture` (the default) is the state's limit ``q -> 1``, ``r p0 + (1 - r) sigmoid(l)``;
:class:`FailureClamp` clamps the independent sum to that range. The update stays one integer addition per voxel
and frame; the read costs ``O(min(n, MAX_VIEWS))`` per voxel (:class:`PersistentFailure`) or ``O(1)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import ClassVar

import numpy as np
import numpy.typing as npt
from scipy.special import expit

from prismap._validate import check_probability
from prismap.errors import PrismapInputError
from prismap.grid._logodds import logit

MAX_VIEWS = 64
"""Counts above this read with the failure share distribution of ``MAX_VIEWS`` views (it has converged)."""

_CHUNK = 65536
"""Voxels read at once (bounds the ``(chunk, n + 1)`` temporary)."""


@dataclass(frozen=True)
class PersistentFailure:
    """A persistent per-voxel failure state: views in it carry no evidence about the voxel.

    Attributes
    ----------
    rate : float in [0, 1)
        ``r``: stationary probability that a view of a voxel is in the failure state (the matcher's gross
        error rate at the voxel's pixels).
    persistence : float in [rate, 1]
        ``q = P(fails in view t | failed in view t - 1)``. ``q = r`` is failures striking independently;
        ``q -> 1`` is a failure that, once there, stays for every view.
    """

    name: ClassVar[str] = "persistent-failure"
    rate: float
    persistence: float

    def __post_init__(self):
        rate = _check_rate(self.rate)
        persistence = check_probability(self.persistence, "persistence", open_interval=False)
        if persistence < rate:
            raise PrismapInputError(
                f"`persistence` {persistence!r} must be >= `rate` {rate!r} (a failure cannot "
                "make the next view's failure less likely than its base rate)"
            )
        object.__setattr__(self, "rate", rate)
        object.__setattr__(self, "persistence", persistence)

    def failure_counts(self, n_views: int) -> npt.NDArray[np.float64]:
        """``P(K = k)`` for ``k`` from 0 to ``n_views``: how many of ``n_views`` consecutive views are in the failure state.

        Returns
        -------
        (n_views + 1,) float64, summing to 1.
        """
        return _failure_counts(self.rate, self.persistence, int(n_views))

    def probability(self, log_odds: npt.ArrayLike, count: npt.ArrayLike, p0: float) -> npt.NDArray[np.float64]:
        """``P(occupied)`` of voxels with stored log-odds ``log_odds`` (``logit(p0)`` plus the frames' evidence)
        observed by ``count`` frames.

        Parameters
        ----------
        log_odds : (N,) float
        count : (N,) int, >= 0 (0 = unknown: the prior's log-odds read as ``p0``)
        p0 : float in (0, 1)

        Returns
        -------
        (N,) float64 in [0, 1]
        """
        log, count = _check_sums(log_odds, count)
        prior = float(logit(check_probability(p0, "p0")))
        evidence = log - prior
        out = expit(log)
        views = np.minimum(count.astype(np.int64), MAX_VIEWS)
        for n in np.unique(views[views > 0]):
            share = 1.0 - np.arange(n + 1) / n
            weight = self.failure_counts(n)
            where = np.flatnonzero(views == n)
            for start in range(0, where.size, _CHUNK):
                part = where[start : start + _CHUNK]
                out[part] = expit(prior + evidence[part, None] * share[None, :]) @ weight
        return np.clip(out, 0.0, 1.0, out=out)  # the weights sum to 1 only up to rounding

    def bounds(self, p0: float, n_views: int = 1) -> tuple[float, float]:
        """The probabilities ``(P_min, P_max)`` no evidence of ``n_views`` views can pass: all views failed
        (probability ``r q^(n - 1)``) leave the voxel at ``p0``."""
        stuck = float(self.failure_counts(n_views)[-1])
        p0 = check_probability(p0, "p0")
        return stuck * p0, 1.0 - stuck * (1.0 - p0)

    def to_dict(self) -> dict[str, float]:
        """JSON form."""
        return {"rate": self.rate, "persistence": self.persistence}


@dataclass(frozen=True)
class _OneViewBound:
    """A reading that holds every voxel within the probabilities one view can reach, ``[r p0, 1 - r (1 - p0)]``,
    for a matcher that fails at rate ``r`` (the bound :class:`PersistentFailure` gives one view).

    Attributes
    ----------
    rate : float in [0, 1)
        ``r``: the matcher's gross error rate at a voxel's pixels.
    """

    name: ClassVar[str]
    rate: float

    def __post_init__(self):
        object.__setattr__(self, "rate", _check_rate(self.rate))

    def probability(self, log_odds: npt.ArrayLike, count: npt.ArrayLike, p0: float) -> npt.NDArray[np.float64]:
        """``P(occupied)`` of voxels with stored log-odds ``log_odds`` observed by ``count`` frames.

        Parameters
        ----------
        log_odds : (N,) float
        count : (N,) int, >= 0 (0 = unknown: the prior's log-odds read as ``p0``, inside the bound)
        p0 : float in (0, 1)

        Returns
        -------
        (N,) float64 in ``[r p0, 1 - r (1 - p0)]``
        """
        log, _ = _check_sums(log_odds, count)
        return self._within_bound(expit(log), check_probability(p0, "p0"))

    def bounds(self, p0: float, n_views: int = 1) -> tuple[float, float]:
        """The probabilities ``(P_min, P_max)``: ``(r p0, 1 - r (1 - p0))`` for any ``n_views``."""
        p0 = check_probability(p0, "p0")
        return self.rate * p0, 1.0 - self.rate * (1.0 - p0)

    def to_dict(self) -> dict[str, float]:
        """JSON form."""
        return {"rate": self.rate}


@dataclass(frozen=True)
class FailureMixture(_OneViewBound):
    """The independent sum averaged with the prior by the chance ``r`` that the voxel's views fail for good.

    ``P = r p0 + (1 - r) sigmoid(l)`` for observed voxels: :class:`PersistentFailure` in the limit ``q -> 1`` (a
    failure, once there, stays for every view, so with probability ``r`` none of them says anything about the
    voxel; docs/SENSOR_MODELS.md (9.1)). Its range is :class:`FailureClamp`'s, but it is strictly increasing
    in ``l``: voxels keep the order the evidence gives them (the independent sum's ROC AUC), where the clamp ties
    every voxel beyond the bound. ``rate = 0`` is the independent sum.
    """

    name: ClassVar[str] = "failure-mixture"

    def _within_bound(self, p, p0):
        return self.rate * p0 + (1.0 - self.rate) * p


@dataclass(frozen=True)
class FailureClamp(_OneViewBound):
    """The independent sum clamped to the one-view bound of a matcher that fails at rate ``r``.

    ``P = clip(sigmoid(l), r p0, 1 - r (1 - p0))`` for observed voxels: the bound :class:`PersistentFailure`
    gives one view, held for any number of views (docs/SENSOR_MODELS.md (9.2)).
    ``rate = 0`` is the independent sum.
    """

    name: ClassVar[str] = "failure-clamp"

    def _within_bound(self, p, p0):
        return np.clip(p, *self.bounds(p0))


MapReading = PersistentFailure | FailureMixture | FailureClamp
"""How a map reads its stored sums other than as the independent sum (None)."""

READINGS = {reading.name: reading for reading in (FailureMixture, FailureClamp, PersistentFailure)}
"""The :data:`MapReading` classes by their ``name`` (``prismap map --fusion``, the map file's ``fusion_model``)."""

MAP_READINGS = (*READINGS, "independent")
"""Names of the ways a map can read its sums given a matcher's failure state: :class:`FailureMixture`,
:class:`FailureClamp`, :class:`PersistentFailure` and the independent sum. The first is the default."""


def _check_rate(rate):
    """``rate`` as a float in [0, 1) (a matcher that always fails carries no evidence)."""
    rate = check_probability(rate, "rate", open_interval=False)
    if rate == 1.0:
        raise PrismapInputError("`rate` must lie in [0, 1): a matcher that always fails carries no evidence")
    return rate


def _check_sums(log_odds, count):
    """A map's stored sums as arrays: ``(N,)`` float64 log-odds and ``(N,)`` counts of one shape."""
    log, count = np.asarray(log_odds, dtype=np.float64), np.asarray(count)
    if log.shape != count.shape or log.ndim != 1:
        raise PrismapInputError(f"`log_odds` and `count` must be 1-D of one shape; got {log.shape} and {count.shape}")
    return log, count


@lru_cache(maxsize=256)
def _failure_counts(rate, persistence, n_views):
    if n_views < 1:
        raise PrismapInputError(f"`n_views` must be a positive integer; got {n_views!r}")
    start = rate * (1.0 - persistence) / (1.0 - rate)  # P(fail | good before): keeps the chain stationary
    good, failed = np.zeros(n_views + 1), np.zeros(n_views + 1)  # by failures so far, last view good / failed
    good[0], failed[1] = 1.0 - rate, rate
    for _ in range(n_views - 1):
        next_good = good * (1.0 - start) + failed * (1.0 - persistence)
        next_failed = np.zeros_like(failed)
        next_failed[1:] = good[:-1] * start + failed[:-1] * persistence
        good, failed = next_good, next_failed
    counts = good + failed
    counts.setflags(write=False)
    return counts
