"""One experiment cell (a matcher's disparities mapped with one sensor model), its scores, and the results table."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prismap._files import write_text_atomic
from prismap.errors import PrismapInputError
from prismap.evaluate import SCORE_COLUMNS, MapScores
from prismap.io import GroundTruthOccupancy
from prismap.sensor_models import prior_from_ground_truth

MODELS = ("ideal", "hitmiss", "convolution", "andert", "prism")
"""Every inverse sensor model of SENSOR_MODELS.md, in the order of the tables."""

CONDITIONED_SUFFIX = "_conditioned"
"""A cell's model ``NAME_conditioned`` maps with model NAME conditioned on the error classes."""
MODELS_3D = (
    "ideal",
    "hitmiss",
    "convolution",
    "convolution_conditioned",
    "andert",
    "andert_conditioned",
    "prism",
    "prism_conditioned",
)
"""The cells of the 3-D experiments, in table order: every model, and each model that uses the error model both
plain (the whole-image mixture) and conditioned (each pixel's class mixture)."""
MAP_PRIOR_SUFFIX = "_map_prior"
"""A cell's model ``NAME_map_prior`` (after any conditioned suffix) is PRISM with ``prior="map"``: each cell's prior
the map's current probability (ray mode only)."""
MODELS_3D_MAP_PRIOR = (*MODELS_3D, "prism" + CONDITIONED_SUFFIX + MAP_PRIOR_SUFFIX)
""":data:`MODELS_3D` and conditioned PRISM with the map as prior: a ray-mode run's opt-in (``models=``), not the
default: it costs several times conditioned PRISM's time (README, the 3-D room)."""


def split_variant(name):
    """``(model name, conditioned)`` of a cell's model: ``"prism_conditioned"`` -> ``("prism", True)``; a
    :data:`MAP_PRIOR_SUFFIX` is dropped first (see :func:`variant_params`)."""
    name = name.removesuffix(MAP_PRIOR_SUFFIX)
    if name.endswith(CONDITIONED_SUFFIX):
        return name[: -len(CONDITIONED_SUFFIX)], True
    return name, False


def variant_params(name):
    """The model parameters a cell's variant sets: ``{"prior": "map"}`` for ``..._map_prior``, else ``{}``."""
    return {"prior": "map"} if name.endswith(MAP_PRIOR_SUFFIX) else {}


def model_label(name, names=()):
    """The table label of a cell's model: ``prism (conditioned)``, ``prism (conditioned, map prior)``;
    ``prism (plain)`` when ``names`` has its conditioned twin."""
    model, conditioned = split_variant(name)
    variant = ["conditioned"] if conditioned else []
    if variant_params(name):
        variant.append("map prior")
    elif not conditioned and model + CONDITIONED_SUFFIX in names:
        variant.append("plain")
    return f"{model} ({', '.join(variant)})" if variant else model


RESULTS_FORMAT = "prismap-experiment-results"
RESULTS_VERSION = 3
"""Version 2 added the safety score (``safety_occupied_called_free``, ``safety_threshold``) to the scores; version 3
the "confident and wrong" rates, the logit-spaced reliability bins and the per-frame evidence histograms."""
READABLE_RESULTS_VERSIONS = (2, 3)
"""Results files these can read: a version-2 cell reads with NaN rates and empty bins (a run recomputes it)."""


@dataclass(frozen=True)
class CellResult:
    """Scores of one map: one matcher's (or error source's) disparities integrated with one sensor model.

    Attributes
    ----------
    matcher : str
        Stereo matcher name, or the label of the simulated error source.
    model : str
        Inverse sensor model name.
    scores : MapScores
        Against the ground truth's observed voxels (unknown voxels score as ``p0``).
    time_s : float, seconds
        Wall time of building the map (sensor model construction and every frame).
    n_frames : int
        Frames integrated.
    settings : dict
        The run's settings (world, sizes, seed, p0, ...): a cell is reused on resume only if they match.
    """

    matcher: str
    model: str
    scores: MapScores
    time_s: float
    n_frames: int
    settings: dict = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (scores via :meth:`MapScores.to_dict`, NaN as null)."""
        return {
            "format": RESULTS_FORMAT + "-cell",
            "version": RESULTS_VERSION,
            "matcher": self.matcher,
            "model": self.model,
            "time_s": self.time_s,
            "n_frames": self.n_frames,
            "settings": self.settings,
            "scores": self.scores.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "cell") -> CellResult:
        """Inverse of :meth:`to_dict`; ``source`` names the data in error messages."""
        try:
            if data["format"] != RESULTS_FORMAT + "-cell" or data["version"] not in READABLE_RESULTS_VERSIONS:
                raise PrismapInputError(
                    f"{source}: not a version {list(READABLE_RESULTS_VERSIONS)} experiment cell "
                    f"(format {data['format']!r}, version {data['version']!r})"
                )
            return cls(
                str(data["matcher"]),
                str(data["model"]),
                scores_from_dict(data["scores"]),
                float(data["time_s"]),
                int(data["n_frames"]),
                dict(data["settings"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise PrismapInputError(f"{source}: malformed experiment cell ({type(exc).__name__}: {exc})") from None


_INTEGER_ARRAYS = (
    "bin_counts",
    "hist_free",
    "hist_occupied",
    "logit_bin_counts",
    "evidence_one_view",
    "evidence_per_view",
)
"""The :class:`MapScores` arrays of counts (integers in JSON)."""


def scores_from_dict(data):
    """A :class:`MapScores` from :meth:`MapScores.to_dict` output (null back to NaN, lists to arrays)."""
    values = {}
    for name, value in data.items():
        if isinstance(value, list):
            value = np.array([np.nan if v is None else v for v in value])
            if name in _INTEGER_ARRAYS:
                value = value.astype(np.int64)
        elif value is None:
            value = float("nan")
        values[name] = value
    return MapScores(**values)


def prior_of(truth: GroundTruthOccupancy) -> float:
    """``p0`` for a map on ``truth``'s grid: the occupancy ratio of the voxels it observed (Laplace-smoothed).

    This is the "estimate it from a ground-truth map" rule of SENSOR_MODELS.md section 5: the fraction of
    the evaluated voxels that hold a solid. The sensor models and the map use the same value.
    """
    if truth.observed_keys.shape[0] == 0:
        raise PrismapInputError("the ground truth observes no voxel: no occupancy ratio, and nothing to score")
    occupied = np.zeros(truth.observed_keys.shape[0], dtype=bool)
    occupied[: truth.observed_occupied_keys.shape[0]] = True  # only the count matters
    return prior_from_ground_truth(occupied)


def cell_path(out_dir, matcher, model):
    """Where the cell ``(matcher, model)`` of a run in ``out_dir`` keeps its result JSON."""
    return Path(out_dir) / "cells" / f"{matcher}__{model}.json"


def write_cell(result, path):
    """Write a :class:`CellResult` as JSON, atomically."""
    write_text_atomic(path, json.dumps(result.to_dict(), indent=1) + "\n")


def read_cell(path, settings):
    """The cell stored at ``path`` if it exists and was computed with ``settings``; else None (recompute)."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PrismapInputError(f"{path}: unreadable experiment cell ({exc}); delete it to recompute") from None
    if isinstance(data, dict) and data.get("version") != RESULTS_VERSION:
        return None  # a cell of an older format lacks scores of this one: recompute it
    result = CellResult.from_dict(data, source=str(path))
    return result if result.settings == _plain(settings) else None


