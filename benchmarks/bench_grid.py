"""OctoMap's insertPointCloud versus prismap's map, side by side in one process (ANCHORS.md).

Scenes: (a) a 640x480 depth frame of planes at 1-10 m (tests/support.planes_frame), 0.1 m voxels, its
disparities perturbed by :data:`STREET_MIXTURE` (seed 0); (b) 100k random points at 2-20 m in a 90x60 degree
frustum (seed 0), 0.1 m voxels. Same points, resolution and max range for both. Prints wall seconds (median
of --repeat runs) with the throughput ratio, CPU seconds (process time, both threads; steadier than wall time
on a shared machine), the time spent inside the sensor model's own calls (hit/miss in ray mode is added while
casting: no model calls), and bytes per known voxel. The first of the --repeat runs of PRISM builds its
tables (cold); the median is a warm run.

Scene (c), the street (``--street``): ``sim.street_scene(seed=0)`` seen by ``sim.kitti_camera(scale=--scale)``
(1242x375, f 720 px, b 0.54 m at scale 1) along ``sim.street_trajectory(--frames)``, exact depths kept
within 2-80 m (sky and farther pixels invalid), disparities perturbed by :data:`STREET_MIXTURE` with fresh
seeded errors every frame and rounded to OpenCV's 1/16 px, rays cut at 80 m, at 0.2 and 0.1 m voxels. Each
method maps the whole sequence into one map in a fresh process (so the first frame is truly cold: imports,
numba caches, PRISM's first tables), the processes interleaved and repeated --repeat times; the table gives
medians over the repeats of the first frame and of the median steady frame (frames 2..N), wall and CPU, their
ratios to OctoMap's, the process's peak RSS over the sequence above its RSS before it (the peak reset after the
world is loaded), the map's own bytes, for the models with calls the cells they evaluate in a steady frame and their
CPU per cell (the calling threads' CPU: the floor of ray mode, which evaluates every cell of every ray), and for PRISM
the table cache's size and hit rate (distinct keys found / looked up per call). PRISM's rows start with an empty table
store on disk (a rig's first run: every table built, and written); the rows "tables stored" with the store an untimed
run of the same method filled (the rig's later runs: tables read, not built).
Run: .venv/bin/python benchmarks/bench_grid.py [--repeat 3] [--street [--scale 1.0] [--frames 10] [--voxels 0.2 0.1]
[--methods OctoMap PRISM]]
"""

import argparse
import functools
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import dufomap
import octomap

from prismap import sim
from prismap._memory import _meminfo_bytes
from prismap.camera import StereoCamera, integrate_disparity
from prismap.characterise import characterise_matcher, write_error_model
from prismap.gmm import GaussianMixture
from prismap.grid import OccupancyMap
from prismap.pipeline import MappingConfig
from prismap.sensor_models import ConditionedModel, make_sensor_model
from prismap.sensor_models._table_store import STORE_ENV, table_store
from prismap.stereo import make_matcher
from support import planes_frame, world_points

os.environ.setdefault(STORE_ENV, "off")  # PRISM's tables built in this process; scene (c) sets a store per process
VOXEL = 0.1
STORED = ", tables stored"
STREET_MIXTURE = GaussianMixture(np.array([0.80, 0.15, 0.05]), np.array([0.0, -0.1, -2.0]), np.array([0.3, 1.0, 10.0]))
"""Disparity error of scenes (a) and (c): a 0.3 px core, a 1 px shoulder and 5 % outliers of sigma 10 px."""
STREET_RANGE_M = (2.0, 80.0)
STREET_NEAR_M = 1.5  # PRISM's near_m on the street (no surface nearer than 1.8 m to the drive)
STREET_METHODS = {  # label: (model name, mode; UFOMap's: threads)
    "OctoMap insertPointCloud": ("octomap", None),
    "UFOMap run, 1 thread": ("ufomap", "1"),
    "UFOMap run, 2 threads": ("ufomap", "2"),
    "hit/miss, ray": ("hitmiss", "ray"),
    "hit/miss, projective": ("hitmiss", "projective"),
    "Andert, projective": ("andert", "projective"),
    "PRISM, ray": ("prism", "ray"),
    "PRISM, projective": ("prism", "projective"),
    "PRISM conditioned, ray": ("conditioned", "ray"),
    "PRISM conditioned, projective": ("conditioned", "projective"),
    "PRISM conditioned, ray" + STORED: ("conditioned", "ray"),
    "PRISM conditioned, projective" + STORED: ("conditioned", "projective"),
}
"""PRISM's rows without :data:`STORED` start with an empty table store (``PRISMAP_TABLE_CACHE``, a new directory
each process: a rig's first run, which builds every table and writes it); those with it, with the store that an
untimed run of the same method filled (the runs after it)."""
CHARACTERISE_FRAMES = 4
"""Scene (c) with ``--conditioned``: SGBM is characterised on this many of the world's first frames."""


