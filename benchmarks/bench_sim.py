"""Simulator speed and realism: rendering cost per stereo frame next to the matchers that consume it.

Scene: ``prismap.sim.indoor_scene(seed=0)`` (14 x 9 x 3 m room, 29 textured boxes) seen along
``indoor_trajectory(40, seed=0)`` by the New Tsukuba camera (640x480, f = 615 px, b = 0.10 m), image noise
sigma 2 grey levels; 2-D: ``office_world()`` with a 360-ray, 90-degree scanner along its waypoint path.
Prints ms per frame (rendering vs OpenCV block matching and SGBM on the same frames, as a ratio) and the
matchers' disparity errors against the exact ground truth, so a change that makes the images easier or
harder to match shows up. Run: ``.venv/bin/python benchmarks/bench_sim.py [n_frames]``.
"""

import sys
import time

import numpy as np

from prismap import sim
from prismap.stereo import make_matcher


def _timed(function, repeat):
    start = time.perf_counter()
    for i in range(repeat):
        result = function(i)
    return (time.perf_counter() - start) / repeat * 1e3, result


def main(n_frames=10):
    scene, camera = sim.indoor_scene(seed=0), sim.tsukuba_camera()
    poses = sim.indoor_trajectory(40, seed=0)[:: max(1, 40 // n_frames)][:n_frames]
    scene.render(camera, poses[0])  # compile the kernels
    frames = []
    render_ms, _ = _timed(lambda i: frames.append(scene.render(camera, poses[i], rng=i)), len(poses))
    print(f"scene {scene.name}: {len(scene.box_lo)} boxes, {len(poses)} frames of 640x480, noise sigma 2")
    print(f"render (left + right + exact disparity): {render_ms:.1f} ms/frame")
    for name, params in (("bm", {"num_disparities": 64, "block_size": 9}), ("sgbm", {"num_disparities": 64})):
        matcher = make_matcher(name, **params)
        match_ms, _ = _timed(lambda i, matcher=matcher: matcher.compute(frames[i].left, frames[i].right), len(frames))
        errors = np.concatenate([(f.disparity_gt - matcher.compute(f.left, f.right)).ravel() for f in frames[:3]])
        valid = np.isfinite(errors)
        e = errors[valid]
        print(
            f"{name:5s} {match_ms:7.1f} ms/frame (render / match = {render_ms / match_ms:.2f}); first 3 frames: "
            f"valid {valid.mean():.1%}, |e| <= 1 px {np.mean(np.abs(e) <= 1):.1%}, median |e| {np.median(np.abs(e)):.2f} px"
        )
    start = time.perf_counter()
    truth = scene.ground_truth(frames, 0.1)
    print(
        f"ground truth at 0.1 m over {len(frames)} frames: {(time.perf_counter() - start) * 1e3:.0f} ms, "
        f"{len(truth.observed_keys)} observed voxels ({len(truth.observed_occupied_keys)} occupied)"
    )
    world = sim.office_world()
    scanner = sim.StereoScanner2D(n_rays=360, fov_deg=90.0)
    path = sim.waypoint_path(world.waypoints)
    scan_ms, _ = _timed(lambda i: scanner.scan(world, sim.pose_from_heading(path[i, :2], path[i, 2])), len(path))
    print(f"2-D office: {len(world.rectangles)} rectangles, 360 rays: {scan_ms:.2f} ms/scan over {len(path)} poses")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 10)
