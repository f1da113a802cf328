"""Frames per second of ``prismap map``: sequential, and on local Dask clusters of 1 and 2 worker processes.

Scene: the seeded indoor room of ``prismap.sim`` (``indoor_scene(seed=0)``) along ``indoor_trajectory``,
rendered to ``--frames`` stereo pairs (default 16) by a New-Tsukuba-like camera scaled to ``--width`` pixels
(default 320 x 240, f = 307.5 px, baseline 0.10 m) and written as a KITTI-layout sequence in a temporary
directory. Every run maps the same frames with SGBM (64 disparities), the ``--model`` sensor model (default
convolution, sigma 0.5 px), 0.1 m voxels, 8 m max range, ray mode.

Two timings per set-up: ``cli`` is the whole ``prismap map`` command (in this process, including starting
and stopping the local cluster and writing the map file), ``warm`` is :func:`prismap.pipeline.map_sequence`
on an already running cluster whose workers have mapped the sequence once (imports and numba caches
loaded). Ratios are against the sequential run of the same kind.

Run: ``.venv/bin/python benchmarks/bench_pipeline.py [--frames N] [--width W] [--model NAME]``. On a 2-core
machine 2 workers can at best double the throughput; the merge of chunk maps runs in the client.
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

from distributed import Client, LocalCluster

from prismap import sim
from prismap.camera import StereoCamera
from prismap.cli import main as prismap_main
from prismap.io import write_sequence
from prismap.pipeline import MappingConfig, map_sequence

VOXEL_M = 0.1
MAX_RANGE_M = 8.0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--model", default="convolution")
    args = parser.parse_args()
    os.environ.setdefault("PRISMAP_PROGRESS", "0")

    scale = args.width / 640
    camera = StereoCamera(615.0 * scale, 320.0 * scale - 0.5, 240.0 * scale - 0.5, 0.10,
                          width=args.width, height=int(480 * scale))
    model_params = {"sigma_px": 0.5} if args.model in ("convolution", "andert") else {}
    config = MappingConfig(model=args.model, model_params=model_params, voxel_size_m=VOXEL_M, max_range_m=MAX_RANGE_M,
                           matcher="sgbm", matcher_params={"num_disparities": 64})
    with tempfile.TemporaryDirectory() as tmp:
        sequence = Path(tmp) / "seq"
        scene = sim.indoor_scene(seed=0)
        write_sequence(scene.frames(camera, sim.indoor_trajectory(args.frames, seed=0), seed=0), sequence)
        print(f"scene: indoor_scene(seed=0), {args.frames} frames of {camera.width}x{camera.height} px "
              f"(f {camera.focal_px:.1f} px, b 0.10 m); sgbm 64 disparities, {args.model} {model_params}, "
              f"voxel {VOXEL_M} m, max range {MAX_RANGE_M} m")
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
