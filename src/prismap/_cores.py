"""The cores this process may run on: what thread and worker counts are sized by."""

import os


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity; the machine's CPU count where the system has none)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1