def hitmiss(camera):
    return make_sensor_model(
        "hitmiss", focal_baseline=camera.focal_baseline, doffs_px=camera.doffs_px, voxel_size_m=VOXEL, p0=0.5
    )


def timed(fn, repeat):
    """Median wall and CPU seconds of ``fn()`` over ``repeat`` runs, and its last result."""
    wall, cpu = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = fn()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return statistics.median(wall), statistics.median(cpu), result


class TimedModel:
    """Wraps a sensor model and adds up the wall time of its ``cell_posteriors``, ``influence_depth`` and
    ``influence_and_floor_depths`` (``seconds``), and of ``cell_posteriors`` the cells (``cells``) and the calling
    threads' CPU (``cpu``; the integrators call it from several threads at once)."""

    def __init__(self, model):
        self.model, self.seconds, self.cells, self.cpu = model, 0.0, 0, 0.0
        self._lock = threading.Lock()

    def __getattr__(self, name):
        attribute = getattr(self.model, name)  # AttributeError where the model has none: the grid's getattr sees it
        if name == "influence_and_floor_depths":
            return functools.partial(self._timed, attribute)
        return attribute

    def _timed(self, method, *args, cells=0, **kwargs):
        start, start_cpu = time.perf_counter(), time.thread_time()
        try:
            return method(*args, **kwargs)
        finally:
            wall, cpu = time.perf_counter() - start, time.thread_time() - start_cpu
            with self._lock:
                self.seconds += wall
                if cells:
                    self.cells += cells
                    self.cpu += cpu

    def cell_posteriors(self, disparity_px, ray_norm, ray_of_cell, *args, **kwargs):
        return self._timed(
            self.model.cell_posteriors, disparity_px, ray_norm, ray_of_cell, *args, cells=len(ray_of_cell), **kwargs
        )

    def influence_depth(self, *args, **kwargs):
        return self._timed(self.model.influence_depth, *args, **kwargs)

    def with_extra_noise(self, sigma_px):
        return TimedModel(self.model.with_extra_noise(sigma_px))


def measured_disparity(true_disparity, rng):
    """``true - e`` with ``e`` drawn from :data:`STREET_MIXTURE`, rounded to 1/16 px; NaN stays, <= 0 becomes NaN."""
    valid = np.isfinite(true_disparity)
    measured = np.full(true_disparity.shape, np.nan)
    noisy = true_disparity[valid] - STREET_MIXTURE.sample(int(valid.sum()), rng)
    measured[valid] = np.where(noisy > 0, np.rint(noisy * 16.0) / 16.0, np.nan)
    return measured


def mixture_text():
    m = STREET_MIXTURE
    return " + ".join(f"{w:.2f} N({mu:g}, {sd:g} px)" for w, mu, sd in zip(m.weights, m.means, m.sigmas))


def _load():
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def street_frames(scale, n_frames):
    """Camera, poses and measured disparity images (NaN = invalid) of scene (c)."""
    camera = sim.kitti_camera(scale=scale)
    scene = sim.street_scene(seed=0)
    poses = sim.street_trajectory(n_frames, seed=0)
    near, far = STREET_RANGE_M
    disparities = []
    for k, pose in enumerate(poses):
        depth = scene.cast(camera, pose)
        true = np.where((depth >= near) & (depth <= far), camera.focal_baseline / depth - camera.doffs_px, np.nan)
        disparities.append(measured_disparity(true, np.random.default_rng(k)))
    return camera, poses, disparities


