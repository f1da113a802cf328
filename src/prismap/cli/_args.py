"""Argument types and the ``--out`` option shared by every ``prismap`` command."""

import argparse
from pathlib import Path


def seed(text):
    """``--seed``: an integer >= 0 (numpy's generators refuse negative seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0; got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0; got {text!r}")
    return value


def add_out(parser, *, file, metavar, help, **kwargs):
    """Add ``--out``; ``file=True`` marks it a file (else a directory) for the check and lock in ``main``."""
    parser.add_argument("--out", type=Path, metavar=metavar, help=help, **kwargs)
    parser.set_defaults(out_is_file=file)
