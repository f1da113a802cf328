"""``prismap characterise``: measure a matcher's disparity errors on data with ground truth, fit mixtures."""

import math
from pathlib import Path

import numpy as np

from prismap._validate import check_positive
from prismap.cli._args import add_out, seed
from prismap.cli._bag import add_bag_arguments, open_bag_argument
from prismap.errors import PrismapInputError

MOTORCYCLE = "middlebury-motorcycle"


def register(subparsers):
    """Add the ``characterise`` parser."""
    parser = subparsers.add_parser(
        "characterise",
        help="fit Gaussian-mixture error models to a stereo matcher's disparity errors",
        description=(
            "Run a stereo matcher on frames with ground-truth disparity, histogram its errors "
            "e = d_true - d_computed, fit Gaussian mixtures with G = 1..max-components by EM and write "
            "error_model.json, table.md, errors.png and errors_wide.png (and errors_classes.png for a conditioned "
            "model) into --out. The matcher's disparity "
            "search range is set to cover the largest ground-truth disparity."
        ),
    )
    parser.add_argument(
        "--dataset",
        metavar="NAME|PATH",
        help=f"'{MOTORCYCLE}' (bundled with scikit-image) or a folder, its kind recognised from "
        "the layout: a Middlebury scene or folder of scenes, a KITTI stereo 2012/2015 training "
        "folder, a KITTI-layout sequence with disp/, a KITTI odometry sequence or raw drive "
        "(Velodyne scans projected into the left camera), New Tsukuba (or --bag)",
    )
    parser.add_argument(
        "--frames",
        metavar="A:B",
        default=None,
        help="frames A up to (excluding) B of the dataset, Python-style (default all; negative A as --frames=-10:)",
    )
    parser.add_argument("--every", type=int, default=1, metavar="K", help="every K-th of those frames (default 1)")
    parser.add_argument(
        "--kitti-disparity",
        choices=("noc", "occ"),
        default="noc",
        help="KITTI stereo ground truth: non-occluded pixels only (noc, default) or also occluded ones (occ)",
    )
    parser.add_argument("--matcher", required=True, choices=("bm", "sgbm", "variational"))
    parser.add_argument("--max-components", type=int, default=4, metavar="G", help="largest G fitted (default 4)")
    add_out(parser, file=False, required=True, metavar="DIR", help="output directory")
    parser.add_argument(
        "--bin-width", type=float, default=1 / 32, metavar="PX", help="histogram bin width in pixels (default 1/32)"
    )
    parser.add_argument("--lr-check", action="store_true", help="invalidate pixels failing the left-right check")
    parser.add_argument(
        "--criterion",
        choices=("bic", "aic"),
        default="bic",
        help="selection criterion of G with --plain (default bic; a conditioned model chooses every G "
        "by held-out log-likelihood)",
    )
    parser.add_argument(
        "--tolerance",
        type=float,
        default=0.01,
        metavar="NATS",
        help="with --plain, select the smallest G within this many nats per error of the best (default 0.01)",
    )
    parser.add_argument("--seed", type=seed, default=0, help="seed of the EM restarts (default 0)")
    parser.add_argument(
        "--plain",
        dest="conditioned",
        action="store_false",
        help="one whole-image mixture; default: classes of pixels by confidence features, chosen by "
        "held-out log-likelihood (the plain model is one candidate), one mixture per class",
    )
    parser.add_argument(
        "--max-classes", type=int, metavar="K", help="most error classes of a conditioned model (default 24)"
    )
    parser.add_argument(
        "--search-frames",
        type=int,
        metavar="N",
        help="frames, evenly spread, whose pixels the class search samples; every frame fills the "
        "class histograms (default 16)",
    )
    parser.add_argument(
        "--max-samples",
        type=int,
        metavar="N",
        help="most pixels the class search keeps, so memory does not grow with the frames (default 4000000)",
    )
    own = parser.add_argument_group(
        "self-characterisation",
        "no ground truth: each frame's errors against the other frames' disparities carried "
        "into it by the poses (docs/SENSOR_MODELS.md, Self-characterisation)",
    )
    own.add_argument(
        "--self",
        dest="self_",
        action="store_true",
        help="characterise from the consistency of a posed sequence (--sequence DIR, or --bag with "
        '--pose-topic or --tf-frames); writes the same error-model files, source "self"',
    )
    own.add_argument("--sequence", type=Path, metavar="DIR", help="with --self: a sequence directory with poses.txt")
    own.add_argument(
        "--min-lag",
        type=int,
        metavar="K",
        help="fewest frames between a frame and those making its reference (default: the smallest lag "
        "at which frames disagree as much as distant ones, measured)",
    )
    own.add_argument(
        "--references",
        type=int,
        default=4,
        metavar="N",
        help="frames whose carried disparities make each reference, their median (default 4)",
    )
    own.add_argument(
        "--max-disparity",
        type=float,
        metavar="PX",
        help="with --self: the matcher's search range (default: the matcher's own)",
    )
    add_bag_arguments(parser, poses=True, truth=True)
    parser.set_defaults(func=run)


