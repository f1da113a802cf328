"""Where the error model comes from: ground truth, a LiDAR beside the camera, or the sequence itself.

The 3-D experiment of a world (:func:`prismap.experiment.run_rendered_world`, its PRISM cells only) gives the
matchers' disparities of the mapping frames, the ground-truth-characterised error model and its maps. The same
mapping frames are then mapped with PRISM using three other error models of the same matcher:

* ``lidar``: characterised on the same characterisation frames against a simulated 64-beam LiDAR beside the
  camera (:func:`prismap.sim.lidar_disparity`, occlusions handled), instead of the exact disparity;
* ``self``: self-characterised from the mapping frames alone, no ground truth
  (:func:`prismap.characterise.self_characterise`);
* ``motorcycle``: characterised on Middlebury's Motorcycle pair, another rig (what a user without any of
  the above would borrow).

Every map is scored against the exact occupancy, and every model's log-likelihood of the mapping frames'
exact errors is measured, per class of the self-characterised model beside the ground-truth model's.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from prismap._files import write_text_atomic
from prismap.errors import PrismapInputError

SOURCES = ("ground-truth", "lidar", "self", "motorcycle")
"""Error-model sources, in table order."""
SOURCE_MODELS = ("prism", "prism_conditioned")
"""The cells mapped with each source's error model."""
SOURCE_MATCHERS = ("bm", "sgbm")
SCORE_FIELDS = ("brier", "log_loss", "ece", "roc_auc", "occupied_called_free", "free_called_occupied")
LOWER_IS_BETTER = {
    "brier": True,
    "log_loss": True,
    "ece": True,
    "roc_auc": False,
    "occupied_called_free": True,
    "free_called_occupied": True,
}
WITHIN = 0.05
"""The self-characterised model's maps must score within 5 % of the ground-truth model's on Brier and log-loss."""
LIDAR_WITHIN_NATS = 0.05
"""The LiDAR model's held-out log-likelihood must lie within this many nats per error of the ground-truth one."""


def _motorcycle_model(folder, matcher_name):
    """The matcher characterised on Middlebury's Motorcycle pair (reused when its files exist)."""
    from prismap.experiment._steps3d import characterise_frames, matcher_for
    from prismap.io import load_middlebury_motorcycle

    frame = load_middlebury_motorcycle()
    truth = frame.disparity_gt
    matcher = matcher_for(matcher_name, float(np.max(truth[np.isfinite(truth)])))
    return characterise_frames(folder, [frame], matcher, "middlebury-motorcycle")[0]


def _self_model(folder, frames, matcher):
    """The matcher self-characterised on ``frames`` (reused when its file exists) and the method's record."""
    from prismap.characterise import load_error_model, self_characterise, write_characterisation

    path = folder / "error_model.json"
    if not path.is_file():
        result = self_characterise(frames, matcher, dataset="the mapping frames, self-characterised")
        write_characterisation(result.characterisation, folder)
    return load_error_model(path)


def class_log_likelihoods(model, reference, frames, disparities):
    """Log-likelihood of the frames' exact errors under ``model`` and ``reference``, per class of ``model``.

    Each pixel with a computed and a true disparity and a class of both models is scored by its class's
    mixture in each model, so the two columns of a row are the same errors.

    Returns
    -------
    list of dict
        Per class of ``model``: ``class``, ``n_errors``, ``model_nats_per_error``, ``reference_nats_per_error``;
        the last row, ``class`` "all", every class together.
    """
    totals = np.zeros((model.n_classes, 3))
    for frame, disparity in zip(frames, disparities):
        errors = np.asarray(frame.disparity_gt, np.float64) - disparity
        labels = [
            m.classify_frame(frame.left, frame.right, disparity)
            if m.conditioned
            else np.where(np.isfinite(disparity), 0, -1)
            for m in (model, reference)
        ]
        keep = np.isfinite(errors) & (labels[0] >= 0) & (labels[1] >= 0)
        errors, mine, theirs = errors[keep], labels[0][keep], labels[1][keep]
        logs = [np.empty(errors.size), np.empty(errors.size)]
        for out, m, label in ((logs[0], model, mine), (logs[1], reference, theirs)):
            for k, mixture in enumerate(m.class_mixtures):
                out[label == k] = mixture.logpdf(errors[label == k])
        for k in range(model.n_classes):
            at = mine == k
            totals[k] += (at.sum(), logs[0][at].sum(), logs[1][at].sum())
    if totals[:, 0].sum() == 0:
        raise PrismapInputError("no mapping-frame pixel has a computed and a true disparity and a class of both models")
    rows = [
        {
            "class": k,
            "n_errors": int(n),
            "model_nats_per_error": a / n if n else None,
            "reference_nats_per_error": b / n if n else None,
        }
        for k, (n, a, b) in enumerate(totals)
    ]
    n, a, b = totals.sum(axis=0)
    return rows + [
        {"class": "all", "n_errors": int(n), "model_nats_per_error": a / n, "reference_nats_per_error": b / n}
    ]


