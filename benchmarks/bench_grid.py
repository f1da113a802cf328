"""OctoMap's insertPointCloud versus prismap's map, side by side in one process (ANCHORS.md).

Scenes: (a) a 640x480 depth frame of planes at 1-10 m (tests/support.planes_frame), 0.1 m voxels;
(b) 100k random points at 2-20 m in a 90x60 degree frustum (seed 0), 0.1 m voxels. Same points, resolution and
max range for both. Prints wall seconds (median of --repeat runs) with the throughput ratio, CPU seconds
(process time, both threads; steadier than wall time on a shared machine), the time spent inside the sensor
model's own calls (hit/miss in ray mode is added while casting: no model calls), and bytes per known voxel.
The first of the --repeat runs of PRISM builds its tables (cold); the median is a warm run.
Run: .venv/bin/python benchmarks/bench_grid.py [--repeat 3]
"""

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import octomap  # noqa: E402

from prismap.camera import StereoCamera  # noqa: E402
from prismap.gmm import GaussianMixture  # noqa: E402
from prismap.grid import OccupancyMap  # noqa: E402
from prismap.sensor_models import make_sensor_model  # noqa: E402
from support import planes_frame, world_points  # noqa: E402

VOXEL = 0.1


def hitmiss(camera):
    return make_sensor_model("hitmiss", focal_baseline=camera.focal_baseline, doffs_px=camera.doffs_px,
                             voxel_size_m=VOXEL, p0=0.5)


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
    """Wraps a sensor model and adds up the wall time of its ``cell_posteriors`` and ``influence_depth``."""

    def __init__(self, model):
        self.model, self.seconds = model, 0.0

    def __getattr__(self, name):
        return getattr(self.model, name)

    def _timed(self, method, *args):
        start = time.perf_counter()
        try:
            return method(*args)
        finally:
            self.seconds += time.perf_counter() - start

    def cell_posteriors(self, *args):
        return self._timed(self.model.cell_posteriors, *args)

    def influence_depth(self, *args):
        return self._timed(self.model.influence_depth, *args)

    def with_extra_noise(self, sigma_px):
        return TimedModel(self.model.with_extra_noise(sigma_px))


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
    print(f"\n[{name}] OctoMap insertPointCloud: {t_octo * 1e3:.0f} ms (CPU {cpu_octo * 1e3:.0f} ms), {octo_known} known "
          f"voxels, {tree.memoryUsage() / octo_known:.2f} bytes/known voxel (memoryUsage() / known voxels, pruned tree)")
    for label, model, fn in prismap_runs:
        timer = TimedModel(model)
        t, cpu, grid = timed(lambda fn=fn, timer=timer: fn(timer), repeat)
        print(f"[{name}] prismap {label}: {t * 1e3:.0f} ms (CPU {cpu * 1e3:.0f} ms), {grid.n_known} known voxels, "
              f"{grid.nbytes() / grid.n_known:.2f} bytes/known voxel (allocated); speed ratio vs OctoMap "
              f"{t_octo / t:.2f}x wall, {cpu_octo / cpu:.2f}x CPU; model calls {timer.seconds / repeat * 1e3:.0f} ms per run "
              "(mean, incl. first-run set-up)")


def _octo(points, origin, max_range):
    tree = octomap.OcTree(VOXEL)
    tree.insertPointCloud(points, origin, maxrange=max_range)
    return tree


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()

    camera, pose, depth = planes_frame()
    model = hitmiss(camera)
    disparity = camera.focal_baseline / depth
    warm = OccupancyMap(VOXEL, p0=0.5)
    for mode in ("ray", "projective"):
        warm.integrate_disparity(disparity[:40, :40], camera, pose, model, mode=mode, max_range_m=12.0)

    def frame(mode):
        def go(ism):
            grid = OccupancyMap(VOXEL, p0=ism.p0 if hasattr(ism, "p0") else 0.5)
            grid.integrate_disparity(disparity, camera, pose, ism, mode=mode, max_range_m=12.0)
            return grid
        return go

    prism = make_sensor_model("prism", focal_baseline=camera.focal_baseline, doffs_px=0.0, voxel_size_m=VOXEL,
                              p0=0.05, error_model=GaussianMixture.gaussian(0.5))
    runs = [("ray, hit/miss", model, frame("ray")), ("projective, hit/miss", model, frame("projective")),
            ("projective, PRISM (p0 0.05, N(0, 0.5 px) errors)", prism, frame("projective"))]
    print("scene (a): 640x480 planes at 1-10 m (floor, walls, slanted box), camera yawed 20 deg, 0.1 m voxels, max range 12 m")
    run("a", world_points(camera, pose, depth), pose[:3, 3].copy(), runs, args.repeat, 12.0)

    rays, depth_b = frustum_scene()
    origin = np.zeros(3)
    points = np.ascontiguousarray(rays * depth_b[:, None])
    fake = StereoCamera(500.0, 0.0, 0.0, 0.1)
    model_b = hitmiss(fake)

    def cloud(ism):
        grid = OccupancyMap(VOXEL, p0=0.5)
        grid.integrate_rays(origin, rays, fake.focal_baseline / depth_b, ism, max_range_m=25.0)
        return grid

    print("\nscene (b): 100k uniform random points at 2-20 m in a 90x60 deg frustum (seed 0), 0.1 m voxels, max range 25 m")
    run("b", points, origin, [("ray, hit/miss", model_b, cloud)], args.repeat, 25.0)


if __name__ == "__main__":
    main()