def sgbm_world(scale, n_frames, directory):
    """Scene (c) from images, as ``prismap map`` sees it: write ``world.npz`` and ``error_model.json`` to ``directory``.

    The street's stereo pairs (``scene.frames(seed=0)``), SGBM's disparities (``make_matcher("sgbm")``, its
    defaults), the error model characterised on the first :data:`CHARACTERISE_FRAMES` frames (conditioned, the
    class count ``characterise_matcher`` picks) and each pixel's class (``ErrorModel.classify_frame``, as
    ``pipeline.DisparitySource`` computes it). Skipped when both files exist (``--world-dir`` reuses them). The error
    model is also written pickled (``error_model.pkl``), which the method processes load: its JSON form holds what
    ``load_error_model`` checks against the matcher's range, and a characterisation may fit components beyond it.
    """
    directory = Path(directory)
    world, model_path = directory / "world.npz", directory / "error_model.pkl"
    if world.is_file() and model_path.is_file():
        return world
    directory.mkdir(parents=True, exist_ok=True)
    camera = sim.kitti_camera(scale=scale)
    poses = sim.street_trajectory(n_frames, seed=0)
    frames = list(sim.street_scene(seed=0).frames(camera, poses, seed=0))
    matcher = make_matcher("sgbm")
    start = time.perf_counter()
    error_model = characterise_matcher(frames[:CHARACTERISE_FRAMES], matcher, progress=False).model
    print(
        f"  characterised SGBM on {min(CHARACTERISE_FRAMES, n_frames)} frames in {time.perf_counter() - start:.0f} s: "
        f"{error_model.n_classes} classes",
        flush=True,
    )
    disparities, classes = [], []
    for frame in frames:
        disparity, lr_disagreement = matcher.compute_with_confidence(frame.left, frame.right)
        disparities.append(disparity.astype(np.float32))
        classes.append(error_model.classify_frame(frame.left, frame.right, disparity, lr_disagreement).astype(np.int16))
    write_error_model(error_model, directory / "error_model.json")
    model_path.write_bytes(pickle.dumps(error_model))
    np.savez(world, poses=poses, disparities=np.stack(disparities), classes=np.stack(classes))
    return world


def load_world(scale, n_frames, world):
    """Camera, poses, disparities (NaN = invalid), classes and error model of scene (c): measured (``world``, from
    :func:`sgbm_world`) or synthetic (``world`` None: :func:`street_frames`, no classes, :data:`STREET_MIXTURE`)."""
    if world is None:
        camera, poses, disparities = street_frames(scale, n_frames)
        return camera, poses, disparities, [None] * len(poses), STREET_MIXTURE
    data = np.load(world)
    error_model = pickle.loads(Path(world).with_name("error_model.pkl").read_bytes())
    return (
        sim.kitti_camera(scale=scale),
        data["poses"],
        list(data["disparities"].astype(np.float64)),
        list(data["classes"].astype(np.int32)),
        error_model,
    )


def street_model(name, camera, voxel, error_model):
    """The sensor model ``name`` of scene (c). Synthetic: p0 0.05, PRISM's near_m :data:`STREET_NEAR_M`. Measured
    (an ErrorModel): what ``prismap map --model prism --error-model M`` builds (``MappingConfig.sensor_model``,
    defaults), plain (the whole-image mixture) or conditioned."""
    if not isinstance(error_model, GaussianMixture):
        model = "prism" if name == "conditioned" else name
        config = MappingConfig(
            model=model, voxel_size_m=voxel, error_model=error_model, conditioned=name == "conditioned"
        )
        return config.sensor_model(camera)
    common = {"focal_baseline": camera.focal_baseline, "doffs_px": camera.doffs_px, "voxel_size_m": voxel}
    if name == "hitmiss":
        return make_sensor_model("hitmiss", p0=0.5, **common)
    if name == "andert":
        return make_sensor_model("andert", sigma_px=float(error_model.sigmas[0]), **common)
    return make_sensor_model("prism", p0=0.05, error_model=error_model, near_m=STREET_NEAR_M, **common)


