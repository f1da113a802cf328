"""Thesis table 6.1: nanoseconds per cell and per ray of every sensor model, PRISM direct and tabulated.

All models run in one process on the same batch (``time_models`` below): the rays of a 640x480
frame (f of the chosen rig, principal point at the centre) seeing 8 fronto-parallel planes at 1-20 m,
disparities rounded to 1/16 px, cells of 0.1 m along each ray up to the largest influence depth, in chunks
of 8192 rays; direct PRISM on 16 seeded random rays of the frame. Ratios are against OctoMap's hit/miss model.
The error model is close to SGBM on Middlebury Motorcycle.

    .venv/bin/python benchmarks/bench_models_table.py                  # full frame, Motorcycle rig
    .venv/bin/python benchmarks/bench_models_table.py --stride 2 --camera tsukuba
"""

import argparse
import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from prismap._progress import progress
from prismap._validate import check_positive
from prismap.errors import PrismapInputError
from prismap.gmm import GaussianMixture
from prismap.study import CAMERAS, RaySetup, study_models

MIXTURE = GaussianMixture([0.84, 0.10, 0.06], [0.01, -0.04, -10.4], [0.24, 0.92, 13.6])


@dataclass(frozen=True)
class PerformanceTable:
    """Cost of every model on one batch of rays (thesis table 6.1).

    Attributes
    ----------
    rows : tuple of dict
        ``{"model", "seconds", "ns_per_cell", "ns_per_ray", "n_rays", "n_cells"}`` per model.
    scene : str
        The batch, in words.
    table_build_s : float, seconds
        The first ``influence_depth`` call of every model on the batch: for PRISM it builds the tables of
        the batch's distinct disparities (paid once per error model and camera).
    n_disparities : int
        Distinct measured disparities in the batch.
    """

    rows: tuple
    scene: str
    table_build_s: float
    n_disparities: int

    def to_dict(self):
        """JSON-ready form."""
        return {
            "scene": self.scene,
            "table_build_s": self.table_build_s,
            "n_disparities": self.n_disparities,
            "rows": list(self.rows),
        }

    def to_markdown(self):
        """Markdown table with the scene and the one-off table cost underneath."""
        lines = ["| model | ns per cell | ns per ray | rays | cells | seconds |", "|---|---:|---:|---:|---:|---:|"]
        for row in self.rows:
            lines.append(
                f"| {row['model']} | {row['ns_per_cell']:.1f} | {row['ns_per_ray']:.0f} | {row['n_rays']} | "
                f"{row['n_cells']} | {row['seconds']:.3f} |"
            )
        lines.append("")
        lines.append(
            f"Scene: {self.scene}. Before timing, the influence depths of the batch took "
            f"{self.table_build_s:.2f} s, mostly building PRISM's tables for {self.n_disparities} distinct "
            "disparities (once per error model and camera)."
        )
        return "\n".join(lines) + "\n"


def _band_scene(setup, focal_px, *, width, height, stride, depth_range_m, n_bands):
    """Rays of every ``stride``-th pixel of a ``width x height`` frame (principal point at the centre) looking
    at ``n_bands`` fronto-parallel planes in vertical bands, depths spaced evenly."""
    v, u = np.mgrid[0:height:stride, 0:width:stride].astype(np.float64)
    x, y = (u - width / 2) / focal_px, (v - height / 2) / focal_px
    near, far = depth_range_m
    band_depth = np.linspace(near, far, n_bands)
    band = np.minimum((u / width * n_bands).astype(np.int64), n_bands - 1)
    disparity = np.array([setup.disparity_at(z) for z in band_depth])[band].ravel()
    return disparity, np.sqrt(1.0 + x * x + y * y).ravel(), band_depth


def _cells(setup, disparity, norm, end_depth):
    """Cells of ``voxel_size_m`` along each ray (in distance) from ``near_m`` to ``end_depth`` (depth)."""
    step = setup.voxel_size_m / norm
    counts = np.maximum(np.ceil((end_depth - setup.near_m) / step), 1).astype(np.int64)
    rays = np.repeat(np.arange(disparity.size, dtype=np.int64), counts)
    index = np.arange(rays.size) - np.repeat(np.cumsum(counts) - counts, counts)
    start = setup.near_m + index * step[rays]
    return rays, start, start + step[rays]


