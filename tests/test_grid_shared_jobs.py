"""SharedJobs: results in submission order, the waiting thread running queued jobs, errors and cancellation."""

import threading
from concurrent.futures import CancelledError

import pytest

from prismap.grid._shared_jobs import SharedJobs, _Job


def test_results_come_in_submission_order_whoever_runs_the_jobs():
    """One worker held up on the first job: the taking thread runs the later jobs itself (all but the last one
    queued, which it leaves to the worker), and the results still come in order."""
    release = threading.Event()
    ran_by = {}

    def job(i):
        if i == 0:
            assert release.wait(10)
        ran_by[i] = threading.get_ident()
        return i * i

    me = threading.get_ident()
    with SharedJobs(1) as jobs:
        for i in range(6):
            jobs.submit(job, i)
        threading.Timer(0.2, release.set).start()
        results = [jobs.next_result() for _ in range(6)]
    assert results == [i * i for i in range(6)]
    assert ran_by[0] != me
    assert {i for i, thread in ran_by.items() if thread == me} >= {2, 3, 4, 5}


def test_the_taking_thread_runs_the_oldest_job_when_no_worker_has_started_it():
    """Both of the worker's slots taken by a job that waits for the taker: the taker runs the oldest queued job
    itself instead of waiting for it (without that this test would wait forever)."""
    started = threading.Event()
    release = threading.Event()
    me = threading.get_ident()

    def blocker():
        started.set()
        assert release.wait(10)
        return "blocker"

    with SharedJobs(1) as jobs:
        jobs._pool.submit(blocker)  # the worker is busy outside the queue of jobs
        assert started.wait(10)
        jobs.submit(threading.get_ident)
        assert jobs.next_result() == me
        release.set()


def test_an_error_is_raised_when_its_result_is_taken_and_later_jobs_are_dropped():
    """The worker busy outside the queue: the taker runs job 1, whose error it raises; jobs 2 and 3, which no thread
    started, are dropped when the block ends."""
    calls = []
    release = threading.Event()

    def job(i):
        calls.append(i)
        if i == 1:
            raise ValueError("job 1 failed")
        return i

    with pytest.raises(ValueError, match="job 1 failed"):
        with SharedJobs(1) as jobs:
            jobs._pool.submit(release.wait, 10)
            for i in range(1, 4):
                jobs.submit(job, i)
            try:
                jobs.next_result()
            finally:  # after the block's end has dropped jobs 2 and 3, which the worker would otherwise run
                threading.Timer(0.3, release.set).start()
    assert calls == [1]
    assert len(jobs) == 2


def test_a_job_runs_once_and_a_cancelled_one_not_at_all():
    calls = []
    job = _Job(calls.append, (1,))
    assert job.unclaimed() and not job.finished()
    job.run()
    job.run()
    job.cancel()
    assert calls == [1] and job.finished() and job.result() is None
    dropped = _Job(calls.append, (2,))
    dropped.cancel()
    dropped.run()
    assert calls == [1]
    with pytest.raises(CancelledError):
        dropped.result()
