"""``prismap experiment``: map a synthetic world with every sensor model and score the maps against exact truth."""

from prismap.cli._args import add_out, seed


def register(subparsers):
    """Add the ``experiment`` parser."""
    parser = subparsers.add_parser(
        "experiment",
        help="map a synthetic world with every sensor model and score the maps",
        description=(
            "office2d: a stereo range scanner with errors drawn from a known SGBM-like mixture (PRISM's "
            "assumptions hold) through the 2-D office. scene3d: rendered stereo pairs of the 3-D indoor scene; "
            "each matcher (bm, sgbm, variational) is characterised on every 4th frame and maps the others. "
            "street3d: the same on a KITTI-like street (621x188 half-size rig, f 360 px, b 0.54 m) driven along. "
            "avenue3d: a second street world (620x188 rig, f 358 px, b 0.54 m; another layout and textures; 4 "
            "characterisation frames), where a model tuned on the street has to hold. "
            "Every model (ideal, hitmiss, convolution, andert, prism) maps the data with p0 = the ground "
            "truth's occupancy ratio; maps are scored on the voxels a perfect sensor observed. Writes "
            "results.md/.json, figures and per-cell results into --out; a rerun with the same options "
            "resumes (finished cells are reused)."
        ),
    )
    parser.add_argument(
        "--world", required=True, choices=("office2d", "scene3d", "street3d", "avenue3d"), help="which experiment"
    )
    add_out(parser, file=False, required=True, metavar="DIR", help="output directory")
    parser.add_argument("--frames", type=int, metavar="N", help="number of frames (default: the size's)")
    parser.add_argument("--voxel", type=float, metavar="M", help="voxel size in metres (default: the size's)")
    parser.add_argument("--seed", type=seed, default=0, help="seed of errors, scene and trajectory (default 0)")
    parser.add_argument("--quick", action="store_true", help="small sizes (seconds to a minute)")
    parser.add_argument(
        "--error-sources",
        action="store_true",
        help="scene3d/street3d: map with PRISM using error models from ground truth, a simulated "
        "LiDAR, self-characterisation of the mapping frames and Middlebury Motorcycle; "
        "writes sources.md/.json (bm and sgbm)",
    )
    parser.set_defaults(func=run)


def run(args):
    """Run the experiment and print its results table; return the exit status."""
    from prismap.experiment import run_office2d, run_rendered_world

    if args.error_sources:
        return _run_sources(args)
    options = {"n_frames": args.frames, "voxel_size_m": args.voxel, "seed": args.seed, "quick": args.quick}
    if args.world == "office2d":
        result = run_office2d(args.out, **options)
    else:
        result = run_rendered_world(args.world, args.out, **options)
    print((args.out / "results.md").read_text(encoding="utf-8"))
    for path, _ in result.artifacts:
        print(f"wrote {path}")
    return 0


def _run_sources(args):
    """``--error-sources``: the error-model sources compared on a 3-D world."""
    from prismap.errors import PrismapInputError
    from prismap.experiment import run_error_sources

    if args.world == "office2d":
        raise PrismapInputError("--error-sources needs a rendered world: --world scene3d or street3d")
    run_error_sources(args.world, args.out, quick=args.quick, n_frames=args.frames, seed=args.seed)
    print((args.out / "sources.md").read_text(encoding="utf-8"))
    return 0