def run_error_sources(
    world: str,
    out_dir: str | os.PathLike[str],
    *,
    quick: bool = False,
    n_frames: int | None = None,
    seed: int = 0,
    matchers: Sequence[str] = SOURCE_MATCHERS,
    models: Sequence[str] = SOURCE_MODELS,
    between_frames: int | None = None,
) -> dict[str, Any]:
    """Map ``world``'s mapping frames with PRISM using each source's error model, score them, write the tables.

    Parameters
    ----------
    world : str
        ``"scene3d"`` or ``"street3d"``.
    out_dir : str or Path
        ``ground-truth/`` holds the world's own experiment (its PRISM cells); ``lidar/``, ``self/`` and
        ``motorcycle/`` each source's characterisations and cells; ``sources.md`` and ``sources.json`` the
        comparison. A rerun reuses finished steps.
    quick, n_frames, seed, between_frames
        Sizes of the world's experiment (:func:`prismap.experiment.run_rendered_world`).
    matchers : sequence of str
    models : sequence of str
        PRISM cells (plain and conditioned).

    Returns
    -------
    dict
        The comparison as written to ``sources.json``: ``cells`` (per matcher, model and source the scores),
        ``likelihood`` (per matcher and source, and per class of the self model beside the ground-truth
        model), ``targets`` (each target with its measured value and whether it is met), ``settings``.
    """
    from dataclasses import replace

    from prismap.experiment._cells import run_cells
    from prismap.experiment._report3d import mapped_log_likelihood
    from prismap.experiment._results import prior_of
    from prismap.experiment._scene3d import run_rendered_world
    from prismap.experiment._steps3d import (
        characterise_frames,
        derived_model_params,
        mapper,
        matcher_for,
        read_disparities,
    )
    from prismap.experiment._worlds3d import render_world
    from prismap.io import read_sequence
    from prismap.sim import lidar_disparity

    out = Path(out_dir)
    base = run_rendered_world(
        world,
        out / "ground-truth",
        n_frames=n_frames,
        seed=seed,
        quick=quick,
        matchers=matchers,
        models=models,
        between_frames=between_frames,
    )
    settings = base.settings
    scene, _, drive_char_frames, char_frames, map_frames = render_world(settings)
    sequence = read_sequence(out / "ground-truth" / "sequence")
    truth = sequence.ground_truth
    p0 = prior_of(truth)
    model_params = derived_model_params(settings, scene, drive_char_frames)
    largest = max(float(np.nanmax(f.disparity_gt)) for f in char_frames + map_frames)
    lidar_frames = [replace(f, disparity_gt=lidar_disparity(scene, f, rng=seed + i)) for i, f in enumerate(char_frames)]
    cells = {(c.matcher, c.model, "ground-truth"): c for c in base.cells}
    likelihood, error_models = {}, {}
    for name in matchers:
        matcher = matcher_for(name, largest)
        disparity_dir = out / "ground-truth" / name / "disparity"
        error_models[name] = {
            "ground-truth": characterise_frames(
                out / "ground-truth" / name / "characterisation", char_frames, matcher, ""
            )[0],
            "lidar": characterise_frames(
                out / "lidar" / name / "characterisation",
                lidar_frames,
                matcher,
                f"{scene.name} characterisation frames, simulated LiDAR",
                source="lidar",
            )[0],
            "self": _self_model(out / "self" / name / "characterisation", map_frames, matcher),
            "motorcycle": _motorcycle_model(out / "motorcycle" / name / "characterisation", name),
        }
        for source in SOURCES[1:]:
            build_map = mapper(sequence, disparity_dir, name, error_models[name][source], p0, model_params, settings)
            for cell in run_cells(
                out / source,
                name,
                models,
                build_map,
                truth,
                dict(settings, derived_model_params=model_params, source=source),
            )[0]:
                cells[(name, cell.model, source)] = cell
        likelihood[name] = {
            source: mapped_log_likelihood(model, map_frames, disparity_dir)
            for source, model in error_models[name].items()
        }
        likelihood[name]["self_by_class"] = class_log_likelihoods(
            error_models[name]["self"],
            error_models[name]["ground-truth"],
            map_frames,
            list(read_disparities(disparity_dir, len(map_frames))),
        )
    document = {
        "world": world,
        "settings": settings,
        "p0": p0,
        "cells": [
            {"matcher": m, "model": model, "source": s, "scores": _scores(c)}
            for (m, model, s), c in sorted(cells.items(), key=_order)
        ],
        "likelihood": likelihood,
    }
    document["targets"] = _targets(document)
    write_text_atomic(out / "sources.json", json.dumps(document, indent=1, default=_plain) + "\n")
    write_text_atomic(out / "sources.md", format_sources(document))
    return document


