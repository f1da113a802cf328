"""``prismap demo``: the whole story (characterise, compare models, map and score) and a report linking it."""

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prismap._files import write_text_atomic
from prismap._progress import progress
from prismap.errors import PrismapInputError
from prismap.experiment._office2d import run_office2d
from prismap.experiment._report import Report, format_index_html, format_index_markdown
from prismap.experiment._scene3d import run_scene3d, run_street3d


@dataclass(frozen=True)
class DemoExperiment:
    """One experiment of the demo.

    Attributes
    ----------
    world : str
        Its folder in the demo's output and the report's anchor.
    title : str
    run : callable
        ``run(out_dir, seed=..., **sizes) -> ExperimentResult``.
    full, quick : dict
        Keyword sizes of the full demo and of ``--quick`` (a smoke run: tiny, numbers not meaningful).
    """

    world: str
    title: str
    run: object
    full: dict
    quick: dict


EXPERIMENTS = (
    DemoExperiment(
        "office2d",
        "2-D office, errors from a known mixture",
        run_office2d,
        full={"quick": False, "n_frames": 120},
        quick={"quick": True, "n_frames": 12},
    ),
    DemoExperiment(
        "scene3d",
        "3-D indoor scene, characterised matchers",
        run_scene3d,
        full={"quick": False, "n_frames": 20},
        quick={"quick": True, "n_frames": 4, "voxel_size_m": 0.2, "matchers": ("sgbm",)},
    ),
    DemoExperiment(
        "street3d",
        "Street, KITTI-like rig, characterised matchers",
        run_street3d,
        full={"quick": False, "n_frames": 12, "matchers": ("bm", "sgbm")},
        quick={"quick": True, "n_frames": 4, "matchers": ("sgbm",)},
    ),
)
"""The demo's experiments in report order: add one here to add it to the demo. The street maps with block matching
and semiglobal matching only: its variational cells cost two thirds of its mapping time, and the conditioned
variants would otherwise double the street's share of the demo."""

MATCHERS = ("bm", "sgbm", "variational")
"""Matchers characterised on the Motorcycle pair."""


STEP_SECONDS = {
    "full": {
        "characterise bm": 26.0,
        "characterise sgbm": 21.0,
        "characterise variational": 21.0,
        "models compare": 2.0,
        "office2d": 4.0,
        "scene3d": 258.0,
        "street3d": 261.0,
    },
    "quick": {
        "characterise bm": 7.0,
        "characterise sgbm": 4.0,
        "characterise variational": 9.0,
        "models compare": 32.0,
        "office2d": 17.0,
        "scene3d": 11.0,
        "street3d": 30.0,
    },
}
"""Each step's wall time (seconds, 2 idle cores), from the Run time line of a report: the progress lines'
percentage and time left follow these shares, not the count of steps. ``full``: a ``make demo`` run; ``quick``: a
first ``--quick`` run, numba compiling the kernels (the step that first calls a kernel pays for it)."""


@dataclass(frozen=True)
class Section:
    """One section of the report: a title, headline lines and ``(path, caption)`` items."""

    title: str
    headline: tuple
    items: tuple


def run_demo(out_dir, *, quick=False, seed=0):
    """Characterise the Motorcycle pair with each matcher, compare the sensor models, run :data:`EXPERIMENTS`.

    Every step writes into its own folder of ``out_dir`` and is skipped if its results exist, so an
    interrupted demo resumes. ``out_dir/index.html`` (and ``index.md``) shows, per step, the headline
    numbers, every table and figure with a caption.

    Parameters
    ----------
    out_dir : str or Path
    quick : bool
        Tiny sizes (:attr:`DemoExperiment.quick`): checks that the pipeline runs end to end.
    seed : int

    Returns
    -------
    Path
        The HTML report.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise PrismapInputError(f"--out {out}: exists and is not a directory")
    steps = [
        (f"characterise {m}", lambda m=m: _characterise_motorcycle(out / "characterise" / m, m, quick=quick))
        for m in MATCHERS
    ]
    steps.append(("models compare", lambda: _compare_models(out / "models", out / "characterise" / "sgbm")))
    experiments = {}
    steps += [(e.world, lambda e=e: _experiment(out, e, experiments, quick=quick, seed=seed)) for e in EXPERIMENTS]
    shares = STEP_SECONDS["quick" if quick else "full"]

    timings, sections = {}, []
    characterised = []
    for name, step in progress(steps, desc="demo", unit="step", weights=[shares[name] for name, _ in steps]):
        start = time.perf_counter()
        section = step()
        timings[name] = time.perf_counter() - start
        if name.startswith("characterise"):
            characterised.append(section)
        else:
            sections.append(section)
    motorcycle = Section(
        "Stereo error models (Middlebury Motorcycle, ground-truth disparity)",
        sum((s.headline for s in characterised), ()),
        sum((s.items for s in characterised), ()),
    )
    sections.insert(0, motorcycle)
    sections = [Section(f"{i}. {s.title}", s.headline, s.items) for i, s in enumerate(sections, start=1)]
    write_text_atomic(out / "index.md", format_index_markdown(sections, timings, out, quick=quick))
    index = out / "index.html"
    report = Report(
        tuple(sections),
        timings,
        out,
        quick=quick,
        experiments=experiments,
        render_3d=_render_3d(out, experiments),
        shell_dir=str(out_dir),
    )
    write_text_atomic(index, format_index_html(report))
    return index


RENDER_3D = ("scene3d", ("sgbm", "bm", "variational"), ("prism_conditioned", "prism"))
"""The map the report draws in 3-D: the room's conditioned PRISM map of the first matcher the run has."""


