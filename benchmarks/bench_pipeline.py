"""Frames per second of ``prismap map``'s work, stage by stage, with SGBM alone as the floor; Dask set-ups.

Scene: the seeded indoor room of ``prismap.sim`` (``indoor_scene(seed=0)``) along ``indoor_trajectory``,
rendered to ``--frames`` stereo pairs (default 16) by a New-Tsukuba-like camera scaled to ``--width`` pixels
(default 640 x 480, f = 615 px, baseline 0.10 m) and written as a KITTI-layout sequence in a temporary
directory. Every run maps the same frames with SGBM (64 disparities), the ``--model`` sensor model (convolution
and Andert take sigma 0.5 px), 0.1 m voxels, 8 m max range. PRISM (the default) runs as ``prismap map`` does by
default: SGBM is characterised on the sequence's first :data:`CHARACTERISE_FRAMES` frames
(:func:`prismap.characterise.characterise_matcher`, conditioned, the class count it picks), the model's own
parameters are its defaults, and the stages are timed twice per mode: conditioned (each pixel's class from its
features, the default) and plain (the whole-image mixture), with their ratio. ``--error-model FILE`` reads PRISM's
error model from an error-model JSON file (:func:`prismap.characterise.load_error_model`, any readable
``format_version``) instead of characterising SGBM: one fixed model, so that runs of different versions of the
library map with the same error model (a version-2 file, without a failure component, maps as it did when written).

Stages (default): :func:`prismap.pipeline.map_sequence`, sequential, in ray and projective mode, with the
library's calls wrapped here to time them: matching (the matcher's ``compute_with_confidence``), model (the sensor model's
``cell_posteriors`` and ``influence_depth``), casting (``grid._accumulator.cast_into`` in ray mode,
``grid._kernels_project.project_voxels`` in projective mode), merge (``grid._kernels_accumulate.apply_frame``)
and rays and the rest (what is left of the frame). Stage seconds add up over threads: in ray mode the model runs
in a thread while the next chunk is cast (and in the casting thread while it would wait), in projective mode on one
part of the walk while the next is walked,
so the shares may add up past 100 % of the wall time (then "rays and rest" is 0). ``cold`` is the first run in
this process (numba caches loaded, PRISM's tables built and written to an empty table store, a temporary
``PRISMAP_TABLE_CACHE``), ``warm`` the median of --repeat more runs (the
pipeline keeps the model, so its tables, between runs of one config). The pipeline computes the next frame's
disparity in a background thread while it integrates this one (``pipeline._prefetch.Prefetch``), so matching
overlaps the other stages; a second line gives warm runs without that look-ahead (each frame's disparity computed
when the loop reaches it), alternating with the runs with it, and a third the CPU per frame of the disparity
thread, of the integration thread and of its workers, and the frame rate they allow on 2 idle cores (the
busiest thread's, or the total CPU over 2 cores). The floor is SGBM's ``compute`` alone on the same frames (warm,
median of --repeat). The load average is printed before and after (the machine is shared).

Dask (``--dask``): sequential, and on local Dask clusters of 1 and 2 worker processes. Two timings per
set-up: ``cli`` is the whole ``prismap map`` command (in this process, including starting and stopping the
local cluster and writing the map file), ``warm`` is :func:`prismap.pipeline.map_sequence` on an already
running cluster whose workers have mapped the sequence once (imports and numba caches loaded). Ratios are
against the sequential run of the same kind.

Run: ``.venv/bin/python benchmarks/bench_pipeline.py [--frames N] [--width W] [--model NAME] [--modes ray projective]
[--error-model FILE] [--cv-threads N] [--dask]``. On a 2-core
machine 2 workers can at best double the throughput; the merge of chunk maps runs in the client.
"""

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
from distributed import Client, LocalCluster

import prismap.grid._accumulator
import prismap.grid._kernels_accumulate
import prismap.grid._kernels_project
import prismap.pipeline._run
from prismap import sim
from prismap.camera import StereoCamera
from prismap.characterise import characterise_matcher, load_error_model
from prismap.cli import main as prismap_main
from prismap.io import read_sequence, write_sequence
from prismap.pipeline import MappingConfig, map_sequence
from prismap.sensor_models._table_store import STORE_ENV
from prismap.stereo import make_matcher

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_grid import TimedModel

CHARACTERISE_FRAMES = 4
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

        self.replace(module, name, timed)
        return original

    def replace(self, module, name, value):
        """Set ``module.name`` to ``value`` until :meth:`restore`."""
        self._undo.append((module, name, getattr(module, name)))
        setattr(module, name, value)

    def restore(self):
        for module, name, original in reversed(self._undo):
            setattr(module, name, original)


class InLine:
    """:class:`prismap.pipeline._prefetch.Prefetch`'s interface without the look-ahead: each frame's disparity
    is computed when the loop reaches it (the frame-by-frame path)."""

    def __init__(self, produce, items):
        self.produce, self.items = produce, list(items)

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        pass

    def __iter__(self):
        for item in self.items:
            yield item, self.produce(item)


