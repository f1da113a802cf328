"""Shared test settings: a non-interactive matplotlib backend and quiet progress bars (whatever the caller's environment says)."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ["PRISMAP_PROGRESS"] = "0"  # hermetic: a caller's setting must not add lines to the one-line checks
os.environ["PRISMAP_TABLE_CACHE"] = (
    "off"  # hermetic: no PRISM tables read from or written to the caller's store (tests of the store set their own)
)
