"""Nanoseconds per cell of every inverse sensor model on one batch of rays, side by side in one process.

Scene: a pinhole camera (f = 615 px, 640x480 principal point at the centre, baseline 0.10 m: New Tsukuba)
looking at a smooth synthetic depth field between 1 and 10 m; disparities rounded to OpenCV's 1/16 px.
Each ray gets cells of 0.1 m along the ray from 0.5 m to 0.5 m past its measured depth (what a grid
casting to the influence depth of the ideal model sees), each ending exactly where the next one starts
(as the grid's ray casting emits them). PRISM uses a two-component error mixture.

    .venv/bin/python benchmarks/bench_sensor_models.py            # 320x240 rays (~4 M cells)
    .venv/bin/python benchmarks/bench_sensor_models.py --full     # 640x480 rays (~17 M cells, ~1 GB)
    .venv/bin/python benchmarks/bench_sensor_models.py --street   # the street's own ray-mode calls (below)

Large batches spill the cell arrays out of the caches, which slows the ideal model most (it only
compares): the ratio is also printed for one call of the size the grid makes (~4096 rays). Then a
40-frame sequence (160x120 rays per frame, the depth field moving by 0.15 rad per frame): PRISM's
total time with a fresh model (tables built as new disparities appear) against the same frames again
(warm), and the ideal model's, to show what share of a sequence table building takes.

``--street``: the first 4 model calls in ray mode (4096 rays each, the cells the ray integrator casts to the
influence depth) and the one call in projective mode of one frame of bench_grid.py's street scene (c) at
0.2 m voxels, PRISM with the street mixture (tables warm; with the frame's voxel overhangs, the default, and
without) against the ideal model on the same calls, CPU time (best of 3).
"""

import argparse
import os
import time

import numpy as np

from prismap.camera import integrate_disparity
from prismap.gmm import GaussianMixture
from prismap.grid import OccupancyMap
from prismap.sensor_models import make_sensor_model
from prismap.sensor_models._table_store import STORE_ENV

FOCAL, BASELINE, WIDTH, HEIGHT = 615.0, 0.10, 640, 480
FB = FOCAL * BASELINE
MIXTURE = GaussianMixture([0.85, 0.15], [0.05, -0.3], [0.4, 2.5])


def scene(step, phase=0.0):
    """Rays of every ``step``-th pixel: disparity, ray norm, and 0.1 m cells along each ray.

    ``phase`` (radians) moves the depth field: the frames of the synthetic sequence.
    """
    v, u = np.mgrid[0:HEIGHT:step, 0:WIDTH:step].astype(np.float64)
    x, y = (u - WIDTH / 2) / FOCAL, (v - HEIGHT / 2) / FOCAL
    depth = 5.5 + 4.5 * np.sin(4 * x + 8 * y * y + phase)  # 1..10 m
    disparity = np.round(FB / depth * 16).ravel() / 16
    ray_norm = np.sqrt(1 + x * x + y * y).ravel()
    z_hat = FB / disparity
    step_depth = 0.1 / ray_norm
    counts = np.ceil((z_hat + 0.5 - 0.5) / step_depth).astype(np.int64)
    rays = np.repeat(np.arange(disparity.size), counts)
    first = np.concatenate(([0], np.cumsum(counts)[:-1]))
    index = np.arange(rays.size) - first[rays]
    start = 0.5 + index * step_depth[rays]
    end = np.append(start[1:], 0.0)
    last = np.append(rays[1:] != rays[:-1], True)
    end[last] = start[last] + step_depth[rays[last]]  # each cell ends exactly where the next starts
    return disparity, ray_norm, rays, start, end


def time_call(model, batch, repeat=1, **kwargs):
    """Best wall time of ``repeat`` calls (seconds): the machine may be shared."""
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        model.cell_posteriors(*batch, **kwargs)
        best = min(best, time.perf_counter() - t0)
    return best