def _render_3d(out, experiments):
    """Draw :data:`RENDER_3D`'s map beside its ground truth into ``out/map3d.png``; ``(path, caption)`` or None."""
    from prismap.experiment._results import cell_path, model_label
    from prismap.io import load_map, read_ground_truth
    from prismap.plots import plot_map_3d

    world, matchers, models = RENDER_3D
    result = experiments.get(world)
    if result is None:
        return None
    names = {c.model for c in result.cells}
    found = [
        (c.matcher, c.model)
        for m in matchers
        for model in models
        for c in result.cells
        if c.matcher == m and c.model == model
    ]
    if not found:
        return None
    matcher, model = found[0]
    map_path = cell_path(out / world, matcher, model).with_suffix(".npz")
    path = out / "map3d.png"
    plot_map_3d(load_map(map_path), read_ground_truth(out / world / "sequence" / "occupancy.npz"), path=path)
    return path, (
        f"The {world} map of {matcher} with {model_label(model, names)} (right; voxels with P > 0.5) "
        "beside the ground truth's occupied voxels (left), coloured by height, the top layer left out."
    )


QUICK_MAX_CLASSES = 4
"""``--quick`` characterises each matcher conditioned on at most this many error classes: the class search's
candidates grow with the bound, and at the default bound it is most of a quick run's time."""


def _characterise_motorcycle(folder, matcher_name, *, quick):
    """The matcher's error model on the Motorcycle pair (reused when its files exist)."""
    from prismap.characterise import characterise_matcher, load_error_model, write_characterisation
    from prismap.characterise._run import written_characterisation
    from prismap.experiment._steps3d import matcher_for
    from prismap.io import load_middlebury_motorcycle

    model_path = folder / "error_model.json"
    if written_characterisation(folder) is None:
        frame = load_middlebury_motorcycle()
        truth = frame.disparity_gt
        matcher = matcher_for(matcher_name, float(np.max(truth[np.isfinite(truth)])))
        options = {"max_classes": QUICK_MAX_CLASSES} if quick else {}
        write_characterisation(
            characterise_matcher([frame], matcher, dataset="middlebury-motorcycle", **options), folder
        )
    model = load_error_model(model_path)
    mixture = model.mixture
    largest = mixture.weights.argmax()
    headline = (
        (
            f"{matcher_name}: selected G = {model.selected_components}; largest component w = "
            f"{mixture.weights[largest]:.3f}, sigma = {mixture.sigmas[largest]:.3f} px."
        ),
    )
    items = (
        (
            folder / "table.md",
            (
                f"{matcher_name} on Motorcycle: mixtures G = 1..4, AIC/BIC, coverage, bad-1px, "
                "bad-2px (thesis tables 3.1-3.3)."
            ),
        ),
        (folder / "errors.png", f"{matcher_name} on Motorcycle: error histogram and fitted mixtures."),
        (folder / "errors_wide.png", f"{matcher_name} on Motorcycle: error tails (log scale)."),
    )
    return Section("", headline, items)


def _compare_models(folder, characterisation):
    """``models compare`` on the SGBM error model with the Motorcycle rig (reused when its files exist)."""
    from prismap.characterise import load_error_model
    from prismap.study import COMPARE_FILES, run_models_compare

    if not all((folder / name).is_file() for name in COMPARE_FILES.values()):
        model_path = characterisation / "error_model.json"
        run_models_compare(load_error_model(model_path), folder, camera="middlebury-motorcycle", source=str(model_path))
    items = tuple(
        (folder / name, f"models compare: {Path(name).stem.replace('_', ' ')}.") for name in COMPARE_FILES.values()
    )
    return Section(
        "Sensor models along one ray (SGBM error model)",
        ("The sensor models along one ray with the SGBM error model; PRISM is the exact yardstick.",),
        items,
    )


def _experiment(out, experiment, experiments, *, quick, seed):
    """Run ``experiment`` into ``out/WORLD``, keep its result in ``experiments[WORLD]``; its report section."""
    sizes = experiment.quick if quick else experiment.full
    result = experiment.run(out / experiment.world, seed=seed, **sizes)
    experiments[experiment.world] = result
    return Section(experiment.title, tuple(headline(result)), tuple(result.artifacts))


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
