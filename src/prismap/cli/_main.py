"""Entry point of the ``prismap`` command: one sub-command per module in ``COMMANDS``.

Each command module (``prismap/cli/_<name>.py``) defines ``register(subparsers)``, which adds its parser
and sets ``func=run`` with ``run(args) -> int``. Bad input (:class:`PrismapInputError`) is printed as one
line on stderr without a traceback, with exit status 2; so are OpenCV's own errors and any operation the
operating system refuses (``OSError``: a full disk, a name too long). A command's ``--out`` (registered
with :func:`prismap.cli._args.add_out`) is checked before the run starts (it may not be one of the run's
inputs, :func:`run_inputs`) and locked (``fcntl``) for its whole duration, so two runs never share it; a
refused run removes the ``--out`` directory it created.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import shutil
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

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


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``prismap`` with ``argv`` (default ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    name = " ".join(filter(None, (args.command, getattr(args, "action", None))))  # e.g. "models compare"
    signal.signal(signal.SIGTERM, _terminate)  # unwind on SIGTERM, so temporaries and locks are removed
    try:
        with _output_lock(args), _removed_if_refused(args):
            return int(args.func(args) or 0)
    except PrismapInputError as exc:
        print(f"prismap {name}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except cv2.error as exc:
        print(
            f"prismap {name}: error: OpenCV {exc.func or 'call'} refused the input: "
            f"{(exc.err or str(exc)).strip().splitlines()[0]}",
            file=sys.stderr,
        )
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"prismap {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"prismap {name}: interrupted", file=sys.stderr)
        return 130
    except SystemError as exc:
        # Ctrl-C inside a compiled kernel surfaces as "returned a result with an exception set"
        if not isinstance(exc.__cause__ or exc.__context__, KeyboardInterrupt):
            raise
        print(f"prismap {name}: interrupted", file=sys.stderr)
        return 130


def _one_line(exc):
    """The message of ``exc`` on one line (a library's multi-line complaint joined), as the command promises."""
    return " ".join(line.strip() for line in str(exc).splitlines() if line.strip())


def _terminate(signum, frame):
    raise SystemExit(128 + signum)


SEQUENCE_INPUTS = ("calib.txt", "poses.txt", "image_2", "image_3", "disp", "velodyne", "occupancy.npz")
"""What a sequence directory's readers read (``prismap.io.read_sequence``): an output may not be one of them."""


def run_inputs(args):
    """``(role, path)`` of every file or directory argument of ``args`` but ``--out``: what the run reads.

    A sequence directory (one with ``image_2``) contributes the inputs its readers open
    (:data:`SEQUENCE_INPUTS`, and a KITTI tree's ``ROOT/poses/NN.txt``), so outputs may still be written beside
    them; any other directory is an input as a whole.
    """
    inputs = []
    for key, value in sorted(vars(args).items()):
        if key == "out" or not isinstance(value, Path):
            continue
        role = f"--{key.replace('_', '-')}" if key != "map" else "the map file"
        if (value / "image_2").is_dir():
            inputs += [(role, value / name) for name in SEQUENCE_INPUTS]
            inputs.append((role, value.parent.parent / "poses" / f"{value.name}.txt"))
        else:
            inputs.append((role, value))
    return inputs


@contextlib.contextmanager
def _removed_if_refused(args):
    """Remove the ``--out`` directory this run created when the run is refused (bad input, a full disk).

    A directory that existed before is left as it was (an experiment resumes from it); an interrupted
    run keeps what it wrote, for the same reason.
    """
    out = getattr(args, "out", None)
    if out is None or getattr(args, "out_is_file", False) or out.exists():
        yield
        return
    try:
        yield
    except (PrismapInputError, OSError, cv2.error):
        shutil.rmtree(out, ignore_errors=True)
        raise


def _output_lock(args):
    """Check ``args.out`` and hold its lock for the run (a null context for commands without ``--out``)."""
    out = getattr(args, "out", None)
    if out is None:
        return contextlib.nullcontext()
    check_output(out, directory=not getattr(args, "out_is_file", False), inputs=run_inputs(args))
    return exclusive_lock(out)


if __name__ == "__main__":
    sys.exit(main())