def _order(item):
    (matcher, model, source), _ = item
    return matcher, model, SOURCES.index(source)


def _scores(cell):
    return {name: float(getattr(cell.scores, name)) for name in SCORE_FIELDS}


def _plain(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    if dataclasses.is_dataclass(value):
        return dataclasses.asdict(value)
    raise TypeError(f"cannot write {type(value).__name__}")


def _targets(document):
    """The issue's targets, each measured: self within 5 % of ground truth, better than Motorcycle, LiDAR's likelihood."""
    by = {(c["matcher"], c["model"], c["source"]): c["scores"] for c in document["cells"]}
    targets = []
    for (matcher, model, source), scores in by.items():
        if source != "self":
            continue
        gt, moto = by[(matcher, model, "ground-truth")], by[(matcher, model, "motorcycle")]
        for name in ("brier", "log_loss"):
            ratio = scores[name] / gt[name] - 1.0
            targets.append(
                {
                    "target": f"{matcher} {model}: self {name} within {WITHIN:.0%} of ground truth",
                    "value": ratio,
                    "met": bool(ratio <= WITHIN),
                }
            )
        worse = [
            name
            for name in SCORE_FIELDS
            if (scores[name] >= moto[name] if LOWER_IS_BETTER[name] else scores[name] <= moto[name])
        ]
        targets.append(
            {
                "target": f"{matcher} {model}: self better than Motorcycle on every score",
                "value": ", ".join(worse) or "none worse",
                "met": not worse,
            }
        )
    for matcher, sources in document["likelihood"].items():
        gap = sources["ground-truth"]["conditioned_nats_per_error"] - sources["lidar"]["conditioned_nats_per_error"]
        targets.append(
            {
                "target": f"{matcher}: LiDAR model's held-out log-likelihood within {LIDAR_WITHIN_NATS} "
                "nats/error of the ground-truth one",
                "value": gap,
                "met": bool(gap <= LIDAR_WITHIN_NATS),
            }
        )
    return targets


def format_sources(document):
    """Markdown: scores per matcher, model and source; likelihoods; per-class likelihoods; targets."""
    lines = [
        f"# Error-model sources on {document['world']}",
        "",
        "PRISM maps of the same mapping frames and disparities, each with the error model of one source "
        "(ground truth, simulated LiDAR, self-characterisation from the mapping frames, Middlebury "
        f"Motorcycle); p0 = {document['p0']:.4f}.",
        "",
        "| matcher | model | source | " + " | ".join(SCORE_FIELDS) + " | Brier vs GT | log-loss vs GT |",
        "|---" * (5 + len(SCORE_FIELDS)) + "|",
    ]
    by = {(c["matcher"], c["model"], c["source"]): c["scores"] for c in document["cells"]}
    for (matcher, model, source), scores in by.items():
        gt = by[(matcher, model, "ground-truth")]
        lines.append(
            f"| {matcher} | {model} | {source} | "
            + " | ".join(f"{scores[n]:.4f}" for n in SCORE_FIELDS)
            + f" | {scores['brier'] / gt['brier'] - 1:+.1%} | {scores['log_loss'] / gt['log_loss'] - 1:+.1%} |"
        )
    lines += [
        "",
        "## Log-likelihood of the mapping frames' exact errors (nats per error)",
        "",
        "| matcher | source | conditioned | plain | errors |",
        "|---|---|---|---|---|",
    ]
    for matcher, sources in document["likelihood"].items():
        for source in SOURCES:
            row = sources[source]
            lines.append(
                f"| {matcher} | {source} | {row['conditioned_nats_per_error']:.4f} | "
                f"{row['plain_nats_per_error']:.4f} | {row['n_errors']} |"
            )
    lines += [
        "",
        "## Per class of the self-characterised model",
        "",
        "Each class's pixels of the mapping frames, their exact errors under the self model's class mixture "
        "and under the ground-truth model (each pixel under its own class there).",
        "",
        "| matcher | class | errors | self | ground truth |",
        "|---|---|---|---|---|",
    ]
    for matcher, sources in document["likelihood"].items():
        for row in sources["self_by_class"]:
            if row["n_errors"]:
                lines.append(
                    f"| {matcher} | {row['class']} | {row['n_errors']} | {row['model_nats_per_error']:.4f} | "
                    f"{row['reference_nats_per_error']:.4f} |"
                )
    lines += ["", "## Targets", "", "| target | measured | met |", "|---|---|---|"]
    for target in document["targets"]:
        value = target["value"]
        shown = f"{value:+.4f}" if isinstance(value, float) else str(value)
        lines.append(f"| {target['target']} | {shown} | {'yes' if target['met'] else 'NO'} |")
    return "\n".join(lines) + "\n"
