"""The ``--bag`` options shared by ``prismap map`` and ``prismap characterise``: a ROS bag as the input sequence."""

from pathlib import Path

from prismap.errors import PrismapInputError

MAX_STAMP_GAP_S = 86400.0
"""Largest ``--pair-tolerance`` and ``--pose-gap`` (seconds, one day): a bag's stamps are int64 nanoseconds."""


def add_bag_arguments(parser, *, poses, truth=False):
    """Add ``--bag`` and its topic options to ``parser``.

    ``poses`` (``prismap map``) adds ``--pose-topic``/``--tf-frames``/``--pose-gap`` and names ``--sequence`` as
    the input the bag replaces; without it (``prismap characterise``) the bag replaces ``--dataset``. ``truth``
    adds ``--truth-topic``.
    """
    from prismap.io._rosbag import MAX_POSE_GAP_S, PAIR_TOLERANCE_S

    instead = "--sequence" if poses else "--dataset"
    group = parser.add_argument_group(
        "ROS bag input", f"a ROS 1 .bag, a ROS 2 bag directory (sqlite3 or MCAP) or a .mcap file instead of {instead}"
    )
    group.add_argument("--bag", type=Path, metavar="PATH", help="the bag")
    group.add_argument("--left", metavar="TOPIC", help="left image topic (sensor_msgs/Image or CompressedImage)")
    group.add_argument("--right", metavar="TOPIC", help="right image topic")
    group.add_argument("--left-info", metavar="TOPIC", help="left CameraInfo (default: <left namespace>/camera_info)")
    group.add_argument(
        "--right-info", metavar="TOPIC", help="right CameraInfo (default: <right namespace>/camera_info)"
    )
    group.add_argument(
        "--rectified",
        choices=("auto", "yes", "no"),
        default="auto",
        help="images already rectified? auto: yes for image_rect topics or an identity calibration",
    )
    group.add_argument(
        "--pair-tolerance",
        type=float,
        default=PAIR_TOLERANCE_S,
        metavar="S",
        help=f"largest left-right stamp difference, seconds (default {PAIR_TOLERANCE_S})",
    )
    if poses:
        source = group.add_mutually_exclusive_group()
        source.add_argument(
            "--pose-topic",
            metavar="TOPIC",
            help="nav_msgs/Odometry or geometry_msgs/PoseStamped topic with the left camera's pose",
        )
        source.add_argument("--tf-frames", metavar="WORLD:CAMERA", help="compose the /tf + /tf_static chain instead")
        group.add_argument(
            "--pose-gap",
            type=float,
            default=MAX_POSE_GAP_S,
            metavar="S",
            help=f"largest spacing of the pose samples around an image stamp (default {MAX_POSE_GAP_S})",
        )
    if truth:
        group.add_argument(
            "--lidar-topic",
            metavar="TOPIC",
            help="ground truth from a LiDAR's sensor_msgs/PointCloud2 scans (nearest in time to each "
            "left image; moved by the pose source between the two stamps when one is given; "
            "points hidden from the camera dropped)",
        )
        group.add_argument(
            "--lidar-extrinsics",
            type=Path,
            metavar="FILE",
            help="LiDAR -> left camera transform: one line of 12 numbers, the 3x4 [R | t] row by row "
            "(default: from /tf_static)",
        )
        group.add_argument(
            "--scan-tolerance",
            type=float,
            default=0.05,
            metavar="S",
            help="largest stamp difference of an image and its LiDAR scan, seconds (default 0.05)",
        )
        group.add_argument(
            "--truth-topic",
            metavar="TOPIC",
            help="ground truth: stereo_msgs/DisparityImage or depth image (32FC1 m, 16UC1 mm)",
        )


def open_bag_argument(args):
    """The :class:`~prismap.io.BagSequence` the ``--bag`` options describe (``args.bag`` must be set)."""
    from prismap.io import read_bag

    if not (args.left and args.right):
        raise PrismapInputError("--bag needs --left TOPIC and --right TOPIC")
    for option in ("pair_tolerance", "pose_gap", "scan_tolerance"):
        value = getattr(args, option, 1.0)
        if not 0 < value <= MAX_STAMP_GAP_S:
            raise PrismapInputError(
                f"--{option.replace('_', '-')} must lie in (0, {MAX_STAMP_GAP_S:g}] seconds; got {value}"
            )
    tf_frames = None
    if getattr(args, "tf_frames", None):
        world, sep, camera = args.tf_frames.partition(":")
        if not (sep and world and camera):
            raise PrismapInputError(f"--tf-frames {args.tf_frames!r}: expected WORLD:CAMERA frame ids")
        tf_frames = (world, camera)
    options = {
        "pose_topic": getattr(args, "pose_topic", None),
        "tf_frames": tf_frames,
        "truth_topic": getattr(args, "truth_topic", None),
    }
    if getattr(args, "lidar_topic", None):
        options.update(
            lidar_topic=args.lidar_topic,
            scan_tolerance_s=args.scan_tolerance,
            T_cam_lidar=None if args.lidar_extrinsics is None else read_extrinsics(args.lidar_extrinsics),
        )
    elif getattr(args, "lidar_extrinsics", None) is not None:
        raise PrismapInputError("--lidar-extrinsics is the transform of --lidar-topic; give the topic too")
    if hasattr(args, "pose_gap"):
        options["max_pose_gap_s"] = args.pose_gap
    return read_bag(
        args.bag,
        left=args.left,
        right=args.right,
        left_info=args.left_info,
        right_info=args.right_info,
        rectified={"auto": None, "yes": True, "no": False}[args.rectified],
        pair_tolerance_s=args.pair_tolerance,
        **options,
    )


def read_extrinsics(path):
    """The LiDAR -> camera transform of ``--lidar-extrinsics``: one line of the 3x4 ``[R | t]``, as (4, 4) float64."""
    from prismap._validate import check_pose
    from prismap.io._text import homogeneous, read_number_rows

    rows = read_number_rows(path, "LiDAR extrinsics", 12, layout="3x4 [R | t] of T_cam_lidar")
    if len(rows) != 1:
        raise PrismapInputError(f"{path}: LiDAR extrinsics must be one line of 12 numbers; got {len(rows)} lines")
    return check_pose(homogeneous(rows.reshape(3, 4)), f"{path}: LiDAR extrinsics")