def cloud(camera, pose, disparity):
    """World points (N, 3) of a disparity image's valid pixels."""
    valid = np.isfinite(disparity)
    depth = np.where(valid, camera.focal_baseline / (disparity + camera.doffs_px), np.nan)
    return world_points(camera, pose, depth)[valid.ravel()]


def street_method(name, mode, voxel, scale, n_frames, world=None):
    """Map scene (c) with one method in this (fresh) process; per-frame wall and CPU seconds and memory."""
    camera, poses, disparities, classes, error_model = load_world(scale, n_frames, world)
    max_range = STREET_RANGE_M[1]
    rss_before = _reset_peak_rss()
    wall, cpu, out = [], [], {}

    def clock(insert, inputs):
        for item in inputs:
            start, start_cpu = time.perf_counter(), time.process_time()
            insert(*item)
            wall.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)

    if name in ("octomap", "ufomap"):  # the clouds are computed before the clock starts
        clouds = [(cloud(camera, pose, disparity), pose) for disparity, pose in zip(disparities, poses)]
    if name == "octomap":
        tree = octomap.OcTree(voxel)
        clock(
            lambda points, pose: tree.insertPointCloud(points, np.ascontiguousarray(pose[:3, 3]), maxrange=max_range),
            clouds,
        )
        out["map_bytes"] = tree.memoryUsage()
    elif name == "ufomap":
        # UFOMap through DUFOMap's binding: free space to and a hit at each world point within the max range
        # (it has no max range; OctoMap also casts free space along the farther points' rays), no hit or unknown
        # inflation (d_s 0, d_p 0): the plain occupancy insert.
        ufo = dufomap.dufomap(voxel, 0.0, 0, num_threads=int(mode))
        clouds = [
            (points[np.linalg.norm(points - pose[:3, 3], axis=1) <= max_range].astype(np.float32), pose)
            for points, pose in clouds
        ]
        clock(lambda points, pose: ufo.run(points, pose, cloud_transform=False), clouds)
        out["map_bytes"] = 0
    else:
        model = street_model(name, camera, voxel, error_model)
        grid = OccupancyMap(voxel, p0=getattr(model, "plain", model).p0)
        if not isinstance(model, ConditionedModel):
            classes = [None] * len(poses)
        timer, model_frames = TimedModel(model), []

        def insert(disparity, pose, ray_class):
            integrate_disparity(
                grid, disparity, camera, pose, timer, mode=mode, max_range_m=max_range, ray_class=ray_class
            )
            model_frames.append((timer.cells, timer.cpu))

        clock(insert, zip(disparities, poses, classes))
        out["map_bytes"] = grid.nbytes()
        if len(model_frames) > 1 and model_frames[-1][0] > model_frames[0][0]:  # frames 2-N (hit/miss: no calls)
            cells, model_cpu = (end - first for end, first in zip(model_frames[-1], model_frames[0]))
            out.update(model_cells=cells / (len(model_frames) - 1), model_ns=model_cpu / cells * 1e9)
        subs = getattr(model, "class_models", ()) + (getattr(model, "plain", model),)
        caches = list({id(m._cache): m._cache for m in subs if hasattr(m, "_cache")}.values())  # a shared one once
        if caches:
            store = table_store()
            out.update(
                tables=sum(len(c) for c in caches),
                table_bytes=sum(c.nbytes for c in caches),
                table_hits=sum(c.hits for c in caches),
                table_builds=sum(c.builds for c in caches) - (store.found if store else 0),
                table_reads=store.found if store else 0,
            )
    out.update(wall=wall, cpu=cpu, rss_rise=_meminfo_bytes("VmHWM", "/proc/self/status") - rss_before)
    return out


