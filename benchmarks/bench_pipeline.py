"""Frames per second of ``prismap map``'s work, stage by stage, with SGBM alone as the floor; Dask set-ups.

Scene: the seeded indoor room of ``prismap.sim`` (``indoor_scene(seed=0)``) along ``indoor_trajectory``,
rendered to ``--frames`` stereo pairs (default 16) by a New-Tsukuba-like camera scaled to ``--width`` pixels
(default 640 x 480, f = 615 px, baseline 0.10 m) and written as a KITTI-layout sequence in a temporary
directory. Every run maps the same frames with SGBM (64 disparities), the ``--model`` sensor model (default
PRISM with :data:`prismap.experiment.SGBM_LIKE_MIXTURE`, near_m 0.9 m = f b / 64 px; convolution and Andert
take sigma 0.5 px), 0.1 m voxels, 8 m max range.

Stages (default): :func:`prismap.pipeline.map_sequence`, sequential, in ray and projective mode, with the
library's calls wrapped here to time them: matching (the matcher's ``compute_with_confidence``), model (the sensor model's
``cell_posteriors`` and ``influence_depth``), casting (``grid._accumulator.cast_into`` in ray mode,
``grid._kernels_project.project_voxels`` in projective mode), merge (``grid._kernels_accumulate.apply_frame``)
and rays and the rest (what is left of the frame). Stage seconds add up over threads: in ray mode the model runs
in two threads while the next chunk is cast, in projective mode on one part of the walk while the next is walked,
so the shares may add up past 100 % of the wall time (then "rays and rest" is 0). ``cold`` is the first run in
this process (numba caches loaded, PRISM's tables built), ``warm`` the median of --repeat more runs (the
pipeline keeps the model, so its tables, between runs of one config). The floor is SGBM's ``compute`` alone
on the same frames (warm, median of --repeat).

Dask (``--dask``): sequential, and on local Dask clusters of 1 and 2 worker processes. Two timings per
set-up: ``cli`` is the whole ``prismap map`` command (in this process, including starting and stopping the
local cluster and writing the map file), ``warm`` is :func:`prismap.pipeline.map_sequence` on an already
running cluster whose workers have mapped the sequence once (imports and numba caches loaded). Ratios are
against the sequential run of the same kind.

Run: ``.venv/bin/python benchmarks/bench_pipeline.py [--frames N] [--width W] [--model NAME] [--dask]``. On a 2-core
machine 2 workers can at best double the throughput; the merge of chunk maps runs in the client.
"""

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from distributed import Client, LocalCluster

import prismap.grid._accumulator
import prismap.grid._kernels_accumulate
import prismap.grid._kernels_project
import prismap.pipeline._run
from prismap import sim
from prismap.camera import StereoCamera
from prismap.cli import main as prismap_main
from prismap.experiment import SGBM_LIKE_MIXTURE
from prismap.io import read_sequence, write_sequence
from prismap.pipeline import MappingConfig, map_sequence
from prismap.stereo import make_matcher

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_grid import TimedModel  # noqa: E402

VOXEL_M = 0.1
MAX_RANGE_M = 8.0
MATCHER_PARAMS = {"num_disparities": 64}


class StageClock:
    """Wraps library functions by their module attribute and adds up the wall seconds spent in each."""

    def __init__(self):
        self.seconds = {}
        self._undo = []

    def wrap(self, module, name, stage):
        original = getattr(module, name)

        def timed(*args, **kwargs):
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - start

        setattr(module, name, timed)
        self._undo.append((module, name, original))
        return original

    def restore(self):
        for module, name, original in reversed(self._undo):
            setattr(module, name, original)


def timed_run(sequence, config):
    """Wall seconds of a sequential map_sequence and the seconds of each stage inside it."""
    clock = StageClock()
    make = clock.wrap(prismap.pipeline._run, "make_matcher", "_make")

    def matcher(*args, **kwargs):
        m = make(*args, **kwargs)
        compute = m.compute_with_confidence  # what DisparitySource calls (the disparity and its LR disagreement)

        def timed_compute(*a, **k):
            start = time.perf_counter()
            try:
                return compute(*a, **k)
            finally:
                clock.seconds["matching"] = clock.seconds.get("matching", 0.0) + time.perf_counter() - start

        m.compute_with_confidence = timed_compute
        return m

    prismap.pipeline._run.make_matcher = matcher
    model_for = prismap.pipeline._run.sensor_model_for
    timers = []

    def timed_model(*args):
        timers.append(TimedModel(model_for(*args)))
        return timers[-1]

    prismap.pipeline._run.sensor_model_for = timed_model
    clock.wrap(prismap.grid._accumulator, "cast_into", "casting")
    clock.wrap(prismap.grid._kernels_project, "project_cells", "casting")
    clock.wrap(prismap.grid._kernels_project, "project_hit_miss", "casting")
    clock.wrap(prismap.grid._kernels_accumulate, "apply_frame", "merge")
    try:
        start = time.perf_counter()
        map_sequence(sequence, config, progress=False)
        wall = time.perf_counter() - start
    finally:
        prismap.pipeline._run.sensor_model_for = model_for
        clock.restore()
    stages = {name: clock.seconds.get(name, 0.0) for name in ("matching", "casting", "merge")}
    stages["model"] = sum(t.seconds for t in timers)
    stages["rays and rest"] = max(wall - sum(stages.values()), 0.0)
    return wall, stages


