"""A map scored against ground-truth occupancy: the one place a map's voxels meet the scores."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import logit

from prismap.evaluate._align import align_with_known
from prismap.evaluate._scores import LOG_LOSS_EPS, MapScores, log_loss_per_voxel, score_map
from prismap.grid import OccupancyMap
from prismap.io import GroundTruthOccupancy


def score_grid(grid: OccupancyMap, truth: GroundTruthOccupancy) -> MapScores:
    """Score ``grid`` on every voxel ``truth`` observed; an unknown voxel scores as ``grid.p0``.

    Parameters
    ----------
    grid : prismap.grid.OccupancyMap
    truth : prismap.io.GroundTruthOccupancy
        Its ``occupied_keys`` and ``observed_keys`` on the map's voxel grid.

    Returns
    -------
    MapScores
        With the per-frame evidence histograms of every voxel the map observed.
    """
    return _scores(_scored_voxels(grid, truth), grid.p0)


def score_grid_with_sources(
    grid: OccupancyMap, truth: GroundTruthOccupancy
) -> tuple[MapScores, dict[str, dict[str, dict[str, float]]]]:
    """:func:`score_grid` and :func:`log_loss_sources` of ``grid`` against ``truth``, aligning the two once."""
    scored = _scored_voxels(grid, truth)
    return _scores(scored, grid.p0), _sources(scored, grid.p0)


class _ScoredVoxels(NamedTuple):
    """``P`` and true state of every voxel the truth observed (unknown ones at the map's ``p0``), whether the map
    holds each, and the stored log-odds and counts of every voxel the map holds."""

    probability: np.ndarray
    occupied: np.ndarray
    known: np.ndarray
    log_odds: np.ndarray
    counts: np.ndarray


def _scores(scored, p0):
    return score_map(scored.probability, scored.occupied, evidence=(scored.log_odds - logit(p0), scored.counts))


def _scored_voxels(grid, truth):
    """``grid`` aligned with ``truth`` once, for the scores and the log-loss sources."""
    keys, probability, log, counts = grid.known_probabilities()
    probability, occupied, known = align_with_known(
        keys, probability, truth.occupied_keys, truth.observed_keys, p0=grid.p0
    )
    return _ScoredVoxels(probability, occupied, known, log, counts)


NEAR_PRIOR_LOG_ODDS = 0.5
"""An observed voxel whose log-odds lie within this of ``logit(p0)`` counts as "near the prior" in
:func:`log_loss_sources`: its frames left it about where it started."""

EVIDENCE_LEVELS = ("never observed", "near the prior", "with evidence")
"""The voxel groups of :func:`log_loss_sources`, by what the map learnt about them."""


def log_loss_sources(grid: OccupancyMap, truth: GroundTruthOccupancy) -> dict[str, dict[str, dict[str, float]]]:
    """Where ``grid``'s log-loss against ``truth`` comes from: its scored voxels split by what the map learnt
    (:data:`EVIDENCE_LEVELS`: never observed, so scored at ``p0``; observed but within
    :data:`NEAR_PRIOR_LOG_ODDS` of the prior's log-odds; observed with evidence) and by their true state.

    The loss no inverse sensor model can lower lives in the first two groups (pixels without a disparity,
    occluded voxels); a sensor model is judged by the third.

    Returns
    -------
    dict
        ``{level: {"occupied" | "free": {"voxels": n, "log_loss": nats}}}``; ``log_loss`` is the group's summed
        loss divided by every scored voxel, so the six add up to :func:`score_grid`'s ``log_loss``.
    """
    return _sources(_scored_voxels(grid, truth), grid.p0)


def _sources(scored, p0):
    probability, occupied, known = scored.probability, scored.occupied, scored.known
    loss = log_loss_per_voxel(probability, occupied)
    near = np.abs(logit(np.clip(probability, LOG_LOSS_EPS, 1.0 - LOG_LOSS_EPS)) - logit(p0)) < NEAR_PRIOR_LOG_ODDS
    groups = dict(zip(EVIDENCE_LEVELS, (~known, known & near, known & ~near)))
    n = max(loss.size, 1)
    return {
        level: {
            state: {"voxels": int(np.sum(member & truly)), "log_loss": float(loss[member & truly].sum() / n)}
            for state, truly in (("occupied", occupied), ("free", ~occupied))
        }
        for level, member in groups.items()
    }
