"""Scores of an occupancy map against ground-truth occupancy (SENSOR_MODELS.md section 6)."""

from prismap.evaluate._align import align_to_ground_truth
from prismap.evaluate._scores import (
    LOG_LOSS_EPS,
    SAFETY_FREE_SHARE,
    SCORE_COLUMNS,
    MapScores,
    roc_auc,
    safety_score,
    score_map,
)

__all__ = [
    "LOG_LOSS_EPS",
    "SAFETY_FREE_SHARE",
    "SCORE_COLUMNS",
    "MapScores",
    "align_to_ground_truth",
    "roc_auc",
    "safety_score",
    "score_map",
]
