"""The shared part of both experiments: map with every model (resumably), score, and draw the figures."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from prismap._files import write_text_atomic
from prismap.errors import PrismapInputError
from prismap.evaluate import score_grid
from prismap.experiment._results import CellResult, cell_path, read_cell, write_cell


@dataclass(frozen=True)
class ExperimentResult:
    """What an experiment run produced.

    Attributes
    ----------
    world : str
        ``"office2d"`` or ``"scene3d"``.
    cells : tuple of CellResult
        Every (matcher, model) pair, in table order.
    p0 : float
        Prior occupancy used by every map and sensor model (the ground truth's occupancy ratio).
    settings : dict
        The run's settings, as written to ``settings.json``.
    artifacts : tuple of (Path, str)
        Every table and figure written, with a one-line caption.
    """

    world: str
    cells: tuple
    p0: float
    settings: dict
    artifacts: tuple

    def cell(self, matcher: str, model: str) -> CellResult:
        """The :class:`CellResult` of ``(matcher, model)``; raises if the run has none."""
        for result in self.cells:
            if result.matcher == matcher and result.model == model:
                return result
        raise PrismapInputError(f"the {self.world} run has no cell ({matcher!r}, {model!r})")


def claim_out_dir(out_dir, settings):
    """Use ``out_dir`` for a run with ``settings``: a fresh directory, or one holding a run of the same settings.

    Resuming is only safe when every file already there was made with the same settings, so a directory
    holding another run's ``settings.json`` is refused.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise PrismapInputError(f"--out {out}: exists and is not a directory")
    path = out / "settings.json"
    plain = json.loads(json.dumps(settings))
    if path.is_file():
        try:
            existing = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise PrismapInputError(f"{path}: unreadable ({exc}); delete it or choose another --out") from None
        if existing != plain:
            changed = sorted(k for k in set(existing) | set(plain) if existing.get(k) != plain.get(k))
            raise PrismapInputError(
                f"--out {out} holds a run with other settings (differing: {', '.join(changed)}); "
                "choose another --out or delete it"
            )
    write_text_atomic(path, json.dumps(plain, indent=1) + "\n")
    return out


def run_cells(out_dir, matcher, models, build_map, truth, settings):
    """Map and score ``matcher``'s data with every model of ``models``, skipping finished cells.

    Parameters
    ----------
    out_dir : Path
        Cells live in ``out_dir/cells/MATCHER__MODEL.json`` with the map beside it (``.npz``).
    matcher : str
    models : sequence of str
    build_map : callable
        ``build_map(model_name) -> OccupancyMap``, the map of all frames with that model. When it has a
        ``record(model_name, map_path)`` attribute, that is called after each new map is written (to write
        the command that reproduces it beside it).
    truth : GroundTruthOccupancy
    settings : dict

    Returns
    -------
    results : list of CellResult
    maps : dict of str -> OccupancyMap
    """
    from prismap.io import load_map, save_map

    results, maps = [], {}
    for model in models:
        json_path = cell_path(out_dir, matcher, model)
        map_path = json_path.with_suffix(".npz")
        result = read_cell(json_path, settings) if map_path.is_file() else None
        if result is None:
            start = time.perf_counter()
            grid = build_map(model)
            elapsed = time.perf_counter() - start
            save_map(grid, map_path)
            if hasattr(build_map, "record"):
                build_map.record(model, map_path)
            result = CellResult(matcher, model, score_grid(grid, truth), elapsed, grid.n_frames, settings)
            write_cell(result, json_path)
        else:
            grid = load_map(map_path)
        results.append(result)
        maps[model] = grid
    return results, maps


def draw_figures(out_dir, matcher, results, maps, truth, *, layer, where):
    """Reliability diagrams, P and evidence histograms and map slices of one matcher's maps; returns
    ``[(path, caption)]``."""
    from prismap.plots import plot_map_slices, plot_probability_histograms, plot_reliability

    out = Path(out_dir)
    scores = {r.model: r.scores for r in results}
    reliability = out / f"reliability_{matcher}.png"
    histograms = out / f"histograms_{matcher}.png"
    slices = out / f"map_slices_{matcher}.png"
    plot_reliability(scores, path=reliability, title=f"Reliability, {matcher}")
    plot_probability_histograms(scores, path=histograms)
    plot_map_slices(maps, truth, layer=layer, path=slices, title=f"{matcher}: {where}", scores_by_model=scores)
    return [
        (reliability, f"Reliability diagram of every model's map ({matcher}); the diagonal is perfect calibration."),
        (histograms, f"P(occupied) of truly free and truly occupied voxels per model ({matcher})."),
        (slices, f"Map slices ({where}) of every model beside the ground truth ({matcher})."),
        *draw_extreme_figures(out, matcher, scores),
    ]


def draw_extreme_figures(out_dir, matcher, scores):
    """The figures of the scale's extremes for one matcher's maps (``scores``: model -> MapScores): the
    logit-spaced reliability diagram and the per-frame evidence histograms; returns ``[(path, caption)]``."""
    from prismap.plots import plot_evidence_histograms, plot_reliability_logit

    out = Path(out_dir)
    logit_path, evidence_path = out / f"reliability_logit_{matcher}.png", out / f"evidence_{matcher}.png"
    plot_reliability_logit(scores, path=logit_path, title=f"Reliability at the extremes, {matcher}")
    figures = [
        (
            logit_path,
            f"Reliability on log-odds axes, bins reaching P = 1e-4 and 1 - 1e-4, with each model's "
            f'"confident and wrong" rates ({matcher}).',
        )
    ]
    if any(s.evidence_per_view.any() for s in scores.values()):
        plot_evidence_histograms(scores, path=evidence_path, title=f"Evidence per frame, {matcher}")
        figures.append(
            (
                evidence_path,
                f"Log-odds increments per frame of the voxels each model's map observed "
                f"({matcher}): one frame's for voxels seen once, the mean for all.",
            )
        )
    return figures