def run(args):
    """Characterise the matcher on the dataset and write the results; return the exit status."""
    from prismap.characterise import characterise_matcher
    from prismap.stereo import make_matcher

    bin_width = check_positive(args.bin_width, "--bin-width")
    if args.max_components < 1:
        raise PrismapInputError(f"`--max-components` must be >= 1; got {args.max_components}")
    for option in ("max_classes", "search_frames", "max_samples"):
        if getattr(args, option) is not None and getattr(args, option) < 1:
            raise PrismapInputError(f"`--{option.replace('_', '-')}` must be >= 1; got {getattr(args, option)}")
    if args.self_:
        return _run_self(args, bin_width)
    if args.sequence is not None:
        raise PrismapInputError("--sequence is the input of --self; with ground truth give --dataset PATH")
    if (args.dataset is None) == (args.bag is None):
        raise PrismapInputError("give exactly one of --dataset NAME|PATH and --bag PATH")
    if args.bag is not None and not (args.truth_topic or args.lidar_topic):
        raise PrismapInputError(
            "--bag: characterising needs ground truth; give --truth-topic TOPIC or --lidar-topic TOPIC"
        )
    frames = _load_frames(args)
    args.dataset = args.dataset or str(args.bag)
    options = {"left_right_check": True} if args.lr_check else {}
    options.update(_search_range(args.matcher, frames))
    try:
        matcher = make_matcher(args.matcher, **options)
    except TypeError:
        raise PrismapInputError(f"--lr-check: matcher {args.matcher!r} has no left-right check option") from None
    result = characterise_matcher(
        frames,
        matcher,
        max_components=args.max_components,
        bin_width=bin_width,
        dataset=args.dataset,
        criterion=args.criterion,
        tolerance=args.tolerance,
        seed=args.seed,
        conditioned=args.conditioned,
        source="lidar" if args.lidar_topic else "ground-truth",
        **{
            name: getattr(args, name)
            for name in ("max_classes", "search_frames", "max_samples")
            if getattr(args, name) is not None
        },
    )
    _report(args, result)
    return 0


def _report(args, result):
    """Write the characterisation's files into ``--out`` and print its summary."""
    from prismap.characterise import write_characterisation

    paths = write_characterisation(result, args.out)
    stats = result.histogram.statistics()
    mixture = result.mixture
    print(
        f"{args.matcher} on {result.model.dataset}: {stats['n_errors']} errors, coverage {stats['coverage']:.3f}, "
        f"bad-2px {stats['bad_2px']:.3f}; selected G = {result.model.selected_components}"
    )
    for weight, mean, sigma in zip(mixture.weights, mixture.means, mixture.sigmas):
        print(f"  w = {weight:.3f}  mu = {mean:+.3f} px  sigma = {sigma:.3f} px")
    record = result.model.class_selection
    if record:
        print(
            f"held-out log-likelihood ({record['held_out']}): plain {record['plain_nats_per_error']:.4f}, "
            f"chosen {record['conditioned_nats_per_error']:.4f} nats per error; "
            f"{result.model.n_classes} class(es) on {list(result.model.classes.features) or 'no feature'}"
        )
    for path in paths.values():
        print(f"wrote {path}")


