"""End-to-end experiments: every sensor model mapped and scored against exact ground truth, and the demo."""

from prismap.experiment._cells import ExperimentResult
from prismap.experiment._models_compare import ModelsComparison, run_models_compare
from prismap.experiment._office2d import SGBM_LIKE_MIXTURE, run_office2d
from prismap.experiment._results import (
    MODELS,
    CellResult,
    format_results_table,
    prior_of,
    read_results,
    score_grid,
    write_results,
)
from prismap.experiment._scene3d import MATCHERS, run_scene3d, split_frames

__all__ = [
    "MATCHERS",
    "MODELS",
    "SGBM_LIKE_MIXTURE",
    "CellResult",
    "ExperimentResult",
    "ModelsComparison",
    "format_results_table",
    "prior_of",
    "read_results",
    "run_models_compare",
    "run_office2d",
    "run_scene3d",
    "score_grid",
    "split_frames",
    "write_results",
]
