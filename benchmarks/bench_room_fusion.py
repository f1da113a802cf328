"""Whether a model's loss near walls comes from fusing frames: the room's maps scored after 1, 2, 5, ... frames.

Takes a finished 3-D run (``prismap.experiment.run_scene3d``) and maps its mapping frames again from the
matcher's own disparities with the run's settings, frame by frame, scoring each model's map after the first
1, 2, 5, ... frames. Scores: ROC AUC, and the ROC AUC of the occupied voxels against the free voxels with an
occupied 6-neighbour only ("near free") and against the other free voxels ("far free"), each on the
ground-truth voxels that every model's map of that many frames has observed (so that unknown voxels, the
same in every map, do not dilute the comparison), and the whole run's Brier score and log-loss on every
scored voxel. A model is a cell name of the experiment (``prism_conditioned``, ``convolution``, ...), with
``prism`` models taking ``prior=map`` as ``prism_conditioned:map``. Run:
``PYTHONPATH=src .venv/bin/python benchmarks/bench_room_fusion.py RUN_DIR [matcher] [models] [counts]``
(comma-separated; defaults sgbm, prism_conditioned,convolution, 1,2,5,all).
"""

import sys
import time

import numpy as np
from bench_room_errors import load_run, near_free

from prismap.evaluate import align_to_ground_truth, score_map
from prismap.experiment._results import split_variant
from prismap.pipeline import MappingConfig
from prismap.pipeline._run import integrate_frames, new_map
from prismap.sensor_models import CLASS_PASS_THROUGH


def main(run_dir, matcher="sgbm", models="prism_conditioned,convolution", counts="1,2,5,all"):
    run, sequence, truth, settings, error_model, params, p0 = load_run(run_dir, matcher)
    near = near_free(truth)
    n_frames = len(sequence)
    stops = sorted({n_frames if c == "all" else min(int(c), n_frames) for c in counts.split(",")})
    results = {}
    for cell in models.split(","):
        name, _, prior = cell.partition(":")
        model, conditioned = split_variant(name)
        model_params = dict(params.get(model, {}), **({"prior": prior} if prior else {}))
        if not conditioned:  # one pass-through per error class is for conditioned PRISM
            model_params.pop(CLASS_PASS_THROUGH, None)
        config = MappingConfig(
            model=model,
            model_params=model_params,
            voxel_size_m=settings["voxel_size_m"],
            p0=p0,
            error_model=error_model,
            conditioned=None if conditioned else False,
            matcher=matcher,
            disparity_source=str((run / matcher / "disparity").resolve()),
            max_range_m=settings["max_range_m"],
            subsample=settings["subsample"],
            mode=settings["mode"],
        )
        grid, done, start = new_map(config), 0, time.perf_counter()
        sensor_model = config.sensor_model(sequence.camera)  # one model, its PRISM tables kept, for every stop
        for stop in stops:
            integrate_frames(grid, sequence, config, range(done, stop), model=sensor_model)
            done = stop
            keys = grid.known_voxels()[0]
            p, occupied = align_to_ground_truth(
                keys, grid.probability_at_keys(keys), truth.occupied_keys, truth.observed_keys, p0=p0
            )
            count = grid.lookup_keys(truth.observed_keys)[1]
            results[(cell, stop)] = (p, occupied, count > 0, time.perf_counter() - start)
    for stop in stops:
        seen = np.logical_and.reduce([results[(cell, stop)][2] for cell in models.split(",")])
        for cell in models.split(","):
            p, occupied, _, elapsed = results[(cell, stop)]
            whole = score_map(p, occupied)
            parts = [
                score_map(
                    np.r_[p[occupied & seen], p[other & seen]],
                    np.r_[np.ones((occupied & seen).sum(), bool), np.zeros((other & seen).sum(), bool)],
                )
                for other in (~occupied, ~occupied & near, ~occupied & ~near)
            ]
            print(
                f"{matcher} {cell:26s} frames {stop:3d}  Brier {whole.brier:.4f}  log-loss {whole.log_loss:.4f}  "
                f"AUC {whole.roc_auc:.4f}  safety {100 * whole.safety_occupied_called_free:.2f} %  | seen voxels "
                f"{int(seen.sum())}: AUC {parts[0].roc_auc:.4f}  near free {parts[1].roc_auc:.4f}  far free "
                f"{parts[2].roc_auc:.4f}  ({elapsed:.1f} s)",
                flush=True,
            )


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
