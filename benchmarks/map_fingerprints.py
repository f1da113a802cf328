"""Fingerprints of small but representative maps: a restructuring that changes no behaviour prints the same lines.

Builds, through the library's own entry points and at reduced sizes:

- the room (:func:`prismap.experiment.run_scene3d`, ray mode, SGBM): every model of
  :data:`~prismap.experiment.MODELS_3D_MAP_PRIOR` (classic, plain and conditioned PRISM, the map prior);
- the street (:func:`prismap.experiment.run_street3d`, projective mode, SGBM): hit/miss, plain and conditioned
  PRISM;
- the 2-D office (:func:`prismap.experiment.run_office2d`): every model of :data:`~prismap.experiment.MODELS`;
- the room's conditioned PRISM map again, on a Dask cluster of 2 worker processes, and the street's plain PRISM.

For every map it prints one sha256 of its sorted voxel keys, log-odds (float64) and observation counts, and the
cell's scores with ``repr`` (every digit of a float64). Run it before and after a change and ``diff`` the
outputs; only the lines starting with ``#`` (load, wall time) may differ.

Usage: ``python benchmarks/map_fingerprints.py [--out DIR] > fingerprints.txt``
"""

import argparse
import hashlib
import os
import tempfile
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

SCORE_FIELDS = (
    "n_voxels",
    "n_occupied",
    "n_free",
    "brier",
    "log_loss",
    "ece",
    "roc_auc",
    "occupied_called_free",
    "free_called_occupied",
    "safety_occupied_called_free",
    "safety_threshold",
)
STREET_MODELS = ("hitmiss", "prism", "prism_conditioned")


def map_digest(grid):
    """sha256 (hex) of the map's voxel size, prior, sorted keys, log-odds and counts."""
    keys, log_odds, counts = grid.known_voxels()
    order = np.lexsort(keys.T[::-1])
    digest = hashlib.sha256()
    digest.update(np.float64([grid.voxel_size_m, grid.p0]).tobytes())
    digest.update(np.ascontiguousarray(keys[order], dtype=np.int64).tobytes())
    digest.update(np.ascontiguousarray(log_odds[order], dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(counts[order], dtype=np.int64).tobytes())
    return digest.hexdigest(), len(keys)


def score_text(scores):
    """Every scalar score and every bin array, exactly."""
    parts = [f"{name}={getattr(scores, name)!r}" for name in SCORE_FIELDS]
    arrays = hashlib.sha256()
    for field in fields(scores):
        value = getattr(scores, field.name)
        if isinstance(value, np.ndarray):
            arrays.update(field.name.encode() + np.ascontiguousarray(value, dtype=np.float64).tobytes())
    return " ".join(parts) + f" bins_sha256={arrays.hexdigest()[:16]}"


def report_run(label, out, result):
    """One line per cell of an experiment run: the map's digest and its scores."""
    from prismap.experiment._results import cell_path
    from prismap.io import load_map

    print(f"{label} p0={result.p0!r}")
    for cell in result.cells:
        grid = load_map(cell_path(out, cell.matcher, cell.model).with_suffix(".npz"))
        digest, n = map_digest(grid)
        print(f"{label} {cell.matcher}/{cell.model} voxels={n} sha256={digest} {score_text(cell.scores)}")


def dask_map(label, out, result, model, mode):
    """The run's ``model`` map again through :func:`prismap.pipeline.map_sequence` on 2 Dask worker processes."""
    import distributed

    from prismap.evaluate import score_grid
    from prismap.experiment._results import split_variant
    from prismap.io import read_sequence
    from prismap.pipeline import MappingConfig, map_sequence

    cell = result.cell("sgbm", model)
    settings = cell.settings
    name, conditioned = split_variant(model)
    params = dict(settings["derived_model_params"].get(name, {}))
    if not conditioned:
        params.pop("class_pass_through", None)
    from prismap.characterise import load_error_model

    error_model = load_error_model(Path(out) / "sgbm" / "characterisation" / "error_model.json")
    sequence = read_sequence(Path(out) / "sequence")
    config = MappingConfig(
        model=name,
        model_params=params,
        voxel_size_m=settings["voxel_size_m"],
        p0=result.p0,
        error_model=error_model,
        conditioned=None if conditioned else False,
        matcher="sgbm",
        disparity_source=str((Path(out) / "sgbm" / "disparity").resolve()),
        max_range_m=settings["max_range_m"],
        subsample=settings["subsample"],
        mode=mode,
    )
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        distributed.Client(cluster) as client,
    ):
        grid = map_sequence(sequence, config, progress=False, client=client, chunk_frames=2)
    digest, n = map_digest(grid)
    print(f"{label} dask2/{model} voxels={n} sha256={digest} {score_text(score_grid(grid, sequence.ground_truth))}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="work directory (default: a temporary one)")
    args = parser.parse_args()
    os.environ["PRISMAP_PROGRESS"] = "0"
    from prismap.experiment import MODELS, MODELS_3D_MAP_PRIOR, run_office2d, run_scene3d, run_street3d

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        room = root / "room"
        result = run_scene3d(room, quick=True, n_frames=8, matchers=("sgbm",), models=MODELS_3D_MAP_PRIOR)
        report_run("room", room, result)
        dask_map("room", room, result, "prism_conditioned", "ray")
        street = root / "street"
        result = run_street3d(
            street, quick=True, n_frames=6, between_frames=2, matchers=("sgbm",), models=STREET_MODELS
        )
        report_run("street", street, result)
        dask_map("street", street, result, "prism", "projective")
        office = root / "office"
        result = run_office2d(office, quick=True, n_frames=12, models=MODELS)
        report_run("office", office, result)
    with open("/proc/loadavg", encoding="ascii") as load:
        print(f"# wall {time.perf_counter() - start:.0f} s, load {load.read().split()[:3]}")


if __name__ == "__main__":
    main()