def table_stages(prism, batch, repeat=5):
    """Nanoseconds per cell of each stage of tabulated PRISM's cell update on ``batch`` (tables warm): the two
    table look-ups per cell (``_kernels_lookup.prism_table_lookup``), the two vectorised exps, the combination and
    the vectorised log, each run alone over the whole batch in blocks as ``prism_table_cells`` runs them."""
    from prismap.sensor_models import _kernel_args, _kernels_lookup, _kernels_math, _prism

    disparity, norm, rays, start, end = (np.ascontiguousarray(a) for a in batch)
    n = start.size
    tables = prism._tables_for(disparity, norm)
    cells = _kernel_args.Cells(rays, start, end)
    geometry, mixture = prism._geometry(), prism._mixture()
    lam = prism.rate_per_m * norm
    stretch = np.zeros(norm.size)
    l_a, l_c, e_a, e_c, lam_len, ratio, fix_value, inc = (np.empty(n) for _ in range(8))
    post = np.empty(n)
    side = np.empty(n, dtype=np.int8)
    fix_index = np.empty(n, dtype=np.int64)
    block = _prism._CHUNK_CELLS
    blocks = [(lo, min(lo + block, n)) for lo in range(0, n, block)]

    def lookup():
        for lo, hi in blocks:
            _kernels_lookup.prism_table_lookup(
                lam,
                stretch,
                tables,
                cells,
                lo,
                hi,
                _prism._QUAD_STEP,
                geometry,
                mixture,
                np.empty(0),  # no failure floor: the model's cells without a blend
                l_a[lo:hi],
                l_c[lo:hi],
                side[lo:hi],
                lam_len[lo:hi],
            )

    def exps():
        for lo, hi in blocks:
            _kernels_math.exp_into(l_a[lo:hi], e_a[lo:hi], hi - lo)
            _kernels_math.exp_into(l_c[lo:hi], e_c[lo:hi], hi - lo)

    def combination():
        for lo, hi in blocks:
            _kernels_lookup.prism_table_combine(
                lo,
                hi,
                l_a[lo:hi],
                l_c[lo:hi],
                e_a[lo:hi],
                e_c[lo:hi],
                side[lo:hi],
                lam_len[lo:hi],
                post,
                ratio[lo:hi],
                fix_index,
                fix_value,
                prism.pass_through,
            )

    def logs():
        for lo, hi in blocks:
            _kernels_math.log_into(ratio[lo:hi], inc[lo:hi], hi - lo)

    out = {}
    for name, stage in (("look-ups", lookup), ("exps", exps), ("combination", combination), ("log", logs)):
        best = np.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            stage()
            best = min(best, time.perf_counter() - t0)
        out[name] = best / n * 1e9
    return out


def sequence(frames, step):
    """Seconds for ``frames`` frames: fresh PRISM, the same PRISM again (warm), ideal; and the PRISM model."""
    common = {"focal_baseline": FB, "voxel_size_m": 0.1, "p0": 0.05}
    batches = [scene(step, 0.15 * k) for k in range(frames)]
    prism = make_sensor_model("prism", error_model=MIXTURE, **common)
    ideal = make_sensor_model("ideal", **common)
    cold = sum(time_call(prism, batch) for batch in batches)
    warm = sum(time_call(prism, batch) for batch in batches)
    base = sum(time_call(ideal, batch) for batch in batches)
    return cold, warm, base, prism


def street_calls(scale, mode, n_calls=4):
    """The first ``n_calls`` model calls of integrating one frame of bench_grid's street scene (c) at 0.2 m in
    ``mode`` (PRISM with the street mixture): (PRISM model, list of ``cell_posteriors`` (arguments, keywords)),
    the keywords holding each ray's ``voxel_overhang_m``."""
    import bench_grid

    camera, poses, disparities = bench_grid.street_frames(scale, 1)
    model = bench_grid.street_model("prism", camera, 0.2)
    calls = []

    class Recorder(bench_grid.TimedModel):
        def cell_posteriors(self, *args, **kwargs):
            if len(calls) < n_calls:
                calls.append((tuple(np.array(a) for a in args), {k: np.array(v) for k, v in kwargs.items()}))
            return self.model.cell_posteriors(*args, **kwargs)

    integrate_disparity(
        OccupancyMap(0.2, p0=model.p0),
        disparities[0],
        camera,
        poses[0],
        Recorder(model),
        mode=mode,
        max_range_m=bench_grid.STREET_RANGE_M[1],
    )
    return model, calls


