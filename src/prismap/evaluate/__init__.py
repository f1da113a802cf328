"""Scores of an occupancy map against ground-truth occupancy (SENSOR_MODELS.md section 6)."""

from prismap.evaluate._align import align_to_ground_truth
from prismap.evaluate._grid import (
    EVIDENCE_LEVELS,
    NEAR_PRIOR_LOG_ODDS,
    log_loss_sources,
    score_grid,
    score_grid_with_sources,
)
from prismap.evaluate._scores import (
    CONFIDENT,
    EVIDENCE_EDGES,
    EXTREME_COLUMNS,
    LOG_LOSS_EPS,
    LOGIT_BIN_EDGES,
    SAFETY_FREE_SHARE,
    SCORE_COLUMNS,
    MapScores,
    evidence_histograms,
    roc_auc,
    safety_score,
    score_map,
)

__all__ = [
    "CONFIDENT",
    "EVIDENCE_EDGES",
    "EVIDENCE_LEVELS",
    "LOG_LOSS_EPS",
    "LOGIT_BIN_EDGES",
    "NEAR_PRIOR_LOG_ODDS",
    "SAFETY_FREE_SHARE",
    "EXTREME_COLUMNS",
    "SCORE_COLUMNS",
    "MapScores",
    "align_to_ground_truth",
    "evidence_histograms",
    "log_loss_sources",
    "roc_auc",
    "safety_score",
    "score_grid",
    "score_grid_with_sources",
    "score_map",
]