def stages(sequence, config, n_frames, repeat):
    """Print cold and warm frames per second with the share of each stage (warm, median over repeats)."""
    cold, _ = timed_run(sequence, config)
    runs = [timed_run(sequence, config) for _ in range(repeat)]
    wall = statistics.median(w for w, _ in runs)
    share = {name: statistics.median(s[name] for _, s in runs) / wall for name in runs[0][1]}
    print(f"{config.mode:<10} cold {n_frames / cold:5.2f} fps, warm {n_frames / wall:5.2f} fps "
          f"({wall / n_frames * 1e3:.0f} ms/frame): " + ", ".join(f"{k} {v:.1%}" for k, v in share.items()))


def sgbm_floor(sequence, n_frames, repeat):
    """Frames per second of SGBM's compute alone on the sequence's pairs (warm, median over repeats)."""
    frames = read_sequence(sequence)
    pairs = [(frames[i].left, frames[i].right) for i in range(n_frames)]
    matcher = make_matcher("sgbm", **MATCHER_PARAMS)
    matcher.compute(*pairs[0])
    walls = []
    for _ in range(repeat):
        start = time.perf_counter()
        for left, right in pairs:
            matcher.compute(left, right)
        walls.append(time.perf_counter() - start)
    return n_frames / statistics.median(walls)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--model", default="prism")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--dask", action="store_true", help="the Dask comparison instead of the stages")
    args = parser.parse_args()
    os.environ.setdefault("PRISMAP_PROGRESS", "0")
    if args.dask and args.model == "prism":
        parser.error("--dask runs the CLI, which takes PRISM's mixture from a characterised file: use another --model")

    scale = args.width / 640
    camera = StereoCamera(615.0 * scale, 320.0 * scale - 0.5, 240.0 * scale - 0.5, 0.10,
                          width=args.width, height=int(480 * scale))
    model_params = {"sigma_px": 0.5} if args.model in ("convolution", "andert") else {}
    error_model = None
    if args.model == "prism":
        model_params = {"near_m": 0.9}
        error_model = SGBM_LIKE_MIXTURE
    with tempfile.TemporaryDirectory() as tmp:
        sequence = Path(tmp) / "seq"
        scene = sim.indoor_scene(seed=0)
        write_sequence(scene.frames(camera, sim.indoor_trajectory(args.frames, seed=0), seed=0), sequence)
        with open("/proc/loadavg") as f:
            load = " ".join(f.read().split()[:3])
        print(f"scene: indoor_scene(seed=0), {args.frames} frames of {camera.width}x{camera.height} px "
              f"(f {camera.focal_px:.1f} px, b 0.10 m); sgbm 64 disparities, {args.model} {model_params}, "
              f"voxel {VOXEL_M} m, max range {MAX_RANGE_M} m; load {load}")
        if not args.dask:
            for mode in ("ray", "projective"):
                config = MappingConfig(model=args.model, model_params=model_params, error_model=error_model,
                                       voxel_size_m=VOXEL_M, max_range_m=MAX_RANGE_M, matcher="sgbm",
                                       matcher_params=MATCHER_PARAMS, mode=mode)
                stages(sequence, config, args.frames, args.repeat)
            print(f"floor: SGBM compute alone {sgbm_floor(sequence, args.frames, args.repeat):.2f} fps")
            return
        config = MappingConfig(model=args.model, model_params=model_params, error_model=error_model,
                               voxel_size_m=VOXEL_M, max_range_m=MAX_RANGE_M, matcher="sgbm",
                               matcher_params=MATCHER_PARAMS)
        command = ["map", "--sequence", str(sequence), "--matcher", "sgbm", "--matcher-param", "num_disparities=64",
                   "--model", args.model, *[f"--model-param={k}={v}" for k, v in model_params.items()],
                   "--voxel", str(VOXEL_M), "--max-range", str(MAX_RANGE_M), "--out", str(Path(tmp) / "map.npz")]
        map_sequence(sequence, config, progress=False)  # numba caches loaded before any timing
        rows = []
        for label, extra in (("sequential", []), ("dask 1 worker", ["--workers", "1"]), ("dask 2 workers", ["--workers", "2"])):
            start = time.perf_counter()
            assert prismap_main(command + extra) == 0
            cli_s = time.perf_counter() - start
            warm_s = _warm_seconds(sequence, config, None if not extra else int(extra[1]))
            rows.append((label, args.frames / cli_s, args.frames / warm_s))
    print(f"{'set-up':<16} {'cli fps':>8} {'ratio':>6} {'warm fps':>9} {'ratio':>6}")
    for label, cli_fps, warm_fps in rows:
        print(f"{label:<16} {cli_fps:8.2f} {cli_fps / rows[0][1]:6.2f} {warm_fps:9.2f} {warm_fps / rows[0][2]:6.2f}")


def _warm_seconds(sequence, config, n_workers):
    """Seconds of map_sequence, sequential or on a running cluster warmed by one full run."""
    if n_workers is None:
        start = time.perf_counter()
        map_sequence(sequence, config, progress=False)
        return time.perf_counter() - start
    with LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        map_sequence(sequence, config, progress=False, client=client)
        start = time.perf_counter()
        map_sequence(sequence, config, progress=False, client=client)
        return time.perf_counter() - start


if __name__ == "__main__":
    main()