def street(scale):
    """CPU nanoseconds per cell of PRISM (warm tables; with and without the voxel overhang) and the ideal model
    on the street's own model calls, in ray mode and in projective mode."""
    for mode in ("ray", "projective"):
        prism, calls = street_calls(scale, mode)
        ideal = make_sensor_model(
            "ideal",
            focal_baseline=prism.focal_baseline,
            doffs_px=prism.doffs_px,
            voxel_size_m=prism.voxel_size_m,
            p0=prism.p0,
        )
        n_cells = sum(args[2].size for args, _ in calls)
        results = {}
        for name, model, overhang in (
            ("ideal", ideal, False),
            ("PRISM", prism, True),
            ("PRISM without overhang", prism, False),
        ):
            jobs = [(args, kwargs if overhang else {}) for args, kwargs in calls]
            for args, kwargs in jobs:
                model.cell_posteriors(*args, **kwargs)
            best = np.inf
            for _ in range(3):
                t0 = time.process_time()
                for args, kwargs in jobs:
                    model.cell_posteriors(*args, **kwargs)
                best = min(best, time.process_time() - t0)
            results[name] = best / n_cells * 1e9
        print(
            f"street scene (c) at scale {scale:g}, 0.2 m voxels, {mode}: {len(calls)} model call(s) of "
            f"{calls[0][0][0].size} rays, {n_cells} cells; CPU ns per cell: ideal {results['ideal']:.1f}, PRISM "
            f"{results['PRISM']:.1f} (ratio {results['PRISM'] / results['ideal']:.2f}), PRISM without the voxel "
            f"overhang {results['PRISM without overhang']:.1f}"
        )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="all 640x480 rays instead of 320x240")
    parser.add_argument("--direct-rays", type=int, default=300, help="rays for the slow direct PRISM")
    parser.add_argument("--frames", type=int, default=40, help="frames of the synthetic sequence (0: skip)")
    parser.add_argument(
        "--street",
        action="store_true",
        help="only the street's ray-mode calls (bench_grid scene (c), KITTI rig, street mixture)",
    )
    parser.add_argument("--scale", type=float, default=1.0, help="--street: kitti_camera scale")
    args = parser.parse_args()
    os.environ.setdefault(STORE_ENV, "off")  # timings of tables built in this process, not read from disk
    if args.street:
        street(args.scale)
        return
    batch = scene(1 if args.full else 2)
    n_cells = batch[2].size
    print(
        f"scene: {batch[0].size} rays ({'640x480' if args.full else '320x240'} of a 640x480 frame), "
        f"depth {FB / batch[0].max():.2f}-{FB / batch[0].min():.2f} m, {n_cells} cells of 0.1 m, "
        f"{np.unique(batch[0]).size} distinct disparities, |r| up to {batch[1].max():.3f}"
    )
    common = {"focal_baseline": FB, "voxel_size_m": 0.1, "p0": 0.05}
    small = scene(16)
    results = {}
    for name in ("ideal", "hitmiss", "convolution", "andert"):
        model = make_sensor_model(name, **common)
        model.cell_posteriors(*small)  # compile / load the numba cache
        results[name] = time_call(model, batch, repeat=3) / n_cells * 1e9
    prism = make_sensor_model("prism", error_model=MIXTURE, **common)
    make_sensor_model("prism", error_model=MIXTURE, **common).cell_posteriors(*small)  # compile, other cache
    t_cold = time_call(prism, batch)
    results["prism table (cold: builds tables)"] = t_cold / n_cells * 1e9
    results["prism table (warm)"] = time_call(prism, batch, repeat=3) / n_cells * 1e9
    pick = np.random.default_rng(0).choice(batch[0].size, size=min(args.direct_rays, batch[0].size), replace=False)
    keep = np.isin(batch[2], pick)
    remap = np.full(batch[0].size, -1)
    remap[pick] = np.arange(pick.size)
    sub = (batch[0][pick], batch[1][pick], remap[batch[2][keep]], batch[3][keep], batch[4][keep])
    prism.cell_posteriors(*small, method="direct")
    results[f"prism direct ({pick.size} rays)"] = time_call(prism, sub, method="direct") / keep.sum() * 1e9
    print(f"{'model':40s} {'ns/cell':>10s} {'x ideal':>9s}")
    for name, ns in results.items():
        print(f"{name:40s} {ns:10.1f} {ns / results['ideal']:9.2f}")
    print(
        f"PRISM tables cached: {len(prism._cache)} ({prism._cache.nbytes / 2**20:.1f} MB); "
        f"ratio tabulated PRISM (warm) / ideal = "
        f"{results['prism table (warm)'] / results['ideal']:.2f} (goal <= 1.5)"
    )
    chunk = scene(8)  # 80x60 rays: about the grid's RAYS_PER_CHUNK (4096) per model call
    ideal = make_sensor_model("ideal", **common)
    ns_ideal = time_call(ideal, chunk, repeat=5) / chunk[2].size * 1e9
    ns_prism = time_call(prism, chunk, repeat=5) / chunk[2].size * 1e9
    print(
        f"one grid-sized call ({chunk[0].size} rays, {chunk[2].size} cells, arrays in cache): ideal "
        f"{ns_ideal:.1f} ns/cell, prism table (warm) {ns_prism:.1f} ns/cell, ratio {ns_prism / ns_ideal:.2f}"
    )
    stage_ns = table_stages(prism, chunk)
    print(
        "  its stages (ns/cell, best of 5): "
        + ", ".join(f"{name} {ns:.1f}" for name, ns in stage_ns.items())
        + f"; the look-up stage alone (no exp, combination or log) is {stage_ns['look-ups'] / ns_ideal:.1f}x the "
        "ideal model: the floor of a tabulated PRISM that interpolates two table rows per cell"
    )
    if args.frames:
        cold, warm, base, model = sequence(args.frames, 4)
        print(
            f"sequence of {args.frames} frames (160x120 rays each): PRISM fresh {cold:.2f} s, again (warm) "
            f"{warm:.2f} s, ideal {base:.2f} s; table building {(cold - warm) / cold:.0%} of the fresh run, "
            f"{len(model._cache)} tables ({model._cache.nbytes / 2**20:.1f} MB)"
        )


if __name__ == "__main__":
    main()
