"""The sensor models along one ray, judged against PRISM (``prismap models compare`` and the demo): ray
profiles, PRISM's sweeps, its influence distance, divergences from PRISM and timings, as figures and tables."""

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prismap._files import write_text_atomic
from prismap._progress import progress
from prismap._validate import check_positive, check_probability
from prismap.errors import PrismapInputError

FILES = {
    "profiles": "profiles.png",
    "sweeps": "prism_sweeps.png",
    "influence": "influence.png",
    "divergence": "divergence.png",
    "tables": "tables.md",
    "json": "models_compare.json",
}
"""The files written into the output folder, by role."""


@dataclass(frozen=True)
class ModelsComparison:
    """What :func:`run_models_compare` wrote and found.

    Attributes
    ----------
    paths : dict of str -> Path
        :data:`FILES` inside the output folder.
    header : str
        One line naming the error model, the camera, the cells and the single-noise sigma.
    comparison : prismap.study.ModelComparison
    performance : prismap.study.PerformanceTable
    """

    paths: dict
    header: str
    comparison: object
    performance: object


def run_models_compare(error_model_path, out_dir, *, focal_px, baseline_m, doffs_px=0.0, camera_label="custom",
                       voxel_size_m=0.1, p0=0.05, distances_m=(2.0, 5.0, 10.0, 20.0), perf_stride=8):
    """Evaluate every registered sensor model on equal cells along one ray and write :data:`FILES`.

    Parameters
    ----------
    error_model_path : str or Path
        Error model JSON from ``prismap characterise``.
    out_dir : str or Path
    focal_px, baseline_m, doffs_px : float, pixels, metres, pixels
        The rig (:data:`prismap.study.CAMERAS` holds the known ones); ``camera_label`` names it in the tables.
    voxel_size_m : float, metres
    p0 : float in (0, 1)
        Prior occupancy of one cell.
    distances_m : sequence of float, metres
        Measured distances of the ray profiles.
    perf_stride : int >= 1
        Timing batch: every ``perf_stride``-th pixel of a 640x480 frame.

    Returns
    -------
    ModelsComparison
    """
    from prismap.characterise import load_error_model
    from prismap.plots import plot_divergence, plot_influence, plot_prism_sweeps, plot_ray_profiles
    from prismap.study import RaySetup, compare_models, influence_distances, prism_sweeps, time_models

    voxel_size_m = check_positive(voxel_size_m, "voxel_size_m")
    p0 = check_probability(p0, "p0")
    distances_m = sorted(float(d) for d in distances_m)
    if isinstance(perf_stride, bool) or int(perf_stride) != perf_stride or perf_stride < 1:
        raise PrismapInputError(f"`perf_stride` must be an integer >= 1; got {perf_stride!r}")
    error_model = load_error_model(error_model_path)
    mixture = error_model.mixture
    setup = RaySetup(focal_baseline=focal_px * baseline_m, doffs_px=doffs_px, voxel_size_m=voxel_size_m, p0=p0)
    for s in distances_m:
        setup.disparity_at(s)  # fail early on distances the camera cannot resolve
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {key: out / name for key, name in FILES.items()}

    steps = progress(total=5, desc="models compare", unit="step")
    comparison = compare_models(mixture, distances_m, setup=setup)
    plot_ray_profiles(comparison, path=paths["profiles"])
    steps.update()
    by_g = {fit.n_components: fit.mixture for fit in error_model.fits}
    sweeps = prism_sweeps(mixture, setup=setup, distances_m=distances_m, reference_m=float(np.median(distances_m)),
                          mixtures_by_components=by_g)
    plot_prism_sweeps(sweeps, path=paths["sweeps"])
    steps.update()
    influence = influence_distances(mixture, np.linspace(1.0, 1.5 * max(distances_m), 16), setup=setup)
    plot_influence(*influence, path=paths["influence"])
    steps.update()
    plot_divergence(comparison, path=paths["divergence"])
    steps.update()
    performance = time_models(mixture, setup=setup, focal_px=focal_px, stride=perf_stride)
    steps.update()
    steps.close()

    header = (f"Error model {error_model_path} ({error_model.matcher} on {error_model.dataset}, G = "
              f"{error_model.selected_components}); camera {camera_label}: f*b = {setup.focal_baseline:.3f} px*m, "
              f"doffs = {doffs_px:g} px; cells of {voxel_size_m:g} m, p0 = {p0:g}; single-noise sigma "
              f"{comparison.noise_sigma_px:.3f} px (largest-weight component).")
    influence_rows = ["| measured (m) | bound behind (m) | observed behind (m) |", "|---:|---:|---:|"]
    influence_rows += [f"| {m:.2f} | {b:.2f} | {o:.2f} |" for m, b, o in zip(*influence)]
    tables = "\n".join([
        "# Sensor models against PRISM", "", header, "",
        "## Divergence from PRISM", "",
        ("Over the cells either model updates, from the camera to the larger influence depth. Cleared occupancy: "
         "PRISM's expected occupied cells among those the model pushes toward free."), "",
        comparison.to_markdown(), "## PRISM's maximum influence distance", "", "\n".join(influence_rows), "",
        "## Performance", "", performance.to_markdown(),
    ])
    write_text_atomic(paths["tables"], tables)
    record = {"error_model": str(error_model_path), "camera": camera_label, "comparison": comparison.to_dict(),
              "influence": {k: v.tolist() for k, v in zip(("measured_m", "bound_m", "observed_m"), influence)},
              "performance": performance.to_dict()}
    write_text_atomic(paths["json"], json.dumps(record, indent=2) + "\n")
    return ModelsComparison(paths, header, comparison, performance)