def _reset_peak_rss():
    """This process's resident bytes, with its peak reset to them (Linux's ``clear_refs``), so that the peak read
    after mapping is the mapping's own and not loading the world's (which can be higher: a rise of 0 then)."""
    with open("/proc/self/clear_refs", "w") as clear:
        clear.write("5")
    return _meminfo_bytes("VmRSS", "/proc/self/status")


def street(args):
    """Scene (c): every method in its own process, interleaved, --repeat times, on each rig (--scales) and voxel
    size; a table of medians per set-up, then the worst ratio of each method over the set-ups."""
    methods = {
        label: STREET_METHODS[label]
        for label in STREET_METHODS
        if (args.conditioned or "conditioned" not in label)
        and (args.methods is None or any(word.lower() in label.lower() for word in args.methods))
    }
    worst = {}
    with tempfile.TemporaryDirectory() as tmp:
        for scale in args.scales:
            camera = sim.kitti_camera(scale=scale)
            world, errors = None, mixture_text()
            if args.conditioned:
                world = sgbm_world(scale, args.frames, Path(args.world_dir or tmp) / f"street_{scale:g}_{args.frames}")
                error_model = pickle.loads(world.with_name("error_model.pkl").read_bytes())
                errors = f"SGBM (its defaults) characterised on {CHARACTERISE_FRAMES} frames, {error_model.n_classes} classes"
            for voxel in args.voxels:
                print(
                    f"\nscene (c): street, {camera.width}x{camera.height} px (f {camera.focal_px:g} px, b "
                    f"{camera.baseline_m:g} m), {args.frames} frames, depths {STREET_RANGE_M[0]:g}-{STREET_RANGE_M[1]:g} m, "
                    f"{voxel} m voxels, rays cut at {STREET_RANGE_M[1]:g} m, errors {errors}; load {_load()}",
                    flush=True,
                )
                runs = {label: [] for label in methods}
                stores = Path(tmp) / f"tables_{scale:g}_{voxel:g}"
                for repeat in range(args.repeat + 1):  # the first round fills the stores of the STORED rows only
                    for index, (label, (name, mode)) in enumerate(methods.items()):
                        if repeat == 0 and not label.endswith(STORED):
                            continue
                        store = stores / (str(index) if label.endswith(STORED) else f"{index}-{repeat}")
                        command = [
                            sys.executable,
                            __file__,
                            "--street-method",
                            name,
                            str(mode),
                            str(voxel),
                            str(scale),
                            str(args.frames),
                            str(world or ""),
                        ]
                        environment = {**os.environ, STORE_ENV: str(store)}
                        done = subprocess.run(command, check=True, capture_output=True, text=True, env=environment)
                        if repeat > 0:
                            runs[label].append(json.loads(done.stdout.splitlines()[-1]))
                _street_table(runs, worst)
                print(f"load {_load()}")
    print(
        f"\nworst over rigs {args.scales} and voxels {args.voxels} (steady state): x Octo lowest; x UFO lowest; "
        "conditioned / plain PRISM of the same mode: time and peak RSS rise highest"
    )
    for label, figures in worst.items():
        print(f"{label:<44} " + "  ".join(f"{key} {value:.2f}" for key, value in figures.items()))


