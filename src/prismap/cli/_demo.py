"""``prismap demo``: characterise, compare the sensor models, run both experiments, write an index page."""

from pathlib import Path

from prismap.cli._args import add_out, seed


def register(subparsers):
    """Add the ``demo`` parser."""
    parser = subparsers.add_parser(
        "demo",
        help="the whole story in a few minutes: error models, model comparison, 2-D and 3-D experiments",
        description=(
            "Characterise the bundled Middlebury Motorcycle pair with bm, sgbm and variational, compare the "
            "sensor models on the SGBM error model (prismap models compare, when available), run the 2-D office "
            "and 3-D indoor experiments and write OUT/index.md linking every table and figure. Finished steps "
            "are reused when the command is run again."
        ),
    )
    add_out(parser, file=False, default=Path("outputs"), metavar="DIR", help="output directory")
    parser.add_argument("--quick", action="store_true", help="tiny sizes: a smoke run, numbers not meaningful")
    parser.add_argument("--seed", type=seed, default=0, help="seed of the experiments (default 0)")
    parser.set_defaults(func=run)


def run(args):
    """Run the demo and print where its index is; return the exit status."""
    from prismap.experiment._demo import run_demo

    index = run_demo(args.out, quick=args.quick, seed=args.seed)
    print(index.read_text(encoding="utf-8"))
    print(f"wrote {index}")
    return 0
