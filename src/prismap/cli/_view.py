"""``prismap view``: an occupancy map in the browser (viser), until interrupted."""

from pathlib import Path


def register(subparsers):
    """Add the ``view`` parser."""
    parser = subparsers.add_parser(
        "view",
        help="look at a map in 3-D in the browser",
        description=(
            "Serve an interactive 3-D view of MAP (a prismap .npz map) at http://HOST:PORT: voxels coloured by "
            "P(occupied) (viridis), a probability threshold, free/unknown/occupied toggles, a height range, "
            "the camera trajectory (--poses: map files do not record poses) and the ground truth beside the "
            "map (--gt), with the map's voxels coloured by their agreement with it (--colour agreement, or the "
            "'colour by' control). Maps beyond 2 M shown voxels are drawn 2^k times coarser (largest P per voxel). "
            "Runs until Ctrl-C."
        ),
    )
    parser.add_argument("map", type=Path, metavar="MAP", help="map file (.npz) from prismap map or experiment")
    parser.add_argument(
        "--gt", type=Path, metavar="TRUTH", help="ground-truth occupancy (.npz, e.g. SEQ/occupancy.npz)"
    )
    parser.add_argument(
        "--poses",
        type=Path,
        metavar="PATH",
        help="camera trajectory: a sequence folder or a poses.txt of 3x4 T_world_cam rows",
    )
    parser.add_argument(
        "--colour",
        choices=("probability", "agreement"),
        default="probability",
        help="colour the map's voxels by P(occupied) (default) or by agreement with --gt: correct "
        "occupied/free, occupied called free (danger), free called occupied",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8080, help="port (default 8080; 0 = any free port)")
    parser.set_defaults(func=run)


def run(args):
    """Load the inputs, serve the viewer until interrupted; return the exit status."""
    import time

    from prismap.errors import PrismapInputError
    from prismap.io import load_map, read_ground_truth
    from prismap.viewer import MapViewer, load_trajectory

    if not 0 <= args.port <= 65535:
        raise PrismapInputError(f"--port must lie in [0, 65535]; got {args.port}")
    grid = load_map(args.map)
    truth = read_ground_truth(args.gt) if args.gt is not None else None
    poses = load_trajectory(args.poses) if args.poses is not None else None
    try:
        viewer = MapViewer(
            grid, truth=truth, poses_w=poses, host=args.host, port=args.port, agreement=args.colour == "agreement"
        )
    except OSError as exc:
        raise PrismapInputError(
            f"--host {args.host} --port {args.port}: cannot listen ({exc.strerror or exc})"
        ) from None
    stats = viewer.stats
    print(
        f"viewing {args.map}: {stats['points']:,} points (voxels of {stats['voxel_m']:g} m), scene built in "
        f"{stats['build_s']:.2f} s",
        flush=True,
    )
    print(f"open http://{args.host}:{viewer.port}/ (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    finally:
        viewer.stop()
