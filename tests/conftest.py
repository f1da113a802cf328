"""Shared test settings: a non-interactive matplotlib backend and quiet progress bars."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("PRISMAP_PROGRESS", "0")