def _street_table(runs, worst):
    """Print one set-up's table and fold its ratios into ``worst`` (label: {figure: worst value so far})."""
    summary = {label: _street_summary(results) for label, results in runs.items()}
    octo = summary.get("OctoMap insertPointCloud") or next(iter(summary.values()))
    ufo = min(
        (row for label, row in summary.items() if label.startswith("UFOMap")),
        key=lambda row: row["steady"],
        default=None,
    )
    print(
        f"{'method':<44} {'cold s':>7} {'CPU':>6} {'steady s':>8} {'CPU':>6} {'x Octo':>6} {'x CPU':>6} {'x UFO':>6} "
        f"{'cold/st':>7} {'RSS MB':>7} {'map MB':>7}  model calls and tables"
    )
    for label, row in summary.items():
        last = runs[label][-1]
        tables = ""
        if "model_cells" in last:
            tables = f"{last['model_cells'] / 1e6:.1f} M cells a frame, {last['model_ns']:.0f} ns a cell; "
        if "tables" in last:
            hit_rate = last["table_hits"] / max(last["table_hits"] + last["table_builds"] + last["table_reads"], 1)
            tables += (
                f"{last['tables']} tables, {last['table_bytes'] / 2**20:.1f} MB, {last['table_builds']} built, "
                f"{last['table_reads']} read from the store, hit rate {hit_rate:.3f}"
            )
        figures = {"x Octo": octo["steady"] / row["steady"]}
        if ufo is not None:
            figures["x UFO"] = ufo["steady"] / row["steady"]
        plain = summary.get(label.replace(" conditioned", "").replace(STORED, ""))
        if plain is not None and plain is not row:
            figures["time / plain"] = row["steady"] / plain["steady"]
            figures["RSS / plain"] = row["rss"] / max(plain["rss"], 1)
        for key, value in figures.items():
            kept = worst.setdefault(label, {}).get(key, value)
            worst[label][key] = max(kept, value) if "plain" in key else min(kept, value)
        print(
            f"{label:<44} {row['cold']:7.2f} {row['cold_cpu']:6.2f} {row['steady']:8.3f} {row['steady_cpu']:6.3f} "
            f"{figures['x Octo']:6.2f} {octo['steady_cpu'] / row['steady_cpu']:6.2f} {figures.get('x UFO', np.nan):6.2f} "
            f"{row['cold'] / row['steady']:7.2f} {row['rss'] / 2**20:7.0f} {row['map'] / 2**20:7.1f}  {tables}",
            flush=True,
        )


def _street_summary(results):
    """Medians over repeats of the first frame, of each run's median steady frame, and of the memory figures."""
    median = statistics.median
    return {
        "cold": median(r["wall"][0] for r in results),
        "cold_cpu": median(r["cpu"][0] for r in results),
        "steady": median(median(r["wall"][1:]) for r in results),
        "steady_cpu": median(median(r["cpu"][1:]) for r in results),
        "rss": median(r["rss_rise"] for r in results),
        "map": median(r["map_bytes"] for r in results),
    }


def octomap_known_voxels(tree):
    return sum(round((leaf.getSize() / VOXEL) ** 3) for leaf in tree.begin_leafs())


def frustum_scene():
    """100k points at 2-20 m in a 90x60 degree frustum as a virtual 'camera' of 100k pixels."""
    rng = np.random.default_rng(0)
    n = 100_000
    x = rng.uniform(-1.0, 1.0, n)  # tan(45 deg)
    y = rng.uniform(-np.tan(np.pi / 6), np.tan(np.pi / 6), n)
    rays = np.column_stack([x, y, np.ones(n)])
    distance = rng.uniform(2.0, 20.0, n)
    depth = distance / np.linalg.norm(rays, axis=1)
    return rays, depth


def run(name, octo_points, origin, prismap_runs, repeat, max_range):
    t_octo, cpu_octo, tree = timed(lambda: _octo(octo_points, origin, max_range), repeat)
    octo_known = octomap_known_voxels(tree)
    print(
        f"\n[{name}] OctoMap insertPointCloud: {t_octo * 1e3:.0f} ms (CPU {cpu_octo * 1e3:.0f} ms), {octo_known} known "
        f"voxels, {tree.memoryUsage() / octo_known:.2f} bytes/known voxel (memoryUsage() / known voxels, pruned tree)"
    )
    for label, model, fn in prismap_runs:
        timer = TimedModel(model)
        t, cpu, grid = timed(lambda fn=fn, timer=timer: fn(timer), repeat)
        print(
            f"[{name}] prismap {label}: {t * 1e3:.0f} ms (CPU {cpu * 1e3:.0f} ms), {grid.n_known} known voxels, "
            f"{grid.nbytes() / grid.n_known:.2f} bytes/known voxel (allocated); speed ratio vs OctoMap "
            f"{t_octo / t:.2f}x wall, {cpu_octo / cpu:.2f}x CPU; model calls {timer.seconds / repeat * 1e3:.0f} ms per run "
            "(mean, incl. first-run set-up)"
        )


