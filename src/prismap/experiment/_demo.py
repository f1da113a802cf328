"""``prismap demo``: the whole story (characterise, compare models, map and score) and an index page linking it."""

import contextlib
import io
import os
import time
from pathlib import Path

from prismap._files import write_text_atomic
from prismap.errors import PrismapInputError

DEMO_SIZES = {
    False: {"office2d": {"quick": False, "n_frames": 120},
            "scene3d": {"quick": False, "n_frames": 20},
            "street3d": {"quick": False, "n_frames": 12}},
    True: {"office2d": {"quick": True, "n_frames": 12},
           "scene3d": {"quick": True, "n_frames": 4, "voxel_size_m": 0.2, "matchers": ("sgbm",)},
           "street3d": {"quick": True, "n_frames": 4, "matchers": ("sgbm",)}},
}
"""Experiment sizes of the demo (full) and of ``--quick`` (a smoke run: tiny, numbers not meaningful)."""

MATCHERS = ("bm", "sgbm", "variational")


def run_demo(out_dir, *, quick=False, seed=0):
    """Characterise the Motorcycle pair with each matcher, compare the sensor models, run both experiments.

    Every step writes into its own folder of ``out_dir`` and is skipped if its results exist, so an
    interrupted demo resumes. ``out_dir/index.md`` links every table and figure with a caption and the
    headline numbers (the best model per score, and PRISM's scores beside the others').

    Parameters
    ----------
    out_dir : str or Path
    quick : bool
        Tiny sizes (:data:`DEMO_SIZES`): checks that the pipeline runs end to end.
    seed : int

    Returns
    -------
    Path
        The index page.
    """
    from prismap.cli._main import COMMANDS
    from prismap.experiment._office2d import run_office2d
    from prismap.experiment._scene3d import run_scene3d, run_street3d

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise PrismapInputError(f"--out {out}: exists and is not a directory")
    sizes = DEMO_SIZES[bool(quick)]
    sections, timings = [], {}

    start = time.perf_counter()
    characterised = []
    for matcher in MATCHERS:
        folder = out / "characterise" / matcher
        if not (folder / "table.md").is_file():
            _command(["characterise", "--dataset", "middlebury-motorcycle", "--matcher", matcher, "--out", str(folder)])
        characterised.append((matcher, folder))
    timings["characterise Motorcycle"] = time.perf_counter() - start
    items = []
    for matcher, folder in characterised:
        items += [(folder / "table.md", f"{matcher} on Motorcycle: mixtures G = 1..4, AIC/BIC, coverage, bad-1px, "
                                        "bad-2px (thesis tables 3.1-3.3)."),
                  (folder / "errors.png", f"{matcher} on Motorcycle: error histogram and fitted mixtures."),
                  (folder / "errors_wide.png", f"{matcher} on Motorcycle: error tails (log scale).")]
    sections.append(("1. Stereo error models (Middlebury Motorcycle, ground-truth disparity)", [], items))

    start = time.perf_counter()
    compare_dir = out / "models"
    if "models" in COMMANDS:
        if not compare_dir.is_dir() or not any(compare_dir.iterdir()):
            _command(["models", "compare", "--error-model", str(out / "characterise" / "sgbm" / "error_model.json"),
                      "--out", str(compare_dir)])
        files = sorted(p for p in compare_dir.rglob("*") if p.suffix in (".md", ".png", ".svg", ".json"))
        items = [(p, f"models compare: {p.stem.replace('_', ' ')}.") for p in files]
        notes = ["The sensor models along one ray with the SGBM error model; PRISM is the exact yardstick."]
    else:
        items, notes = [], ["`prismap models compare` is not part of this build: no ray-level comparison."]
    timings["models compare"] = time.perf_counter() - start
    sections.append(("2. Sensor models along one ray (SGBM error model)", notes, items))

    for title, world, runner in (("3. 2-D office, errors from a known mixture", "office2d", run_office2d),
                                 ("4. 3-D indoor scene, characterised matchers", "scene3d", run_scene3d),
                                 ("5. 3-D street, KITTI-like rig, characterised matchers", "street3d", run_street3d)):
        start = time.perf_counter()
        result = runner(out / world, seed=seed, **sizes[world])
        timings[world] = time.perf_counter() - start
        sections.append((title, headline(result), list(result.artifacts)))

    index = out / "index.md"
    write_text_atomic(index, format_index(sections, timings, out, quick=quick))
    return index


def _command(argv):
    """Run a ``prismap`` sub-command in this process; its output is kept off the demo's stdout."""
    from prismap.cli._main import main

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        status = main(argv)
    if status != 0:
        raise PrismapInputError(f"demo step `prismap {' '.join(argv)}` failed with status {status}")


def headline(result):
    """Lines of headline numbers: per matcher, PRISM's scores and the best other model's."""
    lines = [f"p0 = {result.p0:.4f} (occupancy ratio of the scored voxels)."]
    for matcher in dict.fromkeys(c.matcher for c in result.cells):
        cells = [c for c in result.cells if c.matcher == matcher]
        prism = next((c for c in cells if c.model == "prism"), None)
        others = [c for c in cells if c.model != "prism"]
        if prism is None or not others:
            continue
        best_brier = min(others, key=lambda c: c.scores.brier)
        best_loss = min(others, key=lambda c: c.scores.log_loss)
        s = prism.scores
        lines.append(
            f"{matcher}: PRISM Brier {s.brier:.4f} (best other: {best_brier.model} {best_brier.scores.brier:.4f}), "
            f"log-loss {s.log_loss:.4f} (best other: {best_loss.model} {best_loss.scores.log_loss:.4f}), "
            f"ECE {s.ece:.4f}, AUC {s.roc_auc:.3f}, occupied called free {s.occupied_called_free:.3f}."
        )
    return lines


def format_index(sections, timings, out_dir, *, quick):
    """The Markdown index: per section, headline lines and links (relative to ``out_dir``) with captions."""
    lines = ["# prismap demo", ""]
    if quick:
        lines += ["Quick mode: tiny sizes that only show the pipeline runs; the numbers are not meaningful.", ""]
    total = sum(timings.values())
    lines += [f"Run time: {total:.0f} s (" + ", ".join(f"{k} {v:.0f} s" for k, v in timings.items()) + ").", ""]
    for title, notes, items in sections:
        lines += [f"## {title}", ""]
        lines += [f"- {note}" for note in notes]
        if notes:
            lines.append("")
        for path, caption in items:
            link = Path(os.path.relpath(path, out_dir)).as_posix()
            lines.append(f"- [{link}]({link}): {caption}")
        lines.append("")
    return "\n".join(lines)