def timed_run(sequence, config, *, look_ahead=True):
    """Wall and CPU seconds of a sequential map_sequence and the seconds of each stage inside it; without
    ``look_ahead`` the frames' disparities are computed in line (:class:`InLine`)."""
    clock = StageClock()
    if not look_ahead:
        clock.replace(prismap.pipeline._run, "Prefetch", InLine)
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
    integrate = prismap.pipeline._run.integrate_disparity
    timers = []

    def timed_integrate(grid, disparity, camera, pose, model, **options):
        # the run's model itself reaches DisparitySource, whose test for a conditioned model a wrapper would fail
        timers.append(TimedModel(model))
        return integrate(grid, disparity, camera, pose, timers[-1], **options)

    clock.replace(prismap.pipeline._run, "integrate_disparity", timed_integrate)
    clock.wrap(prismap.grid._accumulator, "cast_into", "casting")
    clock.wrap(prismap.grid._kernels_project, "project_part", "casting")
    clock.wrap(prismap.grid._kernels_accumulate, "apply_frame", "merge")
    source_call = prismap.pipeline._run.DisparitySource.__call__
    disparity_cpu = [0.0]

    def timed_source(self, index):  # CPU of the thread that computes the frame's disparity
        start = time.thread_time()
        try:
            return source_call(self, index)
        finally:
            disparity_cpu[0] += time.thread_time() - start

    clock.replace(prismap.pipeline._run.DisparitySource, "__call__", timed_source)
    try:
        start, cpu, main_cpu = time.perf_counter(), time.process_time(), time.thread_time()
        map_sequence(sequence, config, progress=False)
        wall, cpu, main_cpu = time.perf_counter() - start, time.process_time() - cpu, time.thread_time() - main_cpu
    finally:
        clock.restore()
    stages = {name: clock.seconds.get(name, 0.0) for name in ("matching", "casting", "merge")}
    stages["model"] = sum(t.seconds for t in timers)
    stages["rays and rest"] = max(wall - sum(stages.values()), 0.0)
    main_cpu -= 0.0 if look_ahead else disparity_cpu[0]
    threads = {"disparity": disparity_cpu[0], "integration": main_cpu, "workers": cpu - main_cpu - disparity_cpu[0]}
    return wall, cpu, stages, threads


def stages(sequence, config, n_frames, repeat):
    """Print cold and warm frames per second with the share of each stage (warm, median over repeats), then
    the same warm runs without the look-ahead, alternating with runs with it."""
    cold = timed_run(sequence, config)[0]
    runs, inline = [], []
    for _ in range(repeat):
        runs.append(timed_run(sequence, config))
        inline.append(timed_run(sequence, config, look_ahead=False))
    wall = statistics.median(run[0] for run in runs)
    share = {name: statistics.median(run[2][name] for run in runs) / wall for name in runs[0][2]}
    print(
        f"{config.mode:<10} cold {n_frames / cold:5.2f} fps, warm {n_frames / wall:5.2f} fps "
        f"({wall / n_frames * 1e3:.0f} ms/frame, CPU {_median_ms(runs, 1, n_frames):.0f} ms/frame): "
        + ", ".join(f"{k} {v:.1%}" for k, v in share.items())
    )
    wall_inline = statistics.median(run[0] for run in inline)
    print(
        f"{'':<10} frame by frame (no look-ahead) warm {n_frames / wall_inline:5.2f} fps ({wall_inline / n_frames * 1e3:.0f} "
        f"ms/frame, CPU {_median_ms(inline, 1, n_frames):.0f} ms/frame): the look-ahead x{wall_inline / wall:.2f}"
    )
    threads = {name: statistics.median(run[3][name] for run in runs) / n_frames for name in runs[0][3]}
    bound = min(1.0 / threads["disparity"], 1.0 / threads["integration"], 2.0 / sum(threads.values()))
    print(
        f"{'':<10} CPU per frame with the look-ahead: disparity thread {threads['disparity'] * 1e3:.0f} ms, integration "
        f"thread {threads['integration'] * 1e3:.0f} ms, its workers {threads['workers'] * 1e3:.0f} ms: on 2 idle cores "
        f"at most {bound:.2f} fps (the busiest thread, or the total over 2 cores)"
    )
    return _median_ms(runs, 1, n_frames)


