"""How long ``prismap view`` takes to build its scene for maps of 1 M and 5 M voxels, and how many points
it sends.

Map: ``--voxels`` known voxels (default 1 M and 5 M) of 0.05 m on the walls, floor and ceiling of nested
rooms (a surface map, as stereo gives; 5 % occupied shells, the rest free interior voxels behind them), with
seeded random probabilities. Timed: :class:`prismap.viewer.MapViewer` construction (pyramid, selection,
colours, point-cloud serialisation; no browser connected) with the default view (occupied only), then
turning on free (every known voxel: builds the coarser level the budget needs) and then unknown (adds the
unobserved cells of the box: the largest view), one checkbox callback each, the best of ``--repeat`` runs.

Run: ``.venv/bin/python benchmarks/bench_viewer.py [--voxels 1000000 5000000] [--repeat 3]``.
"""

import argparse
import time

import numpy as np
from scipy.special import logit

from prismap.grid import OccupancyMap
from prismap.viewer import POINT_BUDGET, MapViewer

VOXEL_M = 0.05


def synthetic_map(n_voxels, seed=0):
    """A map of about ``n_voxels`` known voxels: box shells (occupied) around free slabs, random P."""
    rng = np.random.default_rng(seed)
    side = round((n_voxels / 6) ** 0.5)
    a, b = (g.ravel() for g in np.meshgrid(np.arange(side), np.arange(side), indexing="ij"))
    faces = [
        np.c_[a, b, np.zeros_like(a)],
        np.c_[a, b, np.full_like(a, side)],
        np.c_[a, np.zeros_like(a), b],
        np.c_[a, np.full_like(a, side), b],
        np.c_[np.zeros_like(a), a, b],
        np.c_[np.full_like(a, side), a, b],
    ]
    keys = np.unique(np.vstack(faces), axis=0)
    occupied = rng.random(len(keys)) < 0.05
    probability = np.where(occupied, rng.uniform(0.6, 0.99, len(keys)), rng.uniform(0.01, 0.4, len(keys)))
    grid = OccupancyMap(VOXEL_M, p0=0.5)
    grid.set_voxels(keys.astype(np.int32), logit(probability).astype(np.float32), np.ones(len(keys), np.uint16))
    return grid


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--voxels", type=int, nargs="+", default=[1_000_000, 5_000_000])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    print(f"point budget {POINT_BUDGET:,}; voxels {VOXEL_M} m")
    print(
        "| known voxels | build (s) | points sent (occupied) | free on (s) | unknown on (s) | points sent (all) "
        "| map level (all) |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for n in args.voxels:
        grid = synthetic_map(n)
        builds, refreshes = [], []
        for _ in range(args.repeat):
            viewer = MapViewer(grid, port=0)
            builds.append(viewer.stats["build_s"])
            first = viewer.stats
            steps = []
            for name in ("free", "unknown"):  # each checkbox's callback refreshes the scene synchronously
                start = time.perf_counter()
                viewer.show[name].value = True
                steps.append(time.perf_counter() - start)
            refreshes.append(steps)
            every = viewer.refresh()
            viewer.stop()
        free_s, unknown_s = np.min(refreshes, axis=0)
        print(
            f"| {grid.n_known:,} | {min(builds):.2f} | {first['points']:,} | {free_s:.2f} | {unknown_s:.2f} | "
            f"{every['points']:,} | {every['level']} |"
        )


if __name__ == "__main__":
    main()