def _plain(value):
    """``value`` as it reads back from JSON (tuples become lists)."""
    return json.loads(json.dumps(value))


def format_results_table(results: Sequence[CellResult], *, title: str, notes: Sequence[str] = ()) -> str:
    """Markdown: one row per (matcher, model) with every score, the voxel counts and the mapping time."""
    header = ["matcher", "model", *(c[0] for c in SCORE_COLUMNS), "time (s)"]
    lines = [
        f"# {title}",
        "",
        *notes,
        *([""] if notes else []),
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    best = best_models(results)
    names = {result.model for result in results}
    for result in results:
        cells = [result.matcher, model_label(result.model, names)]
        for _, name, fmt, _ in SCORE_COLUMNS:
            value = getattr(result.scores, name)
            text = "n/a" if np.isnan(value) else fmt.format(value)
            if best.get((result.matcher, name)) == result.model:
                text = f"**{text}**"
            cells.append(text)
        cells.append(f"{result.time_s:.1f}")
        lines.append("| " + " | ".join(cells) + " |")
    first = results[0].scores if results else None
    if first is not None:
        counts = f"Scored voxels: {first.n_voxels} ({first.n_occupied} occupied, {first.n_free} free)."
        legend = (
            'Bold: the best model of each matcher on that score (lowest, highest for ROC AUC). "At 90 % free": '
            "occupied voxels called free (P <= t) at the threshold t that calls 90 % of the free ones free, "
            "whatever the prior."
        )
        lines += ["", f"{counts} {legend}"]
    return "\n".join(lines) + "\n"


def best_models(results):
    """``{(matcher, score name): model}``: each matcher's best model per score (its column's better direction)."""
    best = {}
    for _, name, _, better in SCORE_COLUMNS:
        if better is None:
            continue
        sign = -1.0 if better == "higher" else 1.0
        for result in results:
            value = getattr(result.scores, name)
            if np.isnan(value):
                continue
            key = (result.matcher, name)
            current = best.get(key)
            if current is None or sign * value < sign * current[1]:
                best[key] = (result.model, value)
    return {key: model for key, (model, _) in best.items()}


def write_results(
    results: Sequence[CellResult],
    out_dir: str | os.PathLike[str],
    *,
    title: str,
    notes: Sequence[str] = (),
    settings: dict[str, Any] | None = None,
    sections: Sequence[str] = (),
    extra: dict[str, Any] | None = None,
) -> dict[str, Path]:
    """Write ``results.md`` and ``results.json`` (every cell with its full scores) into ``out_dir``.

    ``sections`` (Markdown texts) follow the table in ``results.md``; ``extra`` (plain-JSON fields) joins
    ``results.json``.

    Returns
    -------
    dict of str -> Path: ``{"table": results.md, "json": results.json}``.
    """
    out = Path(out_dir)
    paths = {"table": out / "results.md", "json": out / "results.json"}
    table = format_results_table(results, title=title, notes=notes)
    write_text_atomic(paths["table"], "\n".join([table, *sections]))
    document = {
        "format": RESULTS_FORMAT,
        "version": RESULTS_VERSION,
        "title": title,
        "settings": settings or {},
        "cells": [r.to_dict() for r in results],
        **(extra or {}),
    }
    write_text_atomic(paths["json"], json.dumps(document, indent=1) + "\n")
    return paths


def read_results(path: str | os.PathLike[str]) -> list[CellResult]:
    """The cells of a ``results.json`` written by :func:`write_results`, as a list of :class:`CellResult`."""
    path = Path(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PrismapInputError(f"{path}: unreadable results file ({exc})") from None
    if not isinstance(document, dict) or document.get("format") != RESULTS_FORMAT:
        raise PrismapInputError(f"{path}: not a prismap experiment results file")
    return [CellResult.from_dict(cell, source=f"{path} cell {i}") for i, cell in enumerate(document.get("cells", []))]