def time_models(
    mixture,
    *,
    setup,
    focal_px,
    width=640,
    height=480,
    stride=1,
    depth_range_m=(1.0, 20.0),
    n_bands=8,
    direct_rays=16,
    chunk_rays=8192,
    seed=0,
    names=None,
):
    """Nanoseconds per cell and per ray of every model, PRISM direct and tabulated, on one batch.

    The batch: rays of every ``stride``-th pixel of a ``width x height`` frame (focal ``focal_px``, principal
    point at the centre) that sees ``n_bands`` planes at depths in ``depth_range_m`` (disparities rounded to
    1/16 px); each ray gets cells of ``voxel_size_m`` (along the ray) from ``near_m`` to the largest
    influence depth of the models. All models run on the same chunks of ``chunk_rays`` rays in turn after a
    warm-up; direct PRISM (a quadrature, far slower) runs on ``direct_rays`` rays drawn with ``seed`` and is
    reported per cell and ray of that subset.

    Returns
    -------
    PerformanceTable
    """
    check_positive(focal_px, "focal_px")
    if min(stride, direct_rays, chunk_rays, n_bands) < 1:
        raise PrismapInputError("`stride`, `direct_rays`, `chunk_rays` and `n_bands` must be >= 1")
    disparity, norm, band_depth = _band_scene(
        setup, focal_px, width=width, height=height, stride=stride, depth_range_m=depth_range_m, n_bands=n_bands
    )
    models = study_models(mixture, setup=setup, names=names, prism_method="table")
    t0 = time.perf_counter()
    end_depth = np.max([model.influence_depth(disparity, norm) for model in models.values()], axis=0)
    table_build_s = time.perf_counter() - t0
    timed = dict(models)
    if "prism" in models:
        timed = {("prism (table)" if k == "prism" else k): m for k, m in models.items()}
        timed["prism (direct)"] = dataclasses.replace(models["prism"], method="direct")
    seconds = dict.fromkeys(timed, 0.0)
    cells = dict.fromkeys(timed, 0)
    rays_done = dict.fromkeys(timed, 0)
    direct = np.zeros(disparity.size, dtype=bool)
    direct[np.random.default_rng(seed).choice(disparity.size, min(direct_rays, disparity.size), replace=False)] = True
    starts = range(0, disparity.size, chunk_rays)
    warm = set()
    for first in progress(starts, total=len(starts), desc="timing models"):
        chunk = slice(first, first + chunk_rays)
        batch = (disparity[chunk], norm[chunk], *_cells(setup, disparity[chunk], norm[chunk], end_depth[chunk]))
        sub = np.nonzero(direct[chunk])[0]
        direct_batch = (
            batch[0][sub],
            batch[1][sub],
            *_cells(setup, batch[0][sub], batch[1][sub], end_depth[chunk][sub]),
        )
        for name, model in timed.items():
            use = direct_batch if name == "prism (direct)" else batch
            if use[0].size == 0:
                continue
            if name not in warm:  # compile the kernels outside the timing
                model.cell_posteriors(use[0][:1], use[1][:1], *_cells(setup, use[0][:1], use[1][:1], use[3][:1] + 0.5))
                warm.add(name)
            t = time.perf_counter()
            model.cell_posteriors(*use)
            seconds[name] += time.perf_counter() - t
            cells[name] += use[2].size
            rays_done[name] += use[0].size
    rows = tuple(
        {
            "model": name,
            "seconds": seconds[name],
            "ns_per_cell": 1e9 * seconds[name] / cells[name],
            "ns_per_ray": 1e9 * seconds[name] / rays_done[name],
            "n_rays": rays_done[name],
            "n_cells": cells[name],
        }
        for name in timed
    )
    scene = (
        f"{disparity.size} rays (every {stride}. pixel of a {width}x{height} frame, f = {focal_px:g} px, "
        f"f*b = {setup.focal_baseline:.2f} px*m, doffs = {setup.doffs_px:g} px) on {n_bands} planes at "
        f"{', '.join(f'{z:.2f}' for z in band_depth)} m; cells of {setup.voxel_size_m:g} m along each ray from "
        f"{setup.near_m:g} m to the largest influence depth; p0 = {setup.p0:g}"
    )
    return PerformanceTable(rows, scene, table_build_s, int(np.unique(disparity).size))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--camera", choices=sorted(CAMERAS), default="middlebury-motorcycle")
    parser.add_argument("--stride", type=int, default=1, help="every N-th pixel of the 640x480 frame (default 1)")
    args = parser.parse_args()
    rig = CAMERAS[args.camera]
    setup = RaySetup(focal_baseline=rig["focal_px"] * rig["baseline_m"], doffs_px=rig["doffs_px"])
    table = time_models(MIXTURE, setup=setup, focal_px=rig["focal_px"], stride=args.stride)
    print(
        f"camera {args.camera}; error mixture w={MIXTURE.weights.tolist()} mu={MIXTURE.means.tolist()} "
        f"sigma={MIXTURE.sigmas.tolist()} px"
    )
    print(table.to_markdown())
    peer = next(row for row in table.rows if row["model"] == "hitmiss")
    for row in table.rows:
        print(
            f"{row['model']:>15}: {row['ns_per_cell']:10.1f} ns/cell  {row['ns_per_cell'] / peer['ns_per_cell']:9.1f}x hitmiss"
        )


if __name__ == "__main__":
    main()
