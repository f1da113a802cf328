"""The 2-D experiment: a stereo range scanner whose errors follow a known mixture, through the office world."""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from prismap._progress import progress
from prismap._validate import check_integer, check_positive
from prismap.errors import PrismapInputError
from prismap.experiment._cells import ExperimentResult, claim_out_dir, draw_figures, run_cells
from prismap.experiment._results import MODELS, prior_of, write_results
from prismap.gmm import GaussianMixture

SGBM_LIKE_MIXTURE = GaussianMixture(
    np.array([0.84, 0.10, 0.06]), np.array([0.01, -0.04, -10.4]), np.array([0.24, 0.92, 13.6])
)
"""Disparity error ``e = d_true - d_computed`` (pixels) shaped like a semiglobal matcher's: a sharp core,
a wider shoulder and 6 % gross mismatches that put the surface too near (negative mean)."""

ERROR_SOURCE = "known-mixture"
"""The matcher column of the 2-D results: errors drawn from the mixture itself, not from a matcher."""

OFFICE_SIZES = {
    False: {"path_step_m": 0.25, "turn_step_deg": 10.0, "n_rays": 360, "voxel_size_m": 0.1},
    True: {"path_step_m": 1.0, "turn_step_deg": 30.0, "n_rays": 180, "voxel_size_m": 0.2},
}
"""Full and ``quick`` sizes: pose spacing along the office tour, scanner rays (90 degree field of view), voxel."""


def office2d_settings(
    *, n_frames=None, voxel_size_m=None, seed=0, quick=False, error_model=SGBM_LIKE_MIXTURE, max_depth_m=15.0
):
    """The settings dict of a 2-D run (sizes of ``OFFICE_SIZES`` unless overridden)."""
    sizes = dict(OFFICE_SIZES[bool(quick)])
    if voxel_size_m is not None:
        sizes["voxel_size_m"] = check_positive(voxel_size_m, "voxel_size_m")
    if n_frames is not None:
        check_integer(n_frames, "n_frames", expected="a positive integer or None", condition=lambda n: n >= 1)
    if not isinstance(error_model, GaussianMixture):
        raise PrismapInputError(f"`error_model` must be a GaussianMixture; got {type(error_model).__name__}")
    return {
        "world": "office2d",
        "quick": bool(quick),
        "seed": int(seed),
        "n_frames": n_frames,
        "max_depth_m": check_positive(max_depth_m, "max_depth_m"),
        "fov_deg": 90.0,
        "baseline_m": 0.1,
        "error_model": error_model.to_dict(),
        **sizes,
    }