def _octo(points, origin, max_range):
    tree = octomap.OcTree(VOXEL)
    tree.insertPointCloud(points, origin, maxrange=max_range)
    return tree


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--street", action="store_true", help="scene (c) only")
    parser.add_argument(
        "--scales",
        type=float,
        nargs="+",
        default=[1.0, 0.5],
        help="scene (c): kitti_camera scales, the rigs (1: 1242x375, f 720 px; 0.5: 621x188, f 360 px)",
    )
    parser.add_argument(
        "--conditioned",
        action="store_true",
        help="scene (c) from images: SGBM's disparities, its conditioned error model, PRISM conditioned",
    )
    parser.add_argument("--world-dir", help="scene (c) --conditioned: keep (and reuse) the matched world here")
    parser.add_argument("--frames", type=int, default=10, help="scene (c): frames along the street")
    parser.add_argument("--voxels", type=float, nargs="+", default=[0.2, 0.1], help="scene (c): voxel sizes (m)")
    parser.add_argument(
        "--methods",
        nargs="+",
        help="scene (c): only the methods whose label contains one of these "
        "words (e.g. OctoMap PRISM); ratios are to OctoMap, or to the first method without it",
    )
    parser.add_argument("--street-method", nargs=6, help=argparse.SUPPRESS)  # one process of scene (c)
    args = parser.parse_args()
    if args.street_method:
        name, mode, voxel, scale, frames, world = args.street_method
        print(json.dumps(street_method(name, mode, float(voxel), float(scale), int(frames), world or None)))
        return
    if args.street:
        street(args)
        return

    camera, pose, depth = planes_frame()
    model = hitmiss(camera)
    disparity = measured_disparity(camera.focal_baseline / depth, np.random.default_rng(0))
    depth = camera.focal_baseline / disparity
    warm = OccupancyMap(VOXEL, p0=0.5)
    for mode in ("ray", "projective"):
        integrate_disparity(warm, disparity[:40, :40], camera, pose, model, mode=mode, max_range_m=12.0)

    def frame(mode):
        def go(ism):
            grid = OccupancyMap(VOXEL, p0=ism.p0 if hasattr(ism, "p0") else 0.5)
            integrate_disparity(grid, disparity, camera, pose, ism, mode=mode, max_range_m=12.0)
            return grid

        return go

    prism = make_sensor_model(
        "prism",
        focal_baseline=camera.focal_baseline,
        doffs_px=0.0,
        voxel_size_m=VOXEL,
        p0=0.05,
        error_model=STREET_MIXTURE,
    )
    runs = [
        ("ray, hit/miss", model, frame("ray")),
        ("projective, hit/miss", model, frame("projective")),
        ("projective, PRISM (p0 0.05)", prism, frame("projective")),
    ]
    print(
        "scene (a): 640x480 planes at 1-10 m (floor, walls, slanted box), camera yawed 20 deg, 0.1 m voxels, max range "
        f"12 m, errors {mixture_text()}; load {_load()}"
    )
    valid = np.isfinite(depth).ravel()
    run("a", world_points(camera, pose, depth)[valid], pose[:3, 3].copy(), runs, args.repeat, 12.0)

    rays, depth_b = frustum_scene()
    origin = np.zeros(3)
    points = np.ascontiguousarray(rays * depth_b[:, None])
    fake = StereoCamera(500.0, 0.0, 0.0, 0.1)
    model_b = hitmiss(fake)

    def cloud(ism):
        grid = OccupancyMap(VOXEL, p0=0.5)
        grid.integrate_rays(origin, rays, fake.focal_baseline / depth_b, ism, max_range_m=25.0)
        return grid

    print(
        "\nscene (b): 100k uniform random points at 2-20 m in a 90x60 deg frustum (seed 0), 0.1 m voxels, max range 25 m"
    )
    run("b", points, origin, [("ray, hit/miss", model_b, cloud)], args.repeat, 25.0)


if __name__ == "__main__":
    main()
