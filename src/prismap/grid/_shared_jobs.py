"""Jobs whose results are taken in order, run by worker threads and by the thread that waits for them.

An integrator's writing thread (the only one that may touch the frame accumulator) hands the model's work on a
chunk of cells to worker threads and adds the results in chunk order. While the oldest job is unfinished, that
thread would idle: :meth:`SharedJobs.next_result` has it run a queued job no thread has started instead (the
newest, the one a worker would reach last), as long as that leaves a worker something queued. Which thread runs a job
does not change its result, and the results are taken in submission order, so the frame's sums, and the map,
depend neither on the threads nor on their timing.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import CancelledError, ThreadPoolExecutor
from typing import Any


class _Job:
    """One call ``fn(*args)``, run once by whichever thread claims it first."""

    __slots__ = ("_args", "_claim", "_done", "_error", "_fn", "_result")

    def __init__(self, fn, args):
        self._fn, self._args = fn, args
        self._claim = threading.Lock()  # held from the claim on: a one-shot flag, taken without blocking
        self._done = threading.Event()
        self._result = self._error = None

    def unclaimed(self) -> bool:
        return not self._claim.locked()

    def finished(self) -> bool:
        return self._done.is_set()

    def cancel(self) -> None:
        """Claim the call without running it, unless a thread claimed it already."""
        if self._claim.acquire(blocking=False):
            self._fn = self._args = None
            self._error = CancelledError()
            self._done.set()

    def run(self) -> None:
        """Run the call unless another thread claimed it; its result or exception is kept for :meth:`result`."""
        if not self._claim.acquire(blocking=False):
            return
        try:
            self._result = self._fn(*self._args)
        except BaseException as error:  # re-raised in the thread that takes the result
            self._error = error
        finally:
            self._fn = self._args = None
            self._done.set()

    def result(self) -> Any:
        self._done.wait()
        if self._error is not None:
            raise self._error
        return self._result


class SharedJobs:
    """Jobs run by ``threads`` worker threads and by the thread that takes their results, in submission order.

    Use as a context manager: at its end, jobs no thread has started are dropped and the workers finish the ones
    they hold.
    """

    def __init__(self, threads: int) -> None:
        self._pool = ThreadPoolExecutor(max_workers=threads)
        self._pending: deque[_Job] = deque()

    def __enter__(self) -> SharedJobs:
        return self

    def __exit__(self, *exc_info) -> None:
        for job in self._pending:
            job.cancel()
        self._pool.shutdown(wait=True)

    def __len__(self) -> int:
        """Jobs whose result has not been taken."""
        return len(self._pending)

    def submit(self, fn: Callable[..., Any], *args: Any) -> None:
        """Queue ``fn(*args)``; its result comes from :meth:`next_result` after those of the jobs before it."""
        job = _Job(fn, args)
        self._pending.append(job)
        self._pool.submit(job.run)

    def next_result(self) -> Any:
        """The oldest job's result (its exception raised here). While it is unfinished, this thread runs it if no
        thread has started it, else the newest job no thread has started when one more is left queued for the
        workers."""
        oldest = self._pending[0]
        while not oldest.finished():
            unclaimed = [job for job in self._pending if job.unclaimed()]
            if unclaimed and unclaimed[0] is oldest:
                oldest.run()
            elif len(unclaimed) >= 2:
                unclaimed[-1].run()
            else:
                break
        self._pending.popleft()
        return oldest.result()
