"""The ``--bag`` options shared by ``prismap map`` and ``prismap characterise``: a ROS bag as the input sequence."""

from pathlib import Path

from prismap.errors import PrismapInputError


def add_bag_arguments(parser, *, poses):
    """Add ``--bag`` and its topic options to ``parser``.

    ``poses`` (``prismap map``) adds ``--pose-topic``/``--tf-frames``/``--pose-gap`` and names ``--sequence`` as
    the input the bag replaces; without it (``prismap characterise``) the bag replaces ``--dataset``.
    """
    from prismap.io._rosbag import MAX_POSE_GAP_S, PAIR_TOLERANCE_S

    instead = "--sequence" if poses else "--dataset"
    group = parser.add_argument_group(
        "ROS bag input", f"a ROS 1 .bag, a ROS 2 bag directory (sqlite3 or MCAP) or a .mcap file instead of {instead}")
    group.add_argument("--bag", type=Path, metavar="PATH", help="the bag")
    group.add_argument("--left", metavar="TOPIC", help="left image topic (sensor_msgs/Image or CompressedImage)")
    group.add_argument("--right", metavar="TOPIC", help="right image topic")
    group.add_argument("--left-info", metavar="TOPIC", help="left CameraInfo (default: <left namespace>/camera_info)")
    group.add_argument("--right-info", metavar="TOPIC", help="right CameraInfo (default: <right namespace>/camera_info)")
    group.add_argument("--rectified", choices=("auto", "yes", "no"), default="auto",
                       help="images already rectified? auto: yes for image_rect topics or an identity calibration")
    group.add_argument("--pair-tolerance", type=float, default=PAIR_TOLERANCE_S, metavar="S",
                       help=f"largest left-right stamp difference, seconds (default {PAIR_TOLERANCE_S})")
    if poses:
        source = group.add_mutually_exclusive_group()
        source.add_argument("--pose-topic", metavar="TOPIC", help="nav_msgs/Odometry or geometry_msgs/PoseStamped "
                                                                  "topic with the left camera's pose")
        source.add_argument("--tf-frames", metavar="WORLD:CAMERA", help="compose the /tf + /tf_static chain instead")
        group.add_argument("--pose-gap", type=float, default=MAX_POSE_GAP_S, metavar="S",
                           help=f"largest spacing of the pose samples around an image stamp (default {MAX_POSE_GAP_S})")
    else:
        group.add_argument("--truth-topic", metavar="TOPIC",
                           help="ground truth: stereo_msgs/DisparityImage or depth image (32FC1 m, 16UC1 mm)")


def open_bag_argument(args):
    """The :class:`~prismap.io.BagSequence` the ``--bag`` options describe (``args.bag`` must be set)."""
    from prismap.io import read_bag

    if not (args.left and args.right):
        raise PrismapInputError("--bag needs --left TOPIC and --right TOPIC")
    for option in ("pair_tolerance", "pose_gap"):
        value = getattr(args, option, 1.0)
        if not value > 0:
            raise PrismapInputError(f"--{option.replace('_', '-')} must be > 0 seconds; got {value}")
    tf_frames = None
    if getattr(args, "tf_frames", None):
        world, sep, camera = args.tf_frames.partition(":")
        if not (sep and world and camera):
            raise PrismapInputError(f"--tf-frames {args.tf_frames!r}: expected WORLD:CAMERA frame ids")
        tf_frames = (world, camera)
    options = {"pose_topic": getattr(args, "pose_topic", None), "tf_frames": tf_frames,
               "truth_topic": getattr(args, "truth_topic", None)}
    if hasattr(args, "pose_gap"):
        options["max_pose_gap_s"] = args.pose_gap
    return read_bag(args.bag, left=args.left, right=args.right, left_info=args.left_info, right_info=args.right_info,
                    rectified={"auto": None, "yes": True, "no": False}[args.rectified],
                    pair_tolerance_s=args.pair_tolerance, **options)
