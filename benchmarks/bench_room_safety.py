"""Which occupied voxels a 3-D run's PRISM maps call free at the 90 %-free threshold, and why.

Takes a finished 3-D run (``prismap.experiment.run_scene3d``) and splits the occupied voxels that plain or
conditioned PRISM calls free (``P <= t``, ``t`` each map's safety threshold) into those both maps call free and
those only one does. For each group it prints: the solid share of the voxel's volume (6^3 samples against the
world's boxes), how many of its faces border an observed free voxel (2 = an edge of a solid, 3 = a corner), how
many mapping frames updated it, its distance to the nearest mapping camera, and how often the mapping frames'
noise-free rays cross it without stopping (beyond each ray's voxel overhang, as
``Scene3D.pass_through_ratio`` counts passes) against stopping in it. With ``exact`` it also maps the
mapping frames' exact disparities (rounded to 1/16 px) with plain PRISM and the run's parameters, and counts
how many of each group that map calls free at its own threshold: voxels no per-ray model keeps. Run:
``PYTHONPATH=src .venv/bin/python benchmarks/bench_room_safety.py RUN_DIR [matcher] [exact]``
(default matcher bm).
"""

import sys
import tempfile
from pathlib import Path

import numpy as np
from bench_room_errors import load_run

from prismap.camera import frame_overhang_m
from prismap.evaluate import align_to_ground_truth, safety_score
from prismap.experiment._worlds3d import WORLDS
from prismap.grid import crossed_voxels, pack_keys
from prismap.io import load_map, write_disparity_png
from prismap.pipeline import MappingConfig, map_sequence
from prismap.sensor_models import CLASS_PASS_THROUGH


def called_free(grid, truth, p0):
    """(M,) bool over ``truth.observed_keys``: occupied and ``P <= t`` at the map's 90 %-free threshold ``t``."""
    keys = grid.known_voxels()[0]
    p, occupied = align_to_ground_truth(
        keys, grid.probability_at_keys(keys), truth.occupied_keys, truth.observed_keys, p0=p0
    )
    return occupied & (p <= safety_score(p, occupied)[1]), occupied


def solid_share(keys, box_lo, box_hi, voxel, n=6):
    """(K,) share of each voxel's volume inside the union of the boxes (``n``^3 samples)."""
    grid = (np.arange(n) + 0.5) / n
    offsets = np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), -1).reshape(-1, 3)
    points = (keys[:, None, :] + offsets[None]) * voxel
    inside = np.zeros(points.shape[:2], bool)
    for lo, hi in zip(box_lo, box_hi):
        inside |= np.all((points >= lo) & (points <= hi), axis=2)
    return inside.mean(axis=1)


def noise_free_crossings(sequence, truth, voxel, settings):
    """``(passes, stops)`` (M,) over ``truth.observed_keys``: the mapping frames' noise-free rays that leave the
    voxel before their overhang, and those that end in it."""
    packed = pack_keys(truth.observed_keys)
    order = np.argsort(packed)
    passes, stops = np.zeros(packed.size), np.zeros(packed.size)
    camera, step = sequence.camera, settings["subsample"]
    for index in range(len(sequence)):
        frame = sequence[index]
        pose = np.asarray(frame.T_world_cam)
        depth = np.asarray(camera.depth_from_disparity(frame.disparity_gt), float)[::step, ::step].reshape(-1)
        rays_cam = camera.pixel_rays(frame.disparity_gt.shape)[::step, ::step].reshape(-1, 3)
        overhang = frame_overhang_m(frame.disparity_gt, camera, pose[:3, :3], voxel, step, rays_cam)
        hit = np.isfinite(depth) & (depth <= settings["max_range_m"])
        ray, keys, _, t_out = crossed_voxels(pose[:3, 3], rays_cam @ pose[:3, :3].T, np.where(hit, depth, 0.0), voxel)
        limit = depth - overhang / np.linalg.norm(rays_cam, axis=1)
        cell = pack_keys(keys.astype(np.int64))
        where = np.minimum(np.searchsorted(packed[order], cell), packed.size - 1)
        known = packed[order][where] == cell
        last = np.r_[ray[1:] != ray[:-1], True]
        np.add.at(stops, order[where][known & last], 1)
        np.add.at(passes, order[where][known & ~last & (t_out < limit[ray])], 1)
    return passes, stops


