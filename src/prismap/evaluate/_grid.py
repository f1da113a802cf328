"""A map scored against ground-truth occupancy: the one place a map's voxels meet the scores."""

from __future__ import annotations

from scipy.special import logit

from prismap.evaluate._align import align_to_ground_truth
from prismap.evaluate._scores import MapScores, score_map
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
    keys, probability, log, counts = grid.known_probabilities()
    probability, occupied = align_to_ground_truth(
        keys, probability, truth.occupied_keys, truth.observed_keys, p0=grid.p0
    )
    return score_map(probability, occupied, evidence=(log - logit(grid.p0), counts))
