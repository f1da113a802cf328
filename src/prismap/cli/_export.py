"""``prismap export``: a map file to the formats robot tools open (PLY, OctoMap, PointCloud2 in MCAP or a ROS 2 bag)."""

from pathlib import Path

from prismap._files import check_output
from prismap.errors import PrismapInputError

FORMATS = {".ply": "ply", ".ot": "ot", ".bt": "bt", ".mcap": "mcap"}
"""Format of each output suffix; a ROS 2 bag directory takes ``--format rosbag2``."""


def register(subparsers):
    """Add the ``export`` parser."""
    parser = subparsers.add_parser(
        "export",
        help="write a map to .ply, OctoMap .ot/.bt, or a PointCloud2 in MCAP / a ROS 2 bag",
        description=(
            "Write MAP.npz to --to, in the format of its suffix: .ply (occupied voxel centres with their probability), "
            ".ot (OctoMap, full log-odds), .bt (OctoMap, free/occupied), .mcap (one sensor_msgs/PointCloud2 of the "
            "known voxels' centres, fields x y z probability, float32, for Foxglove and RViz); --format rosbag2 "
            "writes that PointCloud2 into a new ROS 2 bag directory (--storage mcap or sqlite3). Files are written "
            "atomically; an existing bag directory is refused."
        ),
    )
    parser.add_argument("map", type=Path, metavar="MAP.npz", help="map file (prismap map)")
    parser.add_argument("--to", required=True, type=Path, metavar="PATH", help="output file or bag directory")
    parser.add_argument(
        "--format",
        choices=(*sorted(set(FORMATS.values())), "rosbag2"),
        help="output format (default: from the suffix of --to)",
    )
    parser.add_argument(
        "--storage",
        choices=("mcap", "sqlite3"),
        default="mcap",
        help="storage of a --format rosbag2 bag (default mcap)",
    )
    parser.add_argument("--frame-id", default="map", help="PointCloud2 header.frame_id (default map)")
    parser.add_argument("--topic", default="/prismap/map", help="PointCloud2 topic (default /prismap/map)")
    parser.add_argument(
        "--min-probability",
        type=float,
        metavar="P",
        help="PointCloud2: keep voxels with P(occupied) >= P (default: every known voxel)",
    )
    parser.set_defaults(func=run)


def run(args):
    """Export the map; return the exit status."""
    from prismap.io import load_map, write_octomap, write_ply, write_pointcloud2

    kind = args.format or FORMATS.get(args.to.suffix)
    if kind is None:
        raise PrismapInputError(
            f"--to {args.to}: cannot tell the format from the suffix {args.to.suffix!r}; use one of "
            f"{sorted(FORMATS)} or --format rosbag2 for a ROS 2 bag directory"
        )
    if kind in FORMATS.values() and args.to.suffix != f".{kind}":
        raise PrismapInputError(f"--to {args.to}: --format {kind} files end in .{kind}")
    if kind == "rosbag2" and args.to.suffix in FORMATS:
        raise PrismapInputError(
            f"--to {args.to}: a ROS 2 bag is a directory; its name must not end in {args.to.suffix}"
        )
    check_output(args.to, "--to", directory=kind == "rosbag2", inputs=[("the map file", args.map)])
    grid = load_map(args.map)
    if kind == "ply":
        count = write_ply(grid, args.to)
        what = "occupied voxels"
    elif kind in ("ot", "bt"):
        write_octomap(grid, args.to)
        count, what = grid.n_known, "known voxels"
    else:
        count = write_pointcloud2(
            grid,
            args.to,
            storage=args.storage,
            frame_id=args.frame_id,
            topic=args.topic,
            min_probability=args.min_probability,
        )
        what = f"points on {args.topic} (frame {args.frame_id})"
    print(f"wrote {args.to} ({kind}): {count} {what}")
    return 0
