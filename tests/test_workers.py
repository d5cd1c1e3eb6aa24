"""The worker process the node gives a request's expensive work to (issue 38, :mod:`cgp_sim_ros.workers`): what a
job returns comes back (numpy arrays whole), a job past its deadline is ended and the next one runs in a new
process, a job that kills its process or raises is an answer naming it, close() never waits for a job, and the
worker runs in a process of its own (another interpreter: not the caller's GIL)."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from cgp_sim_ros.workers import JobFailed, WorkerProcess


def _pid() -> int:
    return os.getpid()


def _arrays(n: int) -> dict:
    return {"a": np.arange(n, dtype=np.float64).reshape(-1, 3), "b": np.ones(7, np.int8), "text": "x" * 10}


def _sleep(seconds: float) -> str:
    time.sleep(seconds)
    return "slept"


def _die() -> None:
    os._exit(3)


def _raise() -> None:
    raise ValueError("a reason")


@pytest.fixture
def worker():
    w = WorkerProcess("test-worker")
    yield w
    w.close()


def test_results_come_back_from_another_process(worker):
    assert worker.submit(_pid, timeout=60).result(60) != os.getpid()
    got = worker.submit(_arrays, 3_000_000, timeout=60).result(60)  # 24 MB sent out of band
    assert np.array_equal(got["a"], np.arange(3_000_000, dtype=np.float64).reshape(-1, 3))
    assert got["a"].flags.writeable and got["b"].dtype == np.int8 and got["text"] == "x" * 10


def test_a_job_past_its_deadline_is_ended_and_the_next_runs_in_a_new_process(worker):
    first = worker.submit(_pid, timeout=60).result(60)
    slow = worker.submit(_sleep, 60.0, timeout=0.5)
    after = worker.submit(_pid, timeout=60)
    with pytest.raises(JobFailed) as failure:
        slow.result(30)
    assert failure.value.reason == "timeout" and "0.5 s" in str(failure.value)
    second = after.result(60)
    assert second != first and worker.started == 2
    with pytest.raises(ProcessLookupError):
        os.kill(first, 0)  # the old worker is gone


def test_a_crash_or_an_exception_is_an_answer(worker):
    with pytest.raises(JobFailed) as died:
        worker.submit(_die, timeout=60).result(60)
    assert died.value.reason == "died" and "exit status 3" in str(died.value)
    with pytest.raises(JobFailed) as raised:
        worker.submit(_raise, timeout=60).result(60)
    assert raised.value.reason == "error" and str(raised.value) == "ValueError: a reason"
    assert "_raise" in raised.value.details
    assert worker.submit(_sleep, 0.0, timeout=60).result(60) == "slept"


def test_close_does_not_wait_for_a_job_and_leaves_no_process():
    worker = WorkerProcess("test-worker")
    pid = worker.submit(_pid, timeout=60).result(60)
    running = worker.submit(_sleep, 60.0, timeout=120)
    queued = worker.submit(_pid, timeout=60)
    deadline = time.monotonic() + 30
    while not running.running() and time.monotonic() < deadline:
        time.sleep(0.01)
    worker.close()
    for future in (running, queued):
        with pytest.raises(JobFailed) as failure:
            future.result(30)
        assert failure.value.reason == "closed"
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
    with pytest.raises(JobFailed):
        worker.submit(_pid, timeout=1).result(5)
