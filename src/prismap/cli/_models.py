"""``prismap models compare``: every inverse sensor model along one ray, judged against PRISM."""

from pathlib import Path

import numpy as np

from prismap._validate import check_positive, check_probability
from prismap.camera import StereoCamera
from prismap.cli._args import add_out
from prismap.errors import PrismapInputError


def register(subparsers):
    """Add the ``models`` parser and its ``compare`` sub-command."""
    parser = subparsers.add_parser("models", help="study the inverse sensor models along one ray")
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    compare = actions.add_parser(
        "compare",
        help="profiles, PRISM sweeps, influence distance and divergences from PRISM",
        description=(
            "Evaluate every registered sensor model on equal cells along one ray for an error model "
            "(from `prismap characterise`) and write profiles.png, prism_sweeps.png, influence.png, divergence.png, "
            "tables.md and models_compare.json into --out. Single-noise "
            "models (convolution, andert) take the sigma of the mixture's largest-weight component."
        ),
    )
    compare.add_argument(
        "--error-model",
        required=True,
        type=Path,
        metavar="MODEL.json",
        help="error model written by `prismap characterise`",
    )
    add_out(compare, file=False, required=True, metavar="DIR", help="output directory")
    compare.add_argument(
        "--camera",
        choices=sorted(_cameras()),
        default=None,
        help="rig (default middlebury-motorcycle unless --focal-px/--baseline-m are given)",
    )
    compare.add_argument("--focal-px", type=float, default=None, metavar="F", help="focal length (pixels)")
    compare.add_argument("--baseline-m", type=float, default=None, metavar="B", help="baseline (metres)")
    compare.add_argument("--voxel", type=float, default=0.1, metavar="M", help="cell size in metres (default 0.1)")
    compare.add_argument("--p0", type=float, default=0.05, help="prior occupancy of one cell (default 0.05)")
    compare.add_argument(
        "--distances",
        default="2,5,10,20",
        metavar="LIST",
        help="measured distances in metres, comma-separated (default 2,5,10,20)",
    )
    compare.set_defaults(func=run)


def _cameras():
    from prismap.study import CAMERAS

    return CAMERAS


def parse_distances(text):
    """``"2,5,10"`` -> [2.0, 5.0, 10.0]; every value positive and finite."""
    try:
        values = [float(item) for item in str(text).split(",") if item.strip()]
    except ValueError:
        raise PrismapInputError(
            f"--distances: expected comma-separated metres such as 2,5,10,20; got {text!r}"
        ) from None
    if not values or not all(np.isfinite(v) and v > 0 for v in values):
        raise PrismapInputError(f"--distances: expected positive distances in metres; got {text!r}")
    return sorted(values)


def _camera(args):
    """The rig name of --camera, or a StereoCamera from --focal-px/--baseline-m."""
    custom = (args.focal_px, args.baseline_m)
    if args.camera is not None and any(v is not None for v in custom):
        raise PrismapInputError("give either --camera or --focal-px with --baseline-m, not both")
    if any(v is not None for v in custom):
        if None in custom:
            raise PrismapInputError("--focal-px and --baseline-m must be given together")
        return StereoCamera(
            check_positive(args.focal_px, "--focal-px"), 0.0, 0.0, check_positive(args.baseline_m, "--baseline-m")
        )
    return args.camera or "middlebury-motorcycle"


def run(args):
    """Parse the options, run :func:`prismap.study.run_models_compare` and print its summary."""
    from prismap.characterise import load_error_model
    from prismap.study import run_models_compare

    distances = parse_distances(args.distances)
    voxel = check_positive(args.voxel, "--voxel")
    p0 = check_probability(args.p0, "--p0")
    camera = _camera(args)
    error_model = load_error_model(args.error_model)
    result = run_models_compare(
        error_model,
        args.out,
        camera=camera,
        voxel_size_m=voxel,
        p0=p0,
        distances_m=distances,
        source=str(args.error_model),
    )
    print(result.header)
    print(result.comparison.to_markdown())
    for path in result.paths.values():
        print(f"wrote {path}")
    return 0
