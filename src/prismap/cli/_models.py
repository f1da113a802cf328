"""``prismap models compare``: every inverse sensor model along one ray, judged against PRISM."""

import json
from pathlib import Path

import numpy as np

from prismap._files import write_text_atomic
from prismap._progress import progress
from prismap._validate import check_positive, check_probability
from prismap.cli._args import add_out
from prismap.errors import PrismapInputError

FILES = {
    "profiles": "profiles.png",
    "sweeps": "prism_sweeps.png",
    "influence": "influence.png",
    "divergence": "divergence.png",
    "tables": "tables.md",
    "json": "models_compare.json",
}


def register(subparsers):
    """Add the ``models`` parser and its ``compare`` sub-command."""
    parser = subparsers.add_parser("models", help="study the inverse sensor models along one ray")
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    compare = actions.add_parser(
        "compare",
        help="profiles, PRISM sweeps, influence distance, divergences from PRISM and timings",
        description=(
            "Evaluate every registered sensor model on equal cells along one ray for an error model "
            f"(from `prismap characterise`) and write {', '.join(FILES.values())} into --out. Single-noise "
            "models (convolution, andert) take the sigma of the mixture's largest-weight component."
        ),
    )
    compare.add_argument("--error-model", required=True, type=Path, metavar="MODEL.json",
                         help="error model written by `prismap characterise`")
    add_out(compare, file=False, required=True, metavar="DIR", help="output directory")
    compare.add_argument("--camera", choices=sorted(_cameras()), default=None,
                         help="rig (default middlebury-motorcycle unless --focal-px/--baseline-m are given)")
    compare.add_argument("--focal-px", type=float, default=None, metavar="F", help="focal length (pixels)")
    compare.add_argument("--baseline-m", type=float, default=None, metavar="B", help="baseline (metres)")
    compare.add_argument("--voxel", type=float, default=0.1, metavar="M", help="cell size in metres (default 0.1)")
    compare.add_argument("--p0", type=float, default=0.05, help="prior occupancy of one cell (default 0.05)")
    compare.add_argument("--distances", default="2,5,10,20", metavar="LIST",
                         help="measured distances in metres, comma-separated (default 2,5,10,20)")
    compare.add_argument("--perf-stride", type=int, default=8, metavar="N",
                         help="timing batch: every N-th pixel of a 640x480 frame (default 8; 1 = full frame)")
    compare.set_defaults(func=run)


def _cameras():
    from prismap.study import CAMERAS

    return CAMERAS


def parse_distances(text):
    """``"2,5,10"`` -> [2.0, 5.0, 10.0]; every value positive and finite."""
    try:
        values = [float(item) for item in str(text).split(",") if item.strip()]
    except ValueError:
        raise PrismapInputError(f"--distances: expected comma-separated metres such as 2,5,10,20; got {text!r}") from None
    if not values or not all(np.isfinite(v) and v > 0 for v in values):
        raise PrismapInputError(f"--distances: expected positive distances in metres; got {text!r}")
    return sorted(values)


def _camera(args):
    """(focal_px, baseline_m, doffs_px, label) from --camera or --focal-px/--baseline-m."""
    custom = (args.focal_px, args.baseline_m)
    if args.camera is not None and any(v is not None for v in custom):
        raise PrismapInputError("give either --camera or --focal-px with --baseline-m, not both")
    if any(v is not None for v in custom):
        if None in custom:
            raise PrismapInputError("--focal-px and --baseline-m must be given together")
        return check_positive(args.focal_px, "--focal-px"), check_positive(args.baseline_m, "--baseline-m"), 0.0, "custom"
    name = args.camera or "middlebury-motorcycle"
    rig = _cameras()[name]
    return rig["focal_px"], rig["baseline_m"], rig["doffs_px"], name


def run(args):
    """Run the study and write figures and tables; return the exit status."""
    from prismap.characterise import load_error_model
    from prismap.plots import (
        plot_divergence,
        plot_influence,
        plot_prism_sweeps,
        plot_ray_profiles,
    )
    from prismap.study import (
        RaySetup,
        compare_models,
        influence_distances,
        prism_sweeps,
        time_models,
    )

    distances = parse_distances(args.distances)
    voxel = check_positive(args.voxel, "--voxel")
    p0 = check_probability(args.p0, "--p0")
    if args.perf_stride < 1:
        raise PrismapInputError(f"--perf-stride must be >= 1; got {args.perf_stride}")
    focal, baseline, doffs, camera = _camera(args)
    error_model = load_error_model(args.error_model)
    mixture = error_model.mixture
    setup = RaySetup(focal_baseline=focal * baseline, doffs_px=doffs, voxel_size_m=voxel, p0=p0)
    for s in distances:
        setup.disparity_at(s)  # fail early on distances the camera cannot resolve
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {key: out / name for key, name in FILES.items()}

    steps = progress(total=5, desc="models compare", unit="step")
    comparison = compare_models(mixture, distances, setup=setup)
    plot_ray_profiles(comparison, path=paths["profiles"])
    steps.update()
    by_g = {fit.n_components: fit.mixture for fit in error_model.fits}
    sweeps = prism_sweeps(mixture, setup=setup, distances_m=distances, reference_m=float(np.median(distances)),
                          mixtures_by_components=by_g)
    plot_prism_sweeps(sweeps, path=paths["sweeps"])
    steps.update()
    influence = influence_distances(mixture, np.linspace(1.0, 1.5 * max(distances), 16), setup=setup)
    plot_influence(*influence, path=paths["influence"])
    steps.update()
    plot_divergence(comparison, path=paths["divergence"])
    steps.update()
    performance = time_models(mixture, setup=setup, focal_px=focal, stride=args.perf_stride)
    steps.update()
    steps.close()

    header = (f"Error model {args.error_model} ({error_model.matcher} on {error_model.dataset}, G = "
              f"{error_model.selected_components}); camera {camera}: f*b = {setup.focal_baseline:.3f} px*m, "
              f"doffs = {doffs:g} px; cells of {voxel:g} m, p0 = {p0:g}; single-noise sigma "
              f"{comparison.noise_sigma_px:.3f} px (largest-weight component).")
    influence_rows = ["| measured (m) | bound behind (m) | observed behind (m) |", "|---:|---:|---:|"]
    influence_rows += [f"| {m:.2f} | {b:.2f} | {o:.2f} |" for m, b, o in zip(*influence)]
    tables = "\n".join([
        "# Sensor models against PRISM", "", header, "",
        "## Divergence from PRISM", "",
        "Over the cells either model updates, from the camera to the larger influence depth. Cleared occupancy: "
        "PRISM's expected occupied cells among those the model pushes toward free.", "",
        comparison.to_markdown(), "## PRISM's maximum influence distance", "", "\n".join(influence_rows), "",
        "## Performance", "", performance.to_markdown(),
    ])
    write_text_atomic(paths["tables"], tables)
    record = {"error_model": str(args.error_model), "camera": camera, "comparison": comparison.to_dict(),
              "influence": {k: v.tolist() for k, v in zip(("measured_m", "bound_m", "observed_m"), influence)},
              "performance": performance.to_dict()}
    write_text_atomic(paths["json"], json.dumps(record, indent=2) + "\n")
    print(header)
    print(comparison.to_markdown())
    print(performance.to_markdown())
    for path in paths.values():
        print(f"wrote {path}")
    return 0