def _run_self(args, bin_width):
    """``--self``: characterise the matcher from the consistency of a posed sequence; return the exit status."""
    from prismap.characterise import self_characterise
    from prismap.io import read_sequence
    from prismap.stereo import make_matcher

    if args.dataset is not None or args.truth_topic or args.lidar_topic:
        raise PrismapInputError("--self uses no ground truth: drop --dataset, --truth-topic and --lidar-topic")
    if (args.sequence is None) == (args.bag is None):
        raise PrismapInputError("--self: give exactly one of --sequence DIR and --bag PATH")
    if args.bag is not None:
        if not (args.pose_topic or args.tf_frames):
            raise PrismapInputError("--self --bag: needs poses; give --pose-topic TOPIC or --tf-frames WORLD:CAMERA")
        frames, source = open_bag_argument(args), str(args.bag)
    else:
        frames, source = read_sequence(args.sequence), str(args.sequence)
        if frames.poses is None:
            raise PrismapInputError(
                f"--sequence {args.sequence}: no poses.txt; --self carries disparities between frames by their poses"
            )
    options = {"left_right_check": True} if args.lr_check else {}
    if args.max_disparity is not None:
        largest = check_positive(args.max_disparity, "--max-disparity")
        options.update(_range_options(args.matcher, largest, frames.camera.width))
    try:
        matcher = make_matcher(args.matcher, **options)
    except TypeError:
        raise PrismapInputError(f"--lr-check: matcher {args.matcher!r} has no left-right check option") from None
    result = self_characterise(
        frames,
        matcher,
        min_lag=args.min_lag,
        n_references=args.references,
        max_components=args.max_components,
        bin_width=bin_width,
        dataset=source,
        criterion=args.criterion,
        tolerance=args.tolerance,
        seed=args.seed,
        conditioned=args.conditioned,
        **{
            name: getattr(args, name)
            for name in ("max_classes", "search_frames", "max_samples")
            if getattr(args, name) is not None
        },
    )
    record = result.record
    print(
        f"self-characterised from {record['n_frames']} frames: references from {record['n_references']} frames at "
        f"least {record['min_lag']} apart ({record['mean_references']:.2f} per pixel on average), reference noise "
        f"{record['reference_variance_px2'] ** 0.5:.3f} px removed"
    )
    _report(args, result.characterisation)
    return 0


def _load_frames(args):
    """The selected frames of ``--dataset`` or ``--bag`` (a lazy :class:`prismap.io.GroundTruthFrames`)."""
    from prismap.io import GroundTruthFrames, open_ground_truth

    if args.bag is not None:
        bag = open_bag_argument(args)
        return GroundTruthFrames(bag, "rosbag", str(args.bag), range(len(bag)))
    return open_ground_truth(args.dataset, frames=args.frames, every=args.every, kitti_disparity=args.kitti_disparity)


def _search_range(matcher_name, frames):
    """Matcher options whose disparity range covers the largest ground-truth disparity of the frames.

    The largest disparity comes from a pass over the ground truth alone (no frame is kept), bounded by
    each image's width. The range stays below the first frame's width (no match can lie farther; the
    matchers refuse a range that reaches it), so a disparity within 16 px of the width is searched
    up to the last multiple of 16 below it.
    """
    largest = frames.max_disparity_px()
    return _range_options(matcher_name, largest, np.shape(frames.disparity_gt(0))[1])


def _range_options(matcher_name, largest, width):
    """Matcher options searching disparities up to ``largest`` (pixels) in images ``width`` pixels wide."""
    if matcher_name == "variational":
        return {"max_disparity": float(min(math.ceil(largest) + 1, width - 1))}
    if width <= 16:
        raise PrismapInputError(
            f"--dataset: images {width} px wide leave no disparity search range "
            f"({matcher_name} searches in steps of 16 px, below the image width)"
        )
    return {"num_disparities": min(16 * math.ceil((largest + 1) / 16), 16 * ((width - 1) // 16))}
