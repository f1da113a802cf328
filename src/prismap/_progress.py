"""Progress of long runs: one place decides how it is shown, and whether.

On a terminal, a tqdm bar on stderr. Without one (output piped, CI logs), a plain line on stderr per step
and about every 10 % of the work, each with the elapsed time and an estimate of the time left, so a
long command is never silent. ``PRISMAP_PROGRESS`` overrides the choice: ``0`` hides progress, ``bar``
(or ``1``) forces the bar, ``lines`` forces the lines.
"""

import math
import os
import sys
import time

from tqdm.auto import tqdm

MODES = ("off", "bar", "lines")
_ENV = {"0": "off", "off": "off", "1": "bar", "bar": "bar", "lines": "lines"}


def progress_mode(enabled=None, stream=None):
    """How progress is shown: ``"off"``, ``"bar"`` or ``"lines"``.

    Parameters
    ----------
    enabled : bool or None
        False = off. True or None = the environment's choice (``PRISMAP_PROGRESS``), else a bar when
        ``stream`` is a terminal and lines when it is not.
    stream : file-like, optional
        Where progress goes (default ``sys.stderr``).
    """
    if enabled is False:
        return "off"
    env = os.environ.get("PRISMAP_PROGRESS", "").strip().lower()
    if env in _ENV:
        return _ENV[env]
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return "bar" if isatty is not None and isatty() else "lines"


def progress(iterable=None, *, total=None, desc=None, unit="it", enabled=None, weights=None):
    """Wrap ``iterable`` (or count ``update`` calls up to ``total``) and show the progress on stderr.

    Parameters
    ----------
    iterable : iterable, optional
    total : int, optional
        Number of items; taken from ``len(iterable)`` when it has one.
    desc : str, optional
        What is being done, e.g. ``"map prism"``.
    unit : str
        What an item is, e.g. ``"frame"``.
    enabled : bool or None
        See :func:`progress_mode`.
    weights : sequence of float, optional
        Each item's expected share of the work (any positive scale, e.g. its measured seconds), when the
        items differ in cost: the percentage and the time left then follow the weight done, not the count.

    Returns
    -------
    tqdm or LineProgress
        Iterable, with ``update(n)``, ``n`` and ``close()`` (also a context manager) in every mode.
    """
    mode = progress_mode(enabled)
    if mode == "lines":
        return LineProgress(iterable, total=total, desc=desc, unit=unit, weights=weights)
    if weights is None:
        return tqdm(iterable, total=total, desc=desc, unit=unit, disable=mode == "off", leave=False, file=sys.stderr)
    bar = tqdm(
        total=float(sum(weights)),
        desc=desc,
        disable=mode == "off",
        leave=False,
        file=sys.stderr,
        bar_format="{desc}: {percentage:3.0f}% of the work|{bar}| {elapsed} elapsed, ~{remaining} left",
    )
    return _WeightedBar(iterable, weights, bar)


def _checked_weights(weights, total):
    """``weights`` as a list of floats > 0, one per item (``total`` of them when known)."""
    weights = [float(w) for w in weights]
    if not weights or not all(math.isfinite(w) and w > 0 for w in weights):
        raise ValueError(f"progress weights must be finite and > 0; got {weights}")
    if total is not None and len(weights) != total:
        raise ValueError(f"progress needs one weight per item: {len(weights)} weights for {total} items")
    return weights


class _Progress:
    """What every progress display shares: iterating counts each item done (``update``), and ``with``
    closes it."""

    def __iter__(self):
        for item in self.iterable:
            yield item
            self.update()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class _WeightedBar(_Progress):
    """A tqdm bar advanced by each item's weight (see :func:`progress`)."""

    def __init__(self, iterable, weights, bar):
        total = len(iterable) if hasattr(iterable, "__len__") else None
        self.iterable = iterable
        self.weights = _checked_weights(weights, total)
        self.n = 0
        self._bar = bar

    def update(self, n=1):
        """Count ``n`` more items done; the bar moves by their weights."""
        self._bar.update(sum(self.weights[self.n : self.n + n]))
        self.n += n

    def close(self):
        """Remove the bar."""
        self._bar.close()


class LineProgress(_Progress):
    """Progress as plain lines: at the first item, about every 10 % of ``total``, and at the end.

    Without a known total, at items 1, 2, 4, 8, ... Each line reads
    ``DESC: N/TOTAL UNITs (P%), E elapsed, ~R left``; with ``weights`` (one per item, see :func:`progress`)
    ``(P% of the work)``, P and the time left from the weight done.
    """

    def __init__(
        self, iterable=None, *, total=None, desc=None, unit="it", stream=None, clock=time.monotonic, weights=None
    ):
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)
        self.weights = None if weights is None else _checked_weights(weights, total)
        if self.weights is not None:
            total = len(self.weights)
        self.iterable = iterable
        self.total = None if total is None else int(total)
        self.desc = desc or "progress"
        self.unit = unit
        self.n = 0
        self._stream = sys.stderr if stream is None else stream
        self._clock = clock
        self._start = clock()
        self._next = 1
        self._closed = False

    def update(self, n=1):
        """Count ``n`` more items done; write a line when a 10 % step (or the end) is reached."""
        if n <= 0:
            return
        self.n += int(n)
        if self.n >= self._next or (self.total is not None and self.n >= self.total):
            self._write()
            if self.total:
                step = max(1, math.ceil(self.total / 10))
                self._next = (self.n // step + 1) * step
            else:
                self._next = 2 * self.n

    def close(self):
        """Stop; nothing more is written."""
        self._closed = True

    def _write(self):
        if self._closed:
            return
        elapsed = self._clock() - self._start
        text = f"{self.desc}: {self.n}"
        if self.total:
            if self.weights is None:
                done, share = self.n / self.total, ""
            else:
                done, share = sum(self.weights[: self.n]) / sum(self.weights), " of the work"
            text += f"/{self.total} {self.unit}s ({100 * done:.0f}%{share}), {_duration(elapsed)} elapsed"
            left = elapsed / done * max(1 - done, 0)
            text += f", ~{_duration(left)} left"
        else:
            text += f" {self.unit}s, {_duration(elapsed)} elapsed"
        print(text, file=self._stream, flush=True)


def _duration(seconds):
    """``seconds`` as ``12.3 s``, ``4 min 05 s`` or ``1 h 02 min``."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"