def _median_ms(runs, column, n_frames):
    return statistics.median(run[column] for run in runs) / n_frames * 1e3


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
    parser.add_argument("--modes", nargs="+", default=["ray", "projective"], choices=["ray", "projective"])
    parser.add_argument("--error-model", help="PRISM's error model from this JSON file instead of characterising SGBM")
    parser.add_argument("--cv-threads", type=int, default=None, help="cv2.setNumThreads before any run")
    parser.add_argument("--dask", action="store_true", help="the Dask comparison instead of the stages")
    args = parser.parse_args()
    os.environ[STORE_ENV] = tempfile.mkdtemp(prefix="prismap-tables-")  # a rig's first run: an empty table store
    os.environ.setdefault("PRISMAP_PROGRESS", "0")
    if args.cv_threads is not None:
        cv2.setNumThreads(args.cv_threads)
    if args.dask and args.model == "prism":
        parser.error(
            "--dask runs the CLI, which takes PRISM's error model from a characterised file: use another --model"
        )

    scale = args.width / 640
    camera = StereoCamera(
        615.0 * scale, 320.0 * scale - 0.5, 240.0 * scale - 0.5, 0.10, width=args.width, height=int(480 * scale)
    )
    model_params = {"sigma_px": 0.5} if args.model in ("convolution", "andert") else {}
    with tempfile.TemporaryDirectory() as tmp:
        sequence = Path(tmp) / "seq"
        scene = sim.indoor_scene(seed=0)
        frames = list(scene.frames(camera, sim.indoor_trajectory(args.frames, seed=0), seed=0))
        write_sequence(frames, sequence)
        error_model, variants = None, [(None, "")]
        if args.model == "prism":
            error_model = (
                load_error_model(args.error_model)
                if args.error_model
                else characterise_matcher(
                    frames[:CHARACTERISE_FRAMES], make_matcher("sgbm", **MATCHER_PARAMS), progress=False
                ).model
            )
            variants = [(True, "conditioned"), (False, "plain")] if error_model.conditioned else [(False, "plain")]
        del frames
        print(
            f"scene: indoor_scene(seed=0), {args.frames} frames of {camera.width}x{camera.height} px "
            f"(f {camera.focal_px:.1f} px, b 0.10 m); sgbm 64 disparities, {args.model} {model_params}"
            + (
                f" with SGBM's error model from {args.error_model or f'{CHARACTERISE_FRAMES} frames'} "
                f"({error_model.n_classes} classes)"
                if error_model is not None
                else ""
            )
            + f", voxel {VOXEL_M} m, max range {MAX_RANGE_M} m; OpenCV threads {cv2.getNumThreads()}; load {_load()}"
        )
        if not args.dask:
            for mode in args.modes:
                cpu = {}
                for conditioned, label in variants:
                    config = MappingConfig(
                        model=args.model,
                        model_params=model_params,
                        error_model=error_model,
                        conditioned=conditioned,
                        voxel_size_m=VOXEL_M,
                        max_range_m=MAX_RANGE_M,
                        matcher="sgbm",
                        matcher_params=MATCHER_PARAMS,
                        mode=mode,
                    )
                    if label:
                        print(label)
                    cpu_ms = cpu[label] = stages(sequence, config, args.frames, args.repeat)
                if len(cpu) == 2:
                    print(f"{mode}: conditioned / plain warm CPU per frame {cpu['conditioned'] / cpu['plain']:.2f}")
            print(
                f"floor: SGBM compute alone {sgbm_floor(sequence, args.frames, args.repeat):.2f} fps (one thread); "
                f"the last mode's warm CPU per frame on 2 cores {2e3 / cpu_ms:.2f} fps; load {_load()}"
            )
            return
        config = MappingConfig(
            model=args.model,
            model_params=model_params,
            error_model=error_model,
            voxel_size_m=VOXEL_M,
            max_range_m=MAX_RANGE_M,
            matcher="sgbm",
            matcher_params=MATCHER_PARAMS,
        )
        command = [
            "map",
            "--sequence",
            str(sequence),
            "--matcher",
            "sgbm",
            "--matcher-param",
            "num_disparities=64",
            "--model",
            args.model,
            *[f"--model-param={k}={v}" for k, v in model_params.items()],
            "--voxel",
            str(VOXEL_M),
            "--max-range",
            str(MAX_RANGE_M),
            "--out",
            str(Path(tmp) / "map.npz"),
        ]
        map_sequence(sequence, config, progress=False)  # numba caches loaded before any timing
        rows = []
        for label, extra in (
            ("sequential", []),
            ("dask 1 worker", ["--workers", "1"]),
            ("dask 2 workers", ["--workers", "2"]),
        ):
            start = time.perf_counter()
            assert prismap_main(command + extra) == 0
            cli_s = time.perf_counter() - start
            warm_s = _warm_seconds(sequence, config, None if not extra else int(extra[1]))
            rows.append((label, args.frames / cli_s, args.frames / warm_s))
    print(f"{'set-up':<16} {'cli fps':>8} {'ratio':>6} {'warm fps':>9} {'ratio':>6}")
    for label, cli_fps, warm_fps in rows:
        print(f"{label:<16} {cli_fps:8.2f} {cli_fps / rows[0][1]:6.2f} {warm_fps:9.2f} {warm_fps / rows[0][2]:6.2f}")


def _load():
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def _warm_seconds(sequence, config, n_workers):
    """Seconds of map_sequence, sequential or on a running cluster warmed by one full run."""
    if n_workers is None:
        start = time.perf_counter()
        map_sequence(sequence, config, progress=False)
        return time.perf_counter() - start
    with (
        LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        Client(cluster) as client,
    ):
        map_sequence(sequence, config, progress=False, client=client)
        start = time.perf_counter()
        map_sequence(sequence, config, progress=False, client=client)
        return time.perf_counter() - start


if __name__ == "__main__":
    main()
