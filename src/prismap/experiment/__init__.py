"""End-to-end experiments: every sensor model mapped and scored against exact ground truth, and the demo."""

from prismap.evaluate import score_grid  # the scores of every cell, re-exported for the experiments' users
from prismap.experiment._cells import ExperimentResult
from prismap.experiment._office2d import SGBM_LIKE_MIXTURE, run_office2d
from prismap.experiment._results import (
    CONDITIONED_SUFFIX,
    MAP_PRIOR_SUFFIX,
    MODELS,
    MODELS_3D,
    MODELS_3D_MAP_PRIOR,
    CellResult,
    format_results_table,
    prior_of,
    read_results,
    write_results,
)
from prismap.experiment._scene3d import run_rendered_world, run_scene3d, run_street3d
from prismap.experiment._sources3d import SOURCES, run_error_sources
from prismap.experiment._targets import Target, measure_targets
from prismap.experiment._worlds3d import MATCHERS, WORLDS, split_frames

__all__ = [
    "SOURCES",
    "run_error_sources",
    "CONDITIONED_SUFFIX",
    "MAP_PRIOR_SUFFIX",
    "MATCHERS",
    "MODELS",
    "MODELS_3D",
    "MODELS_3D_MAP_PRIOR",
    "SGBM_LIKE_MIXTURE",
    "WORLDS",
    "CellResult",
    "ExperimentResult",
    "Target",
    "format_results_table",
    "measure_targets",
    "prior_of",
    "read_results",
    "run_office2d",
    "run_rendered_world",
    "run_scene3d",
    "run_street3d",
    "score_grid",
    "split_frames",
    "write_results",
]
