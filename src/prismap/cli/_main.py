"""Entry point of the ``prismap`` command: one sub-command per module in ``COMMANDS``.

Each command module (``prismap/cli/_<name>.py``) defines ``register(subparsers)``, which adds its parser
and sets ``func=run`` with ``run(args) -> int``. Bad input (:class:`PrismapInputError`) is printed as one
line on stderr without a traceback, with exit status 2; so are OpenCV's own errors and a write the
operating system refuses. A command's ``--out`` (registered with :func:`prismap.cli._args.add_out`) is
checked before the run starts and locked (``fcntl``) for its whole duration, so two runs never share it.
"""

import argparse
import contextlib
import importlib
import signal
import sys

import cv2

from prismap import __version__
from prismap._files import check_output, exclusive_lock
from prismap.errors import PrismapInputError

COMMANDS = ("characterise", "map", "evaluate", "export", "lidar_truth", "experiment", "demo", "models", "view")


class _Parser(argparse.ArgumentParser):
    """argparse, with a bad option reported on one line (the usage is one ``--help`` away)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser():
    """The argument parser with every registered sub-command."""
    parser = _Parser(
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
    name = " ".join(filter(None, (args.command, getattr(args, "action", None))))  # e.g. "models compare"
    signal.signal(signal.SIGTERM, _terminate)  # unwind on SIGTERM, so temporaries and locks are removed
    try:
        with _output_lock(args):
            return int(args.func(args) or 0)
    except PrismapInputError as exc:
        print(f"prismap {name}: error: {exc}", file=sys.stderr)
        return 2
    except cv2.error as exc:
        print(f"prismap {name}: error: OpenCV {exc.func or 'call'} refused the input: "
              f"{(exc.err or str(exc)).strip().splitlines()[0]}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"prismap {name}: interrupted", file=sys.stderr)
        return 130


def _terminate(signum, frame):
    raise SystemExit(128 + signum)


def _output_lock(args):
    """Check ``args.out`` and hold its lock for the run (a null context for commands without ``--out``)."""
    out = getattr(args, "out", None)
    if out is None:
        return contextlib.nullcontext()
    check_output(out, directory=not getattr(args, "out_is_file", False))
    return exclusive_lock(out)


if __name__ == "__main__":
    sys.exit(main())
