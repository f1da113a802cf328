"""``prismap map``: integrate a stereo sequence into an occupancy map file, sequentially or on Dask, resumably."""

import ast
import contextlib
import json
import logging
import math
import shlex
import sys
from pathlib import Path

from prismap._cores import usable_cores
from prismap._files import write_text_atomic
from prismap._validate import check_positive, check_probability, parse_frame_range
from prismap.cli._args import add_out
from prismap.cli._bag import add_bag_arguments, open_bag_argument
from prismap.errors import PrismapInputError


def register(subparsers):
    """Add the ``map`` parser."""
    from prismap.grid import FLOOR_RAYS, MAP_READINGS, POLICIES
    from prismap.sensor_models import model_names
    from prismap.stereo import matcher_names

    parser = subparsers.add_parser(
        "map",
        help="build an occupancy map from a stereo sequence",
        description=(
            "Integrate the frames of a KITTI-layout stereo sequence (image_2, image_3, calib.txt, poses.txt; or a "
            "KITTI odometry ROOT/sequences/NN with its poses in ROOT/poses/NN.txt) "
            "into a sparse voxel occupancy map and write it to --out (.npz, atomically, only when complete). "
            "Disparities come from --matcher, or from --disparity-dir (uint16 PNG, value / 256 = px, 0 = "
            "invalid; SEQ/disp for the sequence's ground truth). With --checkpoint-every K the partial map is "
            "saved beside --out every K frames (OUT.checkpoint.npz/.json); the same command run again resumes "
            "from it, and refuses a checkpoint written with other options or inputs. A ROS bag is read with --bag "
            "(see the ROS bag options)."
        ),
    )
    parser.add_argument("--sequence", type=Path, metavar="DIR", help="sequence directory (or --bag)")
    add_bag_arguments(parser, poses=True)
    parser.add_argument("--matcher", default="sgbm", choices=matcher_names(), help="stereo matcher (default sgbm)")
    parser.add_argument(
        "--matcher-param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="matcher parameter, repeatable (e.g. num_disparities=64)",
    )
    parser.add_argument("--model", default="prism", choices=model_names(), help="inverse sensor model (default prism)")
    parser.add_argument(
        "--model-param",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="sensor model parameter, repeatable (e.g. p_hit=0.7)",
    )
    parser.add_argument(
        "--error-model",
        type=Path,
        metavar="MODEL.json",
        help="the matcher's error model (prismap characterise); needed by prism, and by "
        "convolution/andert without sigma_px (they take the largest-weight component's sigma). "
        "A conditioned model (with error classes) gives each pixel its class's mixture",
    )
    parser.add_argument(
        "--map-prior",
        action="store_true",
        help="prism: each cell's prior is the map's current probability, not --p0 (Kaufman et al. "
        "2016; the same as --model-param prior=map); ray mode, not on Dask",
    )
    parser.add_argument(
        "--plain",
        action="store_true",
        help="use the error model's whole-image mixture for every pixel, not its classes",
    )
    parser.add_argument(
        "--fusion",
        choices=MAP_READINGS,
        help="how the map reads its sums, from the error model's fusion block (the matcher's failure rate r "
        "and persistence q across views; docs/SENSOR_MODELS.md section 9): failure-mixture (the default when "
        "the block is there) reads r p0 + (1 - r) sigmoid(l), a failure that stays for every view, so every "
        "voxel stays within what one view can prove, [r p0, 1 - r (1 - p0)], in the order its evidence gives; "
        "failure-clamp clamps the sum to that range; persistent-failure reads the sums under the failure state "
        "of the fitted persistence; independent (the default without a block) is the plain sum of the frames' "
        "evidence",
    )
    parser.add_argument(
        "--strict-rig",
        action="store_true",
        help="refuse an error model made on another rig (focal length, baseline, image size, matcher "
        "or its parameters differ; default: print a warning naming both)",
    )
    parser.add_argument("--voxel", required=True, type=float, metavar="M", help="voxel size in metres")
    parser.add_argument("--p0", type=float, default=0.05, help="prior occupancy of a voxel (default 0.05)")
    parser.add_argument("--mode", choices=("ray", "projective"), default="ray", help="integration mode (default ray)")
    parser.add_argument("--policy", choices=POLICIES, help="per-frame policy (default: the model's)")
    parser.add_argument(
        "--max-range",
        type=float,
        default=math.inf,
        metavar="M",
        help="distance along a ray beyond which nothing is updated (default: none)",
    )
    parser.add_argument("--subsample", type=int, default=1, metavar="S", help="use every S-th pixel (default 1)")
    parser.add_argument(
        "--floor-rays",
        type=int,
        default=FLOOR_RAYS,
        metavar="N",
        help=f"ray mode: at least N rays a voxel each way cast the cells at their ray's failure floor, each counted "
        f"for the rays it stands for; 0 = every ray casts every cell (default {FLOOR_RAYS})",
    )
    parser.add_argument("--disparity-dir", type=Path, metavar="DIR", help="precomputed disparities instead of matching")
    parser.add_argument("--frames", default=":", metavar="A:B", help="frames A <= i < B (default all)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="N", help="integrate on a local Dask cluster of N processes")
    where.add_argument("--scheduler", metavar="ADDRESS", help="integrate on an existing Dask cluster")
    parser.add_argument("--chunk-frames", type=int, metavar="C", help="frames per Dask task (default: automatic)")
    parser.add_argument(
        "--checkpoint-every",
        type=int,
        default=0,
        metavar="K",
        help="save a resumable checkpoint every K frames (default 0 = never)",
    )
    add_out(parser, file=True, required=True, metavar="MAP.npz", help="output map file")
    parser.set_defaults(func=run)


def run(args):
    """Map the sequence and write the map; return the exit status."""
    from prismap.io import read_sequence, save_map
    from prismap.pipeline import MappingConfig, map_sequence, remove_checkpoint
    from prismap.pipeline._config import needs_error_model
    from prismap.sensor_models import model_names, table_store

    if args.checkpoint_every < 0:
        raise PrismapInputError(f"--checkpoint-every must be >= 0; got {args.checkpoint_every}")
    if args.workers is not None and not 1 <= args.workers <= usable_cores():
        raise PrismapInputError(
            f"--workers must lie in [1, {usable_cores()}] (the cores this process may use); got {args.workers}"
        )
    sequence = _open_input(args, read_sequence)
    model_params = parse_params(args.model_param, "--model-param")
    if args.map_prior:
        if args.model != "prism":
            raise PrismapInputError(f"--map-prior is an option of --model prism; got --model {args.model}")
        model_params["prior"] = "map"
    if args.error_model is None and args.model in model_names() and needs_error_model(args.model, model_params):
        raise PrismapInputError(
            f"sensor model {args.model!r} needs an error model (--error-model MODEL.json)"
            + (" or --model-param sigma_px=..." if args.model != "prism" else "")
        )
    config = MappingConfig(
        model=args.model,
        voxel_size_m=check_positive(args.voxel, "--voxel"),
        p0=check_probability(args.p0, "--p0"),
        error_model=_error_model(args.error_model),
        conditioned=False if args.plain else None,
        model_params=model_params,
        matcher=args.matcher,
        matcher_params=parse_params(args.matcher_param, "--matcher-param"),
        disparity_source="matcher" if args.disparity_dir is None else _disparity_dir(args.disparity_dir),
        mode=args.mode,
        policy=args.policy,
        max_range_m=args.max_range,
        subsample=args.subsample,
        floor_rays=args.floor_rays,
        frames=parse_frames(args.frames),
        fusion=args.fusion,
    )
    model_text = _error_text(config, sequence.camera)  # a bad model option fails here, not on a frame or a worker
    _check_rig(config, sequence, args)
    checkpoint = None
    if args.checkpoint_every:
        checkpoint = args.out.with_name(args.out.name.removesuffix(".npz") + ".checkpoint.npz")
    with _dask_client(args.workers, args.scheduler) as client:
        grid = map_sequence(
            sequence,
            config,
            progress=True,
            checkpoint=checkpoint,
            checkpoint_every=args.checkpoint_every,
            client=client,
            chunk_frames=args.chunk_frames,
        )
    save_map(grid, args.out)
    if checkpoint is not None:
        remove_checkpoint(checkpoint)
    command = map_command(config, inputs=_input_arguments(args), error_model=args.error_model, out=args.out)
    record = write_map_record(args.out, command, config)
    print(
        f"{grid.n_frames} frames, {grid.n_known} known voxels, {len(grid.occupied_voxels()[0])} occupied "
        f"({config.model}, {model_text}, voxel {config.voxel_size_m} m); wrote {args.out}"
    )
    print(f"reproduce with: {shlex.join(command)}  (settings in {record})")
    store = table_store()
    if store is not None and (store.found or store.written):  # this process's PRISM tables (Dask workers keep theirs)
        print(f"PRISM tables: {store.found} read from {store.directory}, {store.written} built and written there")
    return 0


def map_command(config, *, inputs, error_model, out):
    """The ``prismap map`` command that makes the map of ``config``, every setting explicit.

    Parameters
    ----------
    config : MappingConfig
    inputs : list of str
        The input options, e.g. ``["--sequence", "DIR"]`` or the ``--bag`` options.
    error_model : str or Path or None
        The error model's file (``--error-model``).
    out : str or Path
        The map file (``--out``).

    Returns
    -------
    list of str
        ``argv``, starting ``["prismap", "map"]``; :func:`shlex.join` makes it a shell line.
    """
    from prismap.grid import FLOOR_RAYS
    from prismap.pipeline._config import default_fusion

    argv = ["prismap", "map", *inputs, "--matcher", config.matcher]
    argv += [f"--matcher-param={k}={v!r}" for k, v in config.matcher_params]
    argv += ["--model", config.model]
    argv += [f"--model-param={k}={v!r}" for k, v in config.model_params]
    if error_model is not None:
        argv += ["--error-model", str(error_model)]
        if not config.conditioned and getattr(config.error_model, "n_classes", 1) > 1:  # a model with classes, plain
            argv.append("--plain")
    argv += ["--voxel", repr(config.voxel_size_m), "--p0", repr(config.p0), "--mode", config.mode]
    if config.policy is not None:
        argv += ["--policy", config.policy]
    if math.isfinite(config.max_range_m):
        argv += ["--max-range", repr(config.max_range_m)]
    argv += ["--subsample", str(config.subsample)]
    if config.mode == "ray" and config.floor_rays != FLOOR_RAYS:
        argv += ["--floor-rays", str(config.floor_rays)]
    if config.disparity_source not in ("matcher", "sequence"):
        argv += ["--disparity-dir", config.disparity_source]
    if config.fusion != default_fusion(config.model, config.error_model):
        argv += ["--fusion", config.fusion]
    start, stop = config.frames
    argv += ["--frames", f"{start}:{'' if stop is None else stop}", "--out", str(out)]
    return argv


def write_map_record(map_path, command, config):
    """Write ``MAP.run.json`` beside ``map_path``: the command that reproduces the map and its settings.

    The settings are :meth:`MappingConfig.to_dict` without the error model's numbers (the command names
    its file) and the prismap version. Returns the record's path.
    """
    from prismap import __version__

    settings = {k: v for k, v in config.to_dict().items() if k != "error_model"}
    record = {"command": shlex.join(command), "argv": command, "prismap_version": __version__, "settings": settings}
    path = Path(map_path).with_suffix(".run.json")
    write_text_atomic(path, json.dumps(record, indent=1, default=repr) + "\n")
    return path


def _input_arguments(args):
    """The input options of ``args`` as given: ``--sequence DIR`` or every ``--bag`` option that is set."""
    if args.bag is None:
        return ["--sequence", str(args.sequence)]
    inputs = []
    for option in (
        "bag",
        "left",
        "right",
        "left_info",
        "right_info",
        "rectified",
        "pair_tolerance",
        "pose_topic",
        "tf_frames",
        "pose_gap",
    ):
        value = getattr(args, option, None)
        if value is not None:
            inputs += [f"--{option.replace('_', '-')}", str(value)]
    return inputs


def _open_input(args, read_sequence):
    """The sequence of ``--sequence`` or of ``--bag`` (with poses; not on Dask or with checkpoints)."""
    if (args.sequence is None) == (args.bag is None):
        raise PrismapInputError("give exactly one of --sequence DIR and --bag PATH")
    if args.bag is None:
        if not args.sequence.is_dir():
            raise PrismapInputError(f"--sequence {args.sequence}: sequence directory not found")
        return read_sequence(args.sequence)
    if not (args.pose_topic or args.tf_frames):
        raise PrismapInputError("--bag: mapping needs poses; give --pose-topic TOPIC or --tf-frames WORLD:CAMERA")
    if args.workers is not None or args.scheduler is not None or args.checkpoint_every:
        raise PrismapInputError("--bag runs here, without checkpoints: drop --workers/--scheduler/--checkpoint-every")
    return open_bag_argument(args)


def parse_params(items, option):
    """``["k=v", ...]`` as a dict; values are Python literals (numbers, booleans, strings)."""
    params = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise PrismapInputError(f"{option} {item!r}: expected KEY=VALUE")
        try:
            params[key.strip()] = ast.literal_eval(text.strip())
        except (ValueError, SyntaxError):
            params[key.strip()] = text.strip()
    return params


def parse_frames(text):
    """``"A:B"`` (either side may be empty) as ``(start, stop)``; raises for an empty or bad range."""
    start, stop = parse_frame_range(text, "--frames")
    start = 0 if start is None else start
    if start < 0 or (stop is not None and stop <= start):
        raise PrismapInputError(f"--frames {text!r}: the range is empty or malformed; expected A:B with 0 <= A < B")
    return (start, stop)


def _error_model(path):
    if path is None:
        return None
    from prismap.characterise import load_error_model

    return load_error_model(path)


def _error_text(config, camera):
    """How the run used its error model, for the output line: conditioned (a model per class) or plain."""
    from prismap.sensor_models import ConditionedModel

    model = config.sensor_model(camera)
    if isinstance(model, ConditionedModel):
        return f"conditioned on {model.n_classes} error classes"
    return "plain"


def _check_rig(config, sequence, args):
    """Warn (or refuse with ``--strict-rig``) when the error model was made on another rig than this run's."""
    from prismap.characterise import ErrorModel, check_rig, describe_rig
    from prismap.pipeline._config import DISPARITY_FROM_MATCHER
    from prismap.stereo import make_matcher

    if not isinstance(config.error_model, ErrorModel):
        return
    matcher, params = None, None
    if config.disparity_source == DISPARITY_FROM_MATCHER:
        matcher = config.matcher
        params = make_matcher(config.matcher, **config.matcher_options).params()
    rig = describe_rig(sequence.camera, None, matcher, params)
    message = check_rig(config.error_model, rig, strict=args.strict_rig, where=f"--error-model {args.error_model}")
    if message:
        print(f"prismap map: warning: {message}", file=sys.stderr)


def _disparity_dir(path):
    if not path.is_dir():
        raise PrismapInputError(f"--disparity-dir {path}: directory not found")
    return str(path.resolve())


class _DropInputErrors(logging.Filter):
    """Drops a worker's "Compute Failed" report of a PrismapInputError: the CLI prints it once, on one line."""

    def filter(self, record):
        return "PrismapInputError" not in record.getMessage()


def quiet_input_errors():
    """Run on each Dask worker: its logger no longer prints tracebacks of bad input."""
    logging.getLogger("distributed.worker").addFilter(_DropInputErrors())


@contextlib.contextmanager
def _dask_client(workers, scheduler):
    """A Dask client for ``--workers`` (a local cluster of processes) or ``--scheduler``, else None."""
    if workers is None and scheduler is None:
        yield None
        return
    from distributed import Client, LocalCluster

    cluster = None
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise PrismapInputError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
    else:
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=logging.ERROR
        )
        client = Client(cluster)
    client.run(quiet_input_errors)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
