"""The ``prismap`` command line."""

from prismap.cli._main import main

__all__ = ["main"]
