"""Entry point of the ``prismap`` command: one sub-command per module in ``COMMANDS``.

Each command module (``prismap/cli/_<name>.py``) defines ``register(subparsers)``, which adds its parser
and sets ``func=run`` with ``run(args) -> int``. Bad input (:class:`PrismapInputError`) is printed as one
line on stderr without a traceback, with exit status 2.
"""

import argparse
import importlib
import sys

from prismap import __version__
from prismap.errors import PrismapInputError

COMMANDS = ("characterise", "map", "evaluate", "lidar_truth", "experiment", "demo", "models", "view")


def build_parser():
    """The argument parser with every registered sub-command."""
    parser = argparse.ArgumentParser(
        prog="prismap",
        description="Dense 3-D occupancy mapping from stereo cameras with measured error models (PRISM).",
    )
    parser.add_argument("--version", action="version", version=f"prismap {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"prismap.cli._{name}").register(subparsers)
    return parser


def main(argv=None):
    """Run ``prismap`` with ``argv`` (default ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except PrismapInputError as exc:
        print(f"prismap {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"prismap {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
