"""``prismap lidar-truth``: ground-truth occupancy from a KITTI drive's Velodyne scans (thesis sec. 6.3.3)."""

import math
from pathlib import Path

from prismap._validate import check_positive
from prismap.cli._args import add_out
from prismap.errors import PrismapInputError


def register(subparsers):
    """Add the ``lidar-truth`` parser."""
    parser = subparsers.add_parser(
        "lidar-truth",
        help="ground-truth occupancy from a KITTI drive's Velodyne scans",
        description=(
            "Build a LiDAR reference map from the Velodyne scans of a KITTI odometry sequence (--kitti ROOT "
            "--sequence NN, poses from ROOT/poses/NN.txt) or raw drive (--raw DRIVE_DIR --poses FILE) and write it "
            "as ground-truth occupancy for 'prismap evaluate --gt' (atomically). Each point is a noise-free ray "
            "cast from the laser's origin, posed in the world of the left colour camera (image_2; KITTI's "
            "camera 0 of the first frame for odometry poses): the voxel holding the point gets a hit, the voxels "
            "it crosses a miss (OctoMap's insertPointCloud: p_hit 0.7, p_miss 0.4, occupied-wins within a scan, "
            "prior 0.5). By default only the points in front of the colour camera that project into its image "
            "are used, the part of the 360-degree scan a stereo map can see (--full-scan keeps all). Scored "
            "voxels are the ones these rays reached: occupied where the accumulated probability exceeds 0.5, "
            "free otherwise; voxels no ray touched (behind surfaces, beyond --max-range, outside the "
            "view) are not scored."
        ),
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--kitti", type=Path, metavar="ROOT", help="KITTI odometry root (sequences/, poses/)")
    source.add_argument(
        "--raw", type=Path, metavar="DRIVE_DIR", help="KITTI raw drive (e.g. 2011_09_26_drive_0001_sync)"
    )
    parser.add_argument("--sequence", metavar="NN", help="odometry sequence number (with --kitti)")
    parser.add_argument(
        "--calib-dir",
        type=Path,
        metavar="DIR",
        help="folder of calib_cam_to_cam.txt and calib_velo_to_cam.txt (with --raw; default the drive's parent)",
    )
    parser.add_argument(
        "--poses",
        type=Path,
        metavar="FILE",
        help="one 3x4 row-major T_world_cam per frame of the left colour camera (image_2, as in "
        "prismap's poses.txt); needed for --raw, replaces poses/NN.txt with --kitti",
    )
    parser.add_argument("--voxel", required=True, type=float, metavar="M", help="voxel size in metres")
    parser.add_argument("--frames", default=":", metavar="A:B", help="frames A <= i < B (default all)")
    parser.add_argument(
        "--every", type=int, default=1, metavar="K", help="use every K-th frame of the range (default 1)"
    )
    parser.add_argument(
        "--max-range",
        type=float,
        default=math.inf,
        metavar="M",
        help="points farther from the laser only clear free space up to this range (default: none)",
    )
    parser.add_argument("--full-scan", action="store_true", help="use the whole scan, not only the camera's view")
    add_out(parser, file=True, required=True, metavar="TRUTH.npz", help="output ground-truth file")
    parser.set_defaults(func=run)


def run(args):
    """Build the reference map and write its ground truth; return the exit status."""
    from prismap.cli._map import parse_frames
    from prismap.io import read_kitti_poses, write_ground_truth
    from prismap.pipeline import ground_truth_from_map, lidar_reference_map
    from prismap.pipeline._lidar import kitti_lidar_scans

    voxel = check_positive(args.voxel, "--voxel")
    max_range = math.inf if args.max_range == math.inf else check_positive(args.max_range, "--max-range")
    if args.every < 1:
        raise PrismapInputError(f"--every must be >= 1; got {args.every}")
    start, stop = parse_frames(args.frames)
    sequence, velodyne_dir = _open_sequence(args)
    if not velodyne_dir.is_dir():
        raise PrismapInputError(f"{velodyne_dir}: Velodyne scan folder not found (KITTI's velodyne .bin files)")
    poses = None
    if args.poses is not None:
        poses = read_kitti_poses(args.poses)
        if len(poses) != len(sequence):
            raise PrismapInputError(f"--poses {args.poses}: {len(poses)} poses for {len(sequence)} frames")
    frames = range(len(sequence))[start : stop : args.every]
    if not frames:
        raise PrismapInputError(f"--frames {args.frames}: no frame of the {len(sequence)} in the sequence lies in it")
    scans = kitti_lidar_scans(sequence, frames=frames, poses=poses, camera_view=not args.full_scan)
    grid = lidar_reference_map(scans, voxel, max_range_m=max_range)
    truth = ground_truth_from_map(grid)
    write_ground_truth(args.out, truth)
    n_occupied = len(truth.observed_occupied_keys)
    print(
        f"{len(scans)} scans, voxel {voxel} m: {len(truth.observed_keys)} voxels observed, {n_occupied} occupied, "
        f"{len(truth.observed_keys) - n_occupied} free; wrote {args.out}"
    )
    return 0


def _open_sequence(args):
    """The KITTI sequence of ``--kitti``/``--raw`` and its Velodyne folder."""
    from prismap.io import KittiOdometry, KittiRaw

    if args.kitti is not None:
        if args.sequence is None:
            raise PrismapInputError("--kitti needs --sequence NN (the odometry sequence number)")
        if args.calib_dir is not None:
            raise PrismapInputError("--calib-dir belongs to --raw; an odometry sequence has its own calib.txt")
        sequence = KittiOdometry(args.kitti, args.sequence, load_poses=args.poses is None)
        seq_dir = args.kitti / "sequences" / f"{int(args.sequence):02d}"
        if args.poses is None and sequence.poses is None:
            raise PrismapInputError(
                f"--kitti {args.kitti}: sequence {args.sequence} has no poses/"
                f"{int(args.sequence):02d}.txt (KITTI has them for 00-10); give --poses FILE"
            )
        return sequence, seq_dir / "velodyne"
    if args.sequence is not None:
        raise PrismapInputError("--sequence belongs to --kitti; a raw drive is named by its folder")
    if args.poses is None:
        raise PrismapInputError(
            f"--raw {args.raw}: a raw drive has no camera poses; give --poses FILE "
            "(T_world_cam of image_2 per frame, 3x4 row-major lines)"
        )
    return KittiRaw(args.raw, calib_dir=args.calib_dir), args.raw / "velodyne_points" / "data"