def exact_map(sequence, settings, matcher, error_model, params, p0):
    """Plain PRISM's map of the mapping frames' exact disparities (rounded to 1/16 px), the run's parameters and
    ``matcher``'s whole-image error mixture."""
    with tempfile.TemporaryDirectory() as directory:
        for index in range(len(sequence)):
            exact = np.asarray(sequence[index].disparity_gt, float)
            write_disparity_png(Path(directory) / f"{index:06d}.png", np.round(exact * 16) / 16, "exact disparity")
        prism = {k: v for k, v in params.get("prism", {}).items() if k != CLASS_PASS_THROUGH}
        config = MappingConfig(
            model="prism",
            model_params=prism,
            voxel_size_m=settings["voxel_size_m"],
            p0=p0,
            error_model=error_model,
            conditioned=False,
            matcher=matcher,
            disparity_source=directory,
            max_range_m=settings["max_range_m"],
            subsample=settings["subsample"],
            mode=settings["mode"],
        )
        return map_sequence(sequence, config)


def main(run_dir, matcher="bm", exact=""):
    run, sequence, truth, settings, error_model, params, p0 = load_run(run_dir, matcher)
    voxel = settings["voxel_size_m"]
    plain, occupied = called_free(load_map(run / "cells" / f"{matcher}__prism.npz"), truth, p0)
    conditioned, _ = called_free(load_map(run / "cells" / f"{matcher}__prism_conditioned.npz"), truth, p0)
    counts = load_map(run / "cells" / f"{matcher}__prism.npz").lookup_keys(truth.observed_keys)[1]
    base = WORLDS[settings["world"]]().scene(settings["seed"])
    shift = settings["grid_offset_m"]
    keys = truth.observed_keys
    free_keys = pack_keys(keys[~occupied])
    exposed = sum(
        np.isin(pack_keys(keys + step), free_keys).astype(int)
        for step in np.vstack((np.eye(3, dtype=np.int64), -np.eye(3, dtype=np.int64)))
    )
    cameras = np.array([sequence[i].T_world_cam[:3, 3] for i in range(len(sequence))])
    distance = np.linalg.norm((keys + 0.5)[:, None] * voxel - cameras[None], axis=2).min(axis=1)
    passes, stops = noise_free_crossings(sequence, truth, voxel, settings)
    share = np.zeros(keys.shape[0])
    share[occupied] = solid_share(keys[occupied], base.box_lo + shift, base.box_hi + shift, voxel)
    groups = {
        "both": plain & conditioned,
        "plain only": plain & ~conditioned,
        "conditioned only": conditioned & ~plain,
        "all occupied": occupied,
    }
    exact_free = (
        called_free(exact_map(sequence, settings, matcher, error_model, params, p0), truth, p0)[0] if exact else None
    )
    for name, group in groups.items():
        faces = np.bincount(exposed[group], minlength=4)
        line = (
            f"{matcher} {name:16s} {int(group.sum()):6d} voxels | solid share median {np.median(share[group]):.3f}, "
            f"< 0.2: {np.mean(share[group] < 0.2):.2f} | faces to free 1/2/3: {faces[1]}/{faces[2]}/{faces[3]} | "
            f"frames median {np.median(counts[group]):.0f} | camera distance median {np.median(distance[group]):.2f} m | "
            f"noise-free rays pass {passes[group].sum() / max(1.0, (passes[group] + stops[group]).sum()):.3f}"
        )
        if exact_free is not None:
            line += f" | exact-disparity map calls {int((exact_free & group).sum())} free"
        print(line, flush=True)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
