"""The ``models compare`` workflow: every sensor model against PRISM for one error model, as files."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prismap._files import write_text_atomic
from prismap._progress import progress
from prismap._validate import check_positive, check_probability
from prismap.camera import StereoCamera
from prismap.characterise import ErrorModel
from prismap.errors import PrismapInputError
from prismap.sensor_models import PrismModel, failure_floor
from prismap.study._ray_models import CAMERAS, RaySetup, compare_models, influence_distances, prism_sweeps

COMPARE_FILES = {
    "profiles": "profiles.png",
    "sweeps": "prism_sweeps.png",
    "influence": "influence.png",
    "divergence": "divergence.png",
    "tables": "tables.md",
    "json": "models_compare.json",
}
"""What :func:`run_models_compare` writes into its output directory."""

MAX_DISTANCES = 16
"""Most measured distances one comparison takes (each costs a PRISM profile per model and sweep)."""
INFLUENCE_REACH = 1.5
"""The influence table runs to this multiple of the largest measured distance."""
MIN_DISPARITY_PX = 1.0
"""Smallest disparity ``f b / z`` (pixels, before the offset ``doffs``) a compared distance may have: beyond
it the rounding to 1/16 px moves the measurement by more than 3 %."""


def check_distances(distances_m, setup, far_depth_m):
    """``distances_m`` sorted, each within the rig's range, or raise naming the first that is not.

    A distance must be positive, have a disparity ``f b / z`` of at least :data:`MIN_DISPARITY_PX`, and
    with :data:`INFLUENCE_REACH` times it stay within PRISM's ``far_depth_m`` (where the influence table
    ends); at most :data:`MAX_DISTANCES` of them.
    """
    distances = sorted(check_positive(d, "distances_m") for d in distances_m)
    if not distances:
        raise PrismapInputError("`distances_m` is empty")
    if len(distances) > MAX_DISTANCES:
        raise PrismapInputError(
            f"`distances_m` holds {len(distances)} distances; at most {MAX_DISTANCES} (MAX_DISTANCES)"
        )
    limit = min(setup.focal_baseline / MIN_DISPARITY_PX, far_depth_m / INFLUENCE_REACH)
    if distances[-1] > limit:
        raise PrismapInputError(
            f"`distances_m`: {distances[-1]:g} m lies beyond this rig's range of {limit:.4g} m (a disparity of at "
            f"least {MIN_DISPARITY_PX:g} px at f*b {setup.focal_baseline:.4g} px*m, and {INFLUENCE_REACH:g} times "
            f"the distance within PRISM's far_depth_m {far_depth_m:g} m)"
        )
    return distances


@dataclass(frozen=True)
class ModelsCompareRun:
    """What :func:`run_models_compare` wrote.

    Attributes
    ----------
    paths : dict
        ``COMPARE_FILES`` key -> Path of each written file.
    header : str
        One paragraph: error model, camera, cell size, prior, single-noise sigma.
    comparison : ModelComparison
    """

    paths: dict
    header: str
    comparison: object


def run_models_compare(
    error_model: ErrorModel,
    out_dir: str | os.PathLike[str],
    *,
    camera: str | StereoCamera = "middlebury-motorcycle",
    voxel_size_m: float = 0.1,
    p0: float = 0.05,
    distances_m: Sequence[float] = (2.0, 5.0, 10.0, 20.0),
    source: str = "",
) -> ModelsCompareRun:
    """Profiles, PRISM sweeps, influence distances and divergences of every model, written to ``out_dir``.

    Parameters
    ----------
    error_model : ErrorModel
        From :func:`prismap.characterise.load_error_model` (its selected mixture and its fits by G).
    out_dir : str or Path
        Receives :data:`COMPARE_FILES` (each written atomically).
    camera : str or StereoCamera, keyword-only
        A rig of :data:`CAMERAS` by name, or a camera (labelled ``custom``).
    voxel_size_m : float, metres
    p0 : float in (0, 1)
    distances_m : sequence of float, metres
        Measured distances of the profiles and divergences (:func:`check_distances`).
    source : str
        Where the error model came from, for the tables.

    Returns
    -------
    ModelsCompareRun
    """
    from prismap.plots import plot_divergence, plot_influence, plot_prism_sweeps, plot_ray_profiles

    if isinstance(camera, StereoCamera):
        label, rig = (
            "custom",
            {"focal_px": camera.focal_px, "baseline_m": camera.baseline_m, "doffs_px": camera.doffs_px},
        )
    elif camera in CAMERAS:
        label, rig = camera, CAMERAS[camera]
    else:
        raise PrismapInputError(f"`camera` must be one of {sorted(CAMERAS)} or a StereoCamera; got {camera!r}")
    voxel = check_positive(voxel_size_m, "voxel_size_m")
    p0 = check_probability(p0, "p0")
    mixture = error_model.mixture
    setup = RaySetup(
        focal_baseline=rig["focal_px"] * rig["baseline_m"], doffs_px=rig["doffs_px"], voxel_size_m=voxel, p0=p0
    )
    distances = check_distances(distances_m, setup, PrismModel.far_depth_m)
    out = Path(out_dir)
    paths = {key: out / name for key, name in COMPARE_FILES.items()}

    steps = progress(total=4, desc="models compare", unit="step")
    comparison = compare_models(mixture, distances, setup=setup)
    plot_ray_profiles(comparison, path=paths["profiles"])
    steps.update()
    by_g = {fit.n_components: fit.mixture for fit in error_model.fits}
    sweeps = prism_sweeps(
        mixture,
        setup=setup,
        distances_m=distances,
        reference_m=float(np.median(distances)),
        mixtures_by_components=by_g,
    )
    plot_prism_sweeps(sweeps, path=paths["sweeps"])
    steps.update()
    influence = influence_distances(mixture, np.linspace(1.0, 1.5 * max(distances), 16), setup=setup)
    plot_influence(*influence, path=paths["influence"])
    steps.update()
    plot_divergence(comparison, path=paths["divergence"])
    steps.update()
    steps.close()

    header = (
        f"Error model {source} ({error_model.matcher} on {error_model.dataset}, G = "
        f"{error_model.selected_components}); camera {label}: f*b = {setup.focal_baseline:.3f} px*m, "
        f"doffs = {rig['doffs_px']:g} px; cells of {voxel:g} m, p0 = {p0:g}; single-noise sigma "
        f"{comparison.noise_sigma_px:.3f} px (largest-weight component)" + _failure_note(mixture) + "."
    )
    influence_rows = ["| measured (m) | bound behind (m) | observed behind (m) |", "|---:|---:|---:|"]
    influence_rows += [f"| {m:.2f} | {b:.2f} | {o:.2f} |" for m, b, o in zip(*influence)]
    tables = "\n".join(
        [
            "# Sensor models against PRISM",
            "",
            header,
            "",
            "## Divergence from PRISM",
            "",
            "Over the cells either model updates, from the camera to the larger influence depth. Cleared occupancy: "
            "PRISM's expected occupied cells among those the model pushes toward free.",
            "",
            comparison.to_markdown(),
            "## PRISM's maximum influence distance",
            "",
            "\n".join(influence_rows),
            "",
            "Per-cell costs of the models: `benchmarks/bench_models_table.py`.",
            "",
        ]
    )
    write_text_atomic(paths["tables"], tables)
    record = {
        "error_model": source,
        "camera": label,
        "comparison": comparison.to_dict(),
        "failure": {
            "weight": mixture.failure_weight,
            "search_range_px": mixture.search_range_px,
            "floor": failure_floor(mixture),
        },
        "influence": {k: v.tolist() for k, v in zip(("measured_m", "bound_m", "observed_m"), influence)},
    }
    write_text_atomic(paths["json"], json.dumps(record, indent=2) + "\n")
    return ModelsCompareRun(paths, header, comparison)


def _failure_note(mixture):
    """The matcher-failure component in words: its weight, search range and the evidence bound at ``p0``."""
    if mixture.search_range_px is None:
        return "; no matcher-failure component (a format-1/2 model: Gaussian tails only)"
    lo, hi = mixture.search_range_px
    return (
        f"; matcher failures w_f = {mixture.failure_weight:.2e} uniform over {lo:g}..{hi:g} px "
        f"(W = {hi - lo:g} px), least failure posterior eps = {failure_floor(mixture):.2e}"
    )
