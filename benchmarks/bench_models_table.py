"""Thesis table 6.1: nanoseconds per cell and per ray of every sensor model, PRISM direct and tabulated.

All models run in one process on the same batch (``prismap.study.time_models``): the rays of a 640x480
frame (f of the chosen rig, principal point at the centre) seeing 8 fronto-parallel planes at 1-20 m,
disparities rounded to 1/16 px, cells of 0.1 m along each ray up to the largest influence depth, in chunks
of 8192 rays; direct PRISM on 16 seeded random rays of the frame. Ratios are against OctoMap's hit/miss model.
The error model is close to SGBM on Middlebury Motorcycle.

    .venv/bin/python benchmarks/bench_models_table.py                  # full frame, Motorcycle rig
    .venv/bin/python benchmarks/bench_models_table.py --stride 2 --camera tsukuba
"""

import argparse

from prismap.gmm import GaussianMixture
from prismap.study import CAMERAS, RaySetup, time_models

MIXTURE = GaussianMixture([0.84, 0.10, 0.06], [0.01, -0.04, -10.4], [0.24, 0.92, 13.6])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--camera", choices=sorted(CAMERAS), default="middlebury-motorcycle")
    parser.add_argument("--stride", type=int, default=1, help="every N-th pixel of the 640x480 frame (default 1)")
    args = parser.parse_args()
    rig = CAMERAS[args.camera]
    setup = RaySetup(focal_baseline=rig["focal_px"] * rig["baseline_m"], doffs_px=rig["doffs_px"])
    table = time_models(MIXTURE, setup=setup, focal_px=rig["focal_px"], stride=args.stride)
    print(f"camera {args.camera}; error mixture w={MIXTURE.weights.tolist()} mu={MIXTURE.means.tolist()} "
          f"sigma={MIXTURE.sigmas.tolist()} px")
    print(table.to_markdown())
    peer = next(row for row in table.rows if row["model"] == "hitmiss")
    for row in table.rows:
        print(f"{row['model']:>15}: {row['ns_per_cell']:10.1f} ns/cell  {row['ns_per_cell'] / peer['ns_per_cell']:9.1f}x hitmiss")


if __name__ == "__main__":
    main()
