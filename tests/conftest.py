"""Shared test settings: a non-interactive matplotlib backend and quiet progress bars (whatever the caller's environment says)."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ["PRISMAP_PROGRESS"] = "0"  # hermetic: a caller's setting must not add lines to the one-line checks
