"""Which structure of a matcher's errors costs which model what: the room mapped from synthetic errors.

Takes a finished 3-D run (``prismap.experiment.run_scene3d``) and maps its mapping frames again, each
from the exact disparity minus errors drawn from the matcher's characterised whole-image mixture
(rounded to 1/16 px like OpenCV's), with the run's settings, plain models only:

- ``independent``: every pixel and frame draws on its own (PRISM's assumption 3 holds exactly);
- ``shared``: one draw per 1 cm world cell, the same in every frame that sees it (the errors of a
  surface point repeat across views: log-odds fusion then counts one error many times);
- ``patches``: independent across frames, spatially correlated within one (a Gaussian copula whose
  field is 0.6 / 0.4 of Gaussian blurs of 3 px and 20 px; SGBM's errors in the room correlate about
  0.5 at 4-8 px and 0.3 at 32 px).

For each map it prints Brier, log-loss, ROC AUC, the safety score (occupied called free at 90 % free)
and the ROC AUC of the occupied voxels against the free voxels with an occupied 6-neighbour only
("near free") and against the other free voxels ("far free"). The matcher's own maps from the run are
scored the same way for comparison. Run:
``PYTHONPATH=src .venv/bin/python benchmarks/bench_room_errors.py RUN_DIR [matcher] [variants] [models]``
(comma-separated; defaults sgbm, independent,shared,patches, convolution,prism).
"""

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy import ndimage, stats

from prismap.characterise import load_error_model
from prismap.evaluate import align_to_ground_truth, score_map
from prismap.experiment._results import prior_of
from prismap.grid import pack_keys
from prismap.io import load_map, read_sequence, write_disparity_png
from prismap.pipeline import MappingConfig, map_sequence
from prismap.sensor_models import CLASS_PASS_THROUGH

SHARED_CELL_M = 0.01


def _uniforms(keys, salt):
    """Uniforms in [0, 1) that depend only on ``keys`` (int64) and ``salt``: splitmix64 of each key."""
    x = keys.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(salt)
    for multiplier in (0xBF58476D1CE4E5B9, 0x94D049BB133111EB):
        x ^= x >> np.uint64(31)
        x *= np.uint64(multiplier)
    x ^= x >> np.uint64(29)
    return (x >> np.uint64(11)).astype(np.float64) / 2.0**53


def _mixture_quantile(mixture, u):
    """The mixture's inverse CDF at ``u`` (interpolated on a 2.5 milli-pixel grid over +-80 px)."""
    grid = np.linspace(-80.0, 80.0, 64001)
    cdf = (mixture.weights * stats.norm.cdf((grid[:, None] - mixture.means) / mixture.sigmas)).sum(axis=1)
    return np.interp(u, cdf, grid)


def synthetic_errors(variant, mixture, frame, camera, rng):
    """(N,) errors, pixels, for the pixels of ``frame`` with an exact disparity (row-major)."""
    truth = frame.disparity_gt
    known = np.isfinite(truth)
    if variant == "independent":
        return mixture.sample(int(known.sum()), rng)
    if variant == "shared":
        points_cam = camera.triangulate(np.where(known, truth, np.nan))[known]
        points_w = points_cam @ frame.T_world_cam[:3, :3].T + frame.T_world_cam[:3, 3]
        cell = np.floor(points_w / SHARED_CELL_M).astype(np.int64) + 2**20
        keys = (cell[:, 0] << 42) | (cell[:, 1] << 21) | cell[:, 2]
        return _mixture_quantile(mixture, _uniforms(keys, 1))
    if variant == "patches":

        def field(sigma_px):
            z = ndimage.gaussian_filter(rng.standard_normal(truth.shape), sigma_px, mode="reflect")
            return z / z.std()

        z = np.sqrt(0.6) * field(3.0) + np.sqrt(0.4) * field(20.0)
        return _mixture_quantile(mixture, stats.norm.cdf(z[known]))
    raise SystemExit(f"unknown variant {variant!r}: independent, shared or patches")


def near_free(truth):
    """(M,) bool over ``truth.observed_keys``: the voxel has an occupied 6-neighbour."""
    occupied_keys = pack_keys(truth.occupied_keys)
    near = np.zeros(truth.observed_keys.shape[0], bool)
    for step in np.vstack((np.eye(3, dtype=np.int64), -np.eye(3, dtype=np.int64))):
        near |= np.isin(pack_keys(truth.observed_keys + step), occupied_keys)
    return near


def scores(grid, truth, near):
    """The map's scores and the ROC AUC of occupied voxels against near-free and far-free ones."""
    keys = grid.known_voxels()[0]
    p, occupied = align_to_ground_truth(
        keys, grid.probability_at_keys(keys), truth.occupied_keys, truth.observed_keys, p0=grid.p0
    )
    result = score_map(p, occupied)
    parts = [
        score_map(np.r_[p[occupied], p[other]], np.r_[np.ones(occupied.sum(), bool), np.zeros(other.sum(), bool)])
        for other in (~occupied & near, ~occupied & ~near)
    ]
    return (
        f"Brier {result.brier:.4f}  log-loss {result.log_loss:.4f}  ROC AUC {result.roc_auc:.4f}  "
        f"safety {100 * result.safety_occupied_called_free:.2f} %  AUC near free {parts[0].roc_auc:.4f}  "
        f"far free {parts[1].roc_auc:.4f}"
    )


def load_run(run_dir, matcher):
    """``(run, sequence, truth, settings, error_model, derived model params, p0)`` of a finished 3-D run."""
    run = Path(run_dir)
    sequence = read_sequence(run / "sequence")
    settings = json.loads((run / "settings.json").read_text())
    error_model = load_error_model(run / matcher / "characterisation" / "error_model.json")
    cell = json.loads((run / "cells" / f"{matcher}__prism.json").read_text())
    truth = sequence.ground_truth
    return run, sequence, truth, settings, error_model, cell["settings"]["derived_model_params"], prior_of(truth)


def main(run_dir, matcher="sgbm", variants="independent,shared,patches", models="convolution,prism"):
    run, sequence, truth, settings, error_model, model_params, p0 = load_run(run_dir, matcher)
    near = near_free(truth)
    for model in models.split(","):
        print(f"{matcher} (run)  {model:12s}", scores(load_map(run / "cells" / f"{matcher}__{model}.npz"), truth, near))
    for variant in variants.split(","):
        rng = np.random.default_rng(7)
        with tempfile.TemporaryDirectory() as disparity_dir:
            for index in range(len(sequence)):
                frame = sequence[index]
                known = np.isfinite(frame.disparity_gt)
                disparity = np.full(known.shape, np.nan)
                errors = synthetic_errors(variant, error_model.mixture, frame, sequence.camera, rng)
                disparity[known] = np.round((frame.disparity_gt[known] - errors) * 16.0) / 16.0
                disparity[disparity <= 0] = np.nan
                write_disparity_png(Path(disparity_dir) / f"{index:06d}.png", disparity, f"{variant} disparity")
            for model in models.split(","):
                plain_params = {k: v for k, v in model_params.get(model, {}).items() if k != CLASS_PASS_THROUGH}
                config = MappingConfig(
                    model=model,
                    model_params=plain_params,
                    voxel_size_m=settings["voxel_size_m"],
                    p0=p0,
                    error_model=error_model,
                    conditioned=False,
                    matcher=matcher,
                    disparity_source=disparity_dir,
                    max_range_m=settings["max_range_m"],
                    subsample=settings["subsample"],
                    mode=settings["mode"],
                )
                print(f"{variant:12s} {model:12s}", scores(map_sequence(sequence, config), truth, near), flush=True)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