def run_office2d(
    out_dir: str | os.PathLike[str],
    *,
    n_frames: int | None = None,
    voxel_size_m: float | None = None,
    seed: int = 0,
    quick: bool = False,
    models: Sequence[str] = MODELS,
    error_model: GaussianMixture = SGBM_LIKE_MIXTURE,
    max_depth_m: float = 15.0,
) -> ExperimentResult:
    """Map the office world with every sensor model from disparities with known-mixture errors; score them.

    The scanner (:class:`prismap.sim.StereoScanner2D`, 90 degree field of view, 0.1 m baseline) follows
    :func:`prismap.sim.waypoint_path` through the office's rooms; each ray's true disparity is corrupted by
    an error drawn from ``error_model`` (PRISM's assumptions hold exactly: every other model sees the same
    disparities). Every model maps all frames with its default per-frame policy, and each map is scored on
    the cells a noise-free sensor on the same path observed. ``p0`` is those cells' occupancy ratio
    (:func:`prismap.experiment.prior_of`), for every model; PRISM gets the true mixture, convolution and
    Andert its dominant component's sigma (:func:`prismap.pipeline.build_sensor_model`).

    Parameters
    ----------
    out_dir : str or Path
        Receives ``settings.json``, ``results.md``, ``results.json``, the cells (JSON + map ``.npz``, reused
        by a rerun with the same settings) and the figures.
    n_frames : int or None
        Use this many poses, evenly spaced along the tour (None = all of them).
    voxel_size_m : float or None, metres
        None = the size of :data:`OFFICE_SIZES`.
    seed : int
        Seeds the disparity errors.
    quick : bool
        Coarser path, fewer rays, 0.2 m cells (tests, quick demo).
    models : sequence of str
    error_model : GaussianMixture, pixels
    max_depth_m : float, metres of camera depth
        Farther hits give no measurement.

    Returns
    -------
    ExperimentResult
    """
    from prismap import sim
    from prismap.camera import integrate_disparity
    from prismap.grid import OccupancyMap
    from prismap.pipeline import build_sensor_model

    settings = office2d_settings(
        n_frames=n_frames,
        voxel_size_m=voxel_size_m,
        seed=seed,
        quick=quick,
        error_model=error_model,
        max_depth_m=max_depth_m,
    )
    world = sim.office_world()
    poses = sim.waypoint_path(world.waypoints, step_m=settings["path_step_m"], turn_step_deg=settings["turn_step_deg"])
    if n_frames is not None:
        if n_frames > len(poses):
            raise PrismapInputError(
                f"`n_frames` must be at most {len(poses)} (the scans of the office tour); got {n_frames}"
            )
        poses = poses[np.unique(np.linspace(0, len(poses) - 1, int(n_frames)).round().astype(int))]
    voxel = settings["voxel_size_m"]
    scanner = sim.StereoScanner2D(
        n_rays=settings["n_rays"],
        fov_deg=settings["fov_deg"],
        baseline_m=settings["baseline_m"],
        max_depth_m=settings["max_depth_m"],
        error_model=error_model,
    )
    frames = list(scanner.frames(world, poses, seed=seed))
    truth = world.ground_truth(frames, voxel, max_depth_m=settings["max_depth_m"])  # refuses absurd voxel sizes
    out = claim_out_dir(out_dir, settings)  # after every check of the settings: a refused run writes nothing
    p0 = prior_of(truth)

    # rays stop where the scored cells do: the farthest ray reaches max_depth_m of camera depth at |r| times it
    # (an error can put a measured disparity near 0 px, whose free space would otherwise run for kilometres)
    reach_m = settings["max_depth_m"] * float(
        np.linalg.norm(scanner.camera.pixel_rays((1, settings["n_rays"])), axis=-1).max()
    )

    def build_map(model_name):
        model = build_sensor_model(model_name, scanner.camera, voxel_size_m=voxel, p0=p0, error_model=error_model)
        grid = OccupancyMap(voxel, p0=p0)
        for frame in progress(frames, total=len(frames), desc=f"office2d {model_name}", unit="frame"):
            integrate_disparity(grid, frame.disparity, frame.camera, frame.T_world_cam, model, max_range_m=reach_m)
        return grid

    results, maps = run_cells(out, ERROR_SOURCE, models, build_map, truth, settings)
    notes = (
        f"Office world (30 m x 20 m), {len(frames)} scans of {settings['n_rays']} rays along the tour, "
        f"{voxel} m cells, errors drawn from the mixture w = {_fmt(error_model.weights)}, "
        f"mu = {_fmt(error_model.means)} px, sigma = {_fmt(error_model.sigmas)} px (seed {seed}).",
        f"p0 = {p0:.4f}: the occupancy ratio of the cells a perfect sensor observed (the scored cells).",
    )
    paths = write_results(results, out, title="2-D office, known error mixture", notes=notes, settings=settings)
    artifacts = [
        (paths["table"], "Scores of every sensor model on the 2-D office (Markdown)."),
        (paths["json"], "The same scores with reliability bins and histograms (JSON)."),
    ]
    artifacts += draw_figures(out, ERROR_SOURCE, results, maps, truth, layer=0, where="2-D office")
    return ExperimentResult("office2d", tuple(results), p0, settings, tuple(artifacts))


def _fmt(values):
    return "/".join(f"{v:g}" for v in np.round(values, 3))
