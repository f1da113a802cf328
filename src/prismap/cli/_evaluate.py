"""``prismap evaluate``: score a map file against ground-truth occupancy."""

import json
from pathlib import Path

import numpy as np

from prismap.cli._args import add_out
from prismap.errors import PrismapInputError

_COUNT_ROWS = (
    ("voxels scored", "n_voxels", "{:d}"),
    ("truly occupied", "n_occupied", "{:d}"),
    ("truly free", "n_free", "{:d}"),
)


def register(subparsers):
    """Add the ``evaluate`` parser."""
    parser = subparsers.add_parser(
        "evaluate",
        help="score an occupancy map against ground truth",
        description=(
            "Score a map file (prismap map) against ground-truth occupancy: a file written by "
            "prismap.io's write_ground_truth (e.g. a LiDAR reference map) or a sequence directory holding "
            "occupancy.npz. Every voxel of the ground truth's observed region is scored; voxels the map never "
            "observed score as its prior p0. Prints the scores and writes them as JSON: to --out/scores.json "
            "with reliability diagrams (--out/reliability.png, reliability_logit.png: logit-spaced bins reaching the "
            "extremes) and the per-frame evidence histogram (--out/evidence.png), or beside the map as "
            'MAP.scores.json. The scores include the "confident and wrong" rates: truly free voxels at P >= 0.99 '
            "and truly occupied voxels at P <= 0.01, and calibration at the extremes: of the voxels at P >= 0.99 "
            "(P <= 0.01) the share truly free (occupied), at most 1 % for a calibrated map. A second table says where the "
            "log-loss comes from: voxels the map never observed (scored at p0), observed ones left near the prior, "
            "and those with evidence, each truly occupied or free."
        ),
    )
    parser.add_argument("--map", required=True, type=Path, metavar="MAP.npz", help="map file")
    parser.add_argument("--gt", required=True, type=Path, metavar="DIR|FILE", help="ground-truth occupancy")
    add_out(parser, file=False, metavar="DIR", help="directory for scores.json and reliability.png")
    parser.set_defaults(func=run)


def run(args):
    """Score the map and write the results; return the exit status."""
    from prismap._files import write_text_atomic
    from prismap.evaluate import score_grid_with_sources
    from prismap.io import load_map, read_ground_truth

    grid = load_map(args.map)
    truth = read_ground_truth(_truth_file(args.gt))
    if abs(truth.voxel_size_m - grid.voxel_size_m) > 1e-9 * grid.voxel_size_m:
        raise PrismapInputError(
            f"--gt {args.gt}: voxel size {truth.voxel_size_m} m differs from the map's {grid.voxel_size_m} m"
        )
    if grid.ndim == 2:
        raise PrismapInputError(f"--map {args.map}: a 2-D map; evaluate scores 3-D maps against 3-D ground truth")
    if truth.observed_keys.shape[0] == 0:
        raise PrismapInputError(f"--gt {args.gt}: the ground truth observes no voxel: nothing to score")
    scores, sources = score_grid_with_sources(grid, truth)
    print(format_scores(scores, title=f"{args.map} against {args.gt}"))
    print()
    print(format_sources(sources))
    result = {
        "map": str(args.map),
        "ground_truth": str(args.gt),
        "voxel_size_m": grid.voxel_size_m,
        "p0": grid.p0,
        "policy": "+".join(grid.policies),
        "n_frames": grid.n_frames,
        "scores": scores.to_dict(),
        "log_loss_sources": sources,
    }
    if args.out is None:
        json_path = args.map.with_name(args.map.name.removesuffix(".npz") + ".scores.json")
    else:
        from prismap.plots import plot_evidence_histograms, plot_reliability, plot_reliability_logit

        json_path = args.out / "scores.json"
        plot_reliability(
            {args.map.stem: scores}, path=args.out / "reliability.png", title=f"Reliability of {args.map.name}"
        )
        plot_reliability_logit(
            {args.map.stem: scores},
            path=args.out / "reliability_logit.png",
            title=f"Reliability of {args.map.name} at the extremes",
        )
        plot_evidence_histograms(
            {args.map.stem: scores}, path=args.out / "evidence.png", title=f"Evidence per frame of {args.map.name}"
        )
        for name in ("reliability.png", "reliability_logit.png", "evidence.png"):
            print(f"wrote {args.out / name}")
    write_text_atomic(json_path, json.dumps(result, indent=1) + "\n")
    print(f"wrote {json_path}")
    return 0


def format_scores(scores, *, title):
    """The scores as a two-column Markdown table."""
    from prismap.evaluate import EXTREME_COLUMNS, SCORE_COLUMNS

    lines = [f"{title}", "", "| score | value |", "|---|---|"]
    for label, name, fmt, *_ in (*_COUNT_ROWS, *SCORE_COLUMNS, *EXTREME_COLUMNS):
        value = getattr(scores, name)
        text = "n/a" if isinstance(value, float) and np.isnan(value) else fmt.format(value)
        lines.append(f"| {label} | {text} |")
    return "\n".join(lines)


def format_sources(sources):
    """:func:`prismap.evaluate.log_loss_sources` as a Markdown table: voxels and log-loss per group."""
    from prismap.evaluate import NEAR_PRIOR_LOG_ODDS

    lines = [
        "Where the log-loss comes from (nats per scored voxel; the six parts add up to the log-loss; near the prior: "
        f"|logit P - logit p0| < {NEAR_PRIOR_LOG_ODDS:g})",
        "",
        "| voxels | truly occupied: voxels | log-loss | truly free: voxels | log-loss |",
        "|---|---|---|---|---|",
    ]
    for level, parts in sources.items():
        occupied, free = parts["occupied"], parts["free"]
        lines.append(
            f"| {level} | {occupied['voxels']} | {occupied['log_loss']:.4f} | {free['voxels']} | {free['log_loss']:.4f} |"
        )
    return "\n".join(lines)


def _truth_file(path):
    if path.is_dir():
        candidate = path / "occupancy.npz"
        if not candidate.is_file():
            raise PrismapInputError(f"--gt {path}: a directory without occupancy.npz (ground-truth occupancy)")
        return candidate
    if not path.is_file():
        raise PrismapInputError(f"--gt {path}: no such file or directory")
    return path
