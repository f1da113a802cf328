"""Where a mapped frame's CPU goes, on the street of ``bench_grid.py --street --conditioned`` (scene (c)).

Maps the street's SGBM disparities (``bench_grid.sgbm_world``: the world's own characterised error model, each
pixel's class) with ``prismap map``'s model (conditioned PRISM, or ``--model prism`` for the plain mixture) in ray
mode (the default) or projective mode, one map, frame after frame, and times the parts of each frame with the CPU
clock of the thread that runs them:

- ``cast`` (ray mode): the casting thread's ``_accumulator.cast_into`` (Amanatides & Woo, registering each crossed
  voxel in the frame's accumulator);
- ``walk`` (projective mode): the part threads' walk of the frustum's key box (``_kernels_project.project_part``)
  and ``group by ray``, their cells grouped by ray for the model (``_kernels_project.group_by_ray``);
- ``kernel``: the PRISM look-up kernel (``_kernels_lookup.prism_table_cells``);
- ``model rest``: the rest of the model calls (``Integrator.cell_increments``: keys, failure posteriors);
- ``scatter``: adding the increments to the frame's accumulator (``_accumulator.scatter``; projective:
  ``scatter_keys``, which also registers the voxels);
- ``table builds``: PRISM's tables built for the frame's new keys (``_kernels_pack.prism_tables``, in every thread;
  both modes build them all for the stop depths, before the cells, so none inside the model calls);
- ``rest``: process CPU outside those (the batch, the stop depths' key search, chunks and parts, the map update).

It prints each part's median over the steady frames (all but the first, which loads numba's caches and builds every
table the frame needs; a steady frame builds the tables of the keys it is the first to meet) in seconds a frame and
nanoseconds a cell, then the frame's wall-clock phases: the set-up before the first cell (the batch, the stop
depths and the table builds, in the calling thread and the table builders), the per-cell work (cast or walk, model
and scatter, on every thread: with both cores busy about half the CPU of their parts) and the map update. Not a peer
benchmark: ``bench_grid.py`` compares the same paths with OctoMap and UFOMap.

Run: ``.venv/bin/python benchmarks/frame_breakdown.py [--mode ray] [--scale 1] [--frames 8] [--model conditioned]
[--world-dir DIR]``
"""

import argparse
import collections
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_grid import load_world, sgbm_world, street_model

from prismap.camera import integrate_disparity
from prismap.grid import OccupancyMap, _accumulator, _integrators, _kernels_project
from prismap.sensor_models import _kernels_lookup, _kernels_pack

MODEL_PARTS = {  # label: (owner, attribute)
    "kernel": (_kernels_lookup, "prism_table_cells"),
    "model call": (_integrators.Integrator, "cell_increments"),
    "table builds": (_kernels_pack, "prism_tables"),
}
PARTS = {
    "ray": {"cast": (_accumulator, "cast_into"), "scatter": (_accumulator, "scatter"), **MODEL_PARTS},
    "projective": {
        "walk": (_kernels_project, "project_part"),
        "group by ray": (_kernels_project, "group_by_ray"),
        "scatter": (_accumulator, "scatter_keys"),
        **MODEL_PARTS,
    },
}
"""The parts each mode's frame is timed by."""


class PartClock:
    """Thread CPU seconds spent in each part of ``parts`` (a value of :data:`PARTS`) since :meth:`reset`, the cells
    made (cast or walked) and the tables built, and each part's first start and last end (``perf_counter``)."""

    def __init__(self, parts):
        self.parts = parts
        self.seconds = collections.Counter()
        self.cells = self.tables = 0
        self.first, self.last = {}, {}
        self._lock = threading.Lock()
        for label, (owner, name) in parts.items():
            setattr(owner, name, self._timed(label, getattr(owner, name)))

    def _timed(self, label, function):
        def timed(*args, **kwargs):
            start, begun = time.thread_time(), time.perf_counter()
            result = function(*args, **kwargs)
            with self._lock:
                self.first[label] = min(self.first.get(label, begun), begun)
                self.last[label] = max(self.last.get(label, 0.0), time.perf_counter())
                self.seconds[label] += time.thread_time() - start
                if label == "cast":
                    self.cells += result[1].size
                elif label == "walk":
                    self.cells += result[4]
                elif label == "table builds":
                    self.tables += result[1].shape[0]
            return result

        return timed

    def reset(self):
        self.seconds.clear()
        self.first.clear()
        self.last.clear()
        self.cells = self.tables = 0

    def phases(self, start, end, cells_part):
        """Wall seconds of the frame's phases: ``set-up`` (batch, stop depths, table builds: up to the first
        ``cells_part``, the cast or the walk), ``per-cell work`` (from there to the last scatter) and ``map update``."""
        first, last = self.first[cells_part], self.last["scatter"]
        return {"set-up": first - start, "per-cell work": last - first, "map update": end - last}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--mode", choices=tuple(PARTS), default="ray")
    parser.add_argument("--scale", type=float, default=1.0, help="rig scale: 1 is 1242x375 px, 0.5 is 621x188")
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--model", choices=("conditioned", "prism"), default="conditioned")
    parser.add_argument("--voxel", type=float, default=0.2, help="metres")
    parser.add_argument("--world-dir", help="where the street's world is kept (reused when present)")
    args = parser.parse_args()
    clock = PartClock(PARTS[args.mode])
    with tempfile.TemporaryDirectory() as tmp:
        world = sgbm_world(
            args.scale, args.frames, Path(args.world_dir or tmp) / f"street_{args.scale:g}_{args.frames}"
        )
        camera, poses, disparities, classes, error_model = load_world(args.scale, args.frames, world)
    model = street_model(args.model, camera, args.voxel, error_model)
    grid = OccupancyMap(args.voxel, p0=getattr(model, "plain", model).p0)
    frames = list(zip(disparities, poses, classes if args.model == "conditioned" else [None] * len(poses)))
    rows = []
    for index, (disparity, pose, ray_class) in enumerate(frames):
        clock.reset()
        start, start_cpu = time.perf_counter(), time.process_time()
        integrate_disparity(grid, disparity, camera, pose, model, mode=args.mode, max_range_m=80.0, ray_class=ray_class)
        wall, cpu = time.perf_counter() - start, time.process_time() - start_cpu
        if index:  # the first frame is cold (numba's caches, every table of the frame)
            parts = {label: clock.seconds[label] for label in clock.parts}
            parts["model rest"] = parts.pop("model call") - parts["kernel"]
            parts["rest"] = cpu - sum(parts.values())
            phases = clock.phases(start, start + wall, "cast" if args.mode == "ray" else "walk")
            rows.append({"wall": wall, "CPU": cpu, **parts, **phases, "cells": clock.cells, "tables": clock.tables})
    median = {key: statistics.median(row[key] for row in rows) for key in rows[0]}
    print(
        f"street {camera.width}x{camera.height} px, {args.frames} frames, {args.voxel:g} m voxels, rays to 80 m, "
        f"{args.model} PRISM ({error_model.n_classes} classes), {args.mode} mode: {median['cells'] / 1e6:.1f} M cells "
        f"a frame; {median['tables']:.0f} tables built a frame; median of the steady frames"
    )
    for key in ("wall", "CPU", *(label for label in clock.parts if label != "model call"), "model rest", "rest"):
        print(f"{key:12s} {median[key]:7.3f} s  {median[key] / median['cells'] * 1e9:5.1f} ns a cell")
    print("wall clock: " + ", ".join(f"{key} {median[key]:.3f} s" for key in ("set-up", "per-cell work", "map update")))


if __name__ == "__main__":
    main()
