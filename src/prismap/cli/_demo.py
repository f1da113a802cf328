"""``prismap demo``: characterise, compare the sensor models, run the experiments, write an HTML report."""

from pathlib import Path

from prismap.cli._args import add_out, seed


def register(subparsers):
    """Add the ``demo`` parser."""
    parser = subparsers.add_parser(
        "demo",
        help="the whole story on bundled data: error models, model comparison, 2-D office, 3-D room and street "
        "(about 8 min on 2 idle cores; --quick: every step at tiny sizes)",
        description=(
            "Characterise the bundled Middlebury Motorcycle pair with bm, sgbm and variational, compare the "
            "sensor models on the SGBM error model (prismap models compare), run the experiments (2-D office, "
            "3-D indoor room, 3-D street with a KITTI-like rig) and write the report OUT/index.html (the answer "
            "first: which model wins, map slices and a 3-D view; then every table and figure) and OUT/index.md. "
            "The room and the street take most of the time. Finished steps are reused when the command is run "
            "again."
        ),
    )
    add_out(parser, file=False, default=Path("outputs"), metavar="DIR", help="output directory")
    parser.add_argument(
        "--quick", action="store_true", help="tiny sizes: shows that every step works; its numbers are not meaningful"
    )
    parser.add_argument("--seed", type=seed, default=0, help="seed of the experiments (default 0)")
    parser.set_defaults(func=run)


def run(args):
    """Run the demo, print its Markdown index and where the report is; return the exit status."""
    from prismap.experiment._demo import run_demo

    index = run_demo(args.out, quick=args.quick, seed=args.seed)
    print(index.with_suffix(".md").read_text(encoding="utf-8"))
    print(f"wrote {index} and {index.with_suffix('.md')}")
    return 0
