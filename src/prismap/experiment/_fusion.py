"""The fusion comparison of the 3-D experiments: each error-model map read under independent fusion, the
persistent-failure model fitted on the characterisation frames, its limit of a failure that stays for every view
(``prismap map``'s default reading, which the run's maps take) and clamping at that model's one-view bound.

Every reading is a function of the stored sums (log-odds, count), so one map serves all four and the comparison
costs no mapping (docs/SENSOR_MODELS.md, "Fusion when a matcher's failures repeat").
"""

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.special import expit, logit

from prismap.evaluate import EXTREME_COLUMNS, align_to_ground_truth, score_map
from prismap.grid import FailureClamp, FailureMixture

FUSIONS = ("independent", "persistent failure", "failure for good", "clamped at one view")
"""The readings compared, in table order."""

FUSION_COLUMNS = (
    ("Brier", "brier", "{:.4f}"),
    ("log-loss", "log_loss", "{:.4f}"),
    ("ECE", "ece", "{:.4f}"),
    ("ROC AUC", "roc_auc", "{:.4f}"),
    ("at 90 % free", "safety_occupied_called_free", "{:.4f}"),
    *EXTREME_COLUMNS,
)
"""(label, MapScores field, format) of the section's columns."""


@dataclass(frozen=True)
class FusionRow:
    """One map read one way: ``scores`` (MapScores) of ``matcher``'s ``model`` map under ``fusion``."""

    matcher: str
    model: str
    fusion: str
    scores: object

    def to_dict(self):
        """Plain-JSON form (the scores' numbers, not their bins)."""
        return {
            "matcher": self.matcher,
            "model": self.model,
            "fusion": self.fusion,
            **{name: _plain(getattr(self.scores, name)) for _, name, _ in FUSION_COLUMNS},
        }


FUSED_MODELS = ("andert", "prism")
"""Models whose maps the comparison reads (those that use the error model), plain and conditioned."""


def fit_run_fusion(out_dir, char_frames, matcher, camera, error_model):
    """Fit a matcher's fusion block on the run's characterisation frames, before any map is made.

    The block joins the matcher's error model (``out_dir/characterisation/error_model.json``), so the maps take
    ``prismap map``'s default reading of it, as a user's run would.

    Parameters
    ----------
    out_dir : Path
        The matcher's folder; its disparities of ``char_frames`` go to ``out_dir/fusion_disparity/`` (reused
        on resume).
    char_frames : sequence of StereoFrame
        The run's characterisation frames, with truth and poses.
    matcher : prismap.stereo.StereoMatcher
    camera : StereoCamera
    error_model : ErrorModel
        The matcher's characterised error model.

    Returns
    -------
    ErrorModel
        ``error_model`` with the fitted block (:func:`prismap.characterise.fit_fusion`), or unchanged when the
        frames cannot fit one (too few surface points seen from consecutive positions).
    """
    from prismap.characterise import fit_fusion, write_error_model
    from prismap.errors import PrismapInputError
    from prismap.experiment._steps3d import match_frames, read_disparities

    disparity_dir = match_frames(Path(out_dir) / "fusion_disparity", char_frames, matcher)
    try:
        block = fit_fusion(char_frames, list(read_disparities(disparity_dir, len(char_frames))), camera)
    except PrismapInputError:
        return error_model
    fused = replace(error_model, fusion=block)
    write_error_model(fused, Path(out_dir) / "characterisation" / "error_model.json")
    return fused


def compare_run_fusions(matcher_name, error_model, maps, truth):
    """One matcher's part of a 3-D run's fusion comparison: its error-model maps under every reading.

    Parameters
    ----------
    matcher_name : str
    error_model : ErrorModel
        The matcher's error model after :func:`fit_run_fusion`.
    maps : dict of str -> OccupancyMap
        The matcher's map of each cell model (:func:`~prismap.experiment._cells.run_cells`).
    truth : GroundTruthOccupancy

    Returns
    -------
    list of FusionRow
        Empty when the error model has no fusion block.
    """
    failure = error_model.persistent_failure
    if failure is None:
        return []
    fused = {(matcher_name, model): grid for model, grid in maps.items() if model.startswith(FUSED_MODELS)}
    return compare_fusions(fused, truth, {matcher_name: failure})


def fused_probabilities(log_odds, counts, p0, failure):
    """``P(occupied)`` of voxels with stored ``log_odds`` and ``counts`` under every reading of :data:`FUSIONS`.

    Parameters
    ----------
    log_odds : (N,) float
    counts : (N,) int
    p0 : float
    failure : prismap.grid.PersistentFailure

    Returns
    -------
    dict of str -> (N,) float64
    """
    return {
        "independent": expit(np.asarray(log_odds, dtype=np.float64)),
        "persistent failure": failure.probability(log_odds, counts, p0),
        "failure for good": FailureMixture(failure.rate).probability(log_odds, counts, p0),
        "clamped at one view": FailureClamp(failure.rate).probability(log_odds, counts, p0),
    }


def compare_fusions(maps, truth, failures):
    """Score each map under every reading.

    Parameters
    ----------
    maps : dict of (matcher, model) -> OccupancyMap
    truth : GroundTruthOccupancy
    failures : dict of matcher -> prismap.grid.PersistentFailure

    Returns
    -------
    list of FusionRow
    """
    rows = []
    for (matcher, model), grid in maps.items():
        keys, log, counts = grid.known_voxels()
        evidence = (log - logit(grid.p0), counts)
        for fusion, probability in fused_probabilities(log, counts, grid.p0, failures[matcher]).items():
            p, occupied = align_to_ground_truth(keys, probability, truth.occupied_keys, truth.observed_keys, p0=grid.p0)
            rows.append(FusionRow(matcher, model, fusion, score_map(p, occupied, evidence=evidence)))
    return rows


def format_fusion_section(rows, failures):
    """Markdown section: the fitted failure models (matcher -> PersistentFailure, None = not fitted) and every map
    under every reading."""
    lines = [
        "## Fusion of repeated failures",
        "",
        "Each error-model map read four ways from the same stored sums: the independent sum; the persistent "
        "failure state (rate r and persistence q fitted on the characterisation frames, errors beyond "
        "3 px; docs/SENSOR_MODELS.md); its limit q -> 1, a failure for good, r p0 + (1 - r) sigmoid(l) (the "
        "default); the independent sum clamped to that model's one-view bound [r p0, 1 - r (1 - p0)]. "
        + "; ".join(
            f"{name}: r = {f.rate:.4f}, q = {f.persistence:.3f}"
            if f is not None
            else f"{name}: not fitted (too few surface points seen from consecutive characterisation positions)"
            for name, f in failures.items()
        )
        + ".",
        "",
        "| matcher | model | fusion | " + " | ".join(label for label, _, _ in FUSION_COLUMNS) + " |",
        "|---|---|---|" + "---|" * len(FUSION_COLUMNS),
    ]
    for row in rows:
        values = [_cell(fmt, getattr(row.scores, name)) for _, name, fmt in FUSION_COLUMNS]
        lines.append(f"| {row.matcher} | {row.model} | {row.fusion} | " + " | ".join(values) + " |")
    return "\n".join(lines + [""])


def _cell(fmt, value):
    """``value`` in ``fmt``; a dash for NaN (no voxel at that extreme)."""
    return "-" if np.isnan(value) else fmt.format(value)


def _plain(value):
    value = float(value)
    return None if np.isnan(value) else value
