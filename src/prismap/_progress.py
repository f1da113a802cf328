"""Progress bars for long runs: one place decides how they look and when they are shown."""

import os
import sys

from tqdm.auto import tqdm


def progress(iterable=None, *, total=None, desc=None, unit="it", enabled=None):
    """Wrap ``iterable`` in a progress bar on stderr.

    Shown when stderr is a terminal, hidden otherwise (CI logs, tests) unless ``enabled`` is given or
    the environment variable ``PRISMAP_PROGRESS`` is ``1``/``0``.
    """
    if enabled is None:
        env = os.environ.get("PRISMAP_PROGRESS")
        enabled = env == "1" if env in ("0", "1") else sys.stderr.isatty()
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=not enabled, leave=False, file=sys.stderr)
