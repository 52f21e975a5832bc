"""The worker processes grasp jobs compute in: results, errors, progress and Cancel across the
process boundary; a worker that hangs or dies is replaced; shutdown leaves no child."""

from __future__ import annotations

import contextlib
import os
import threading
import time

import pytest

from shapeviewer.errors import Cancelled, ShapeviewerError
from shapeviewer.runtime import processes
from shapeviewer.runtime.interrupt import alive
from shapeviewer.runtime.processes import ProcessPool, RemoteTraceback, WorkerDied
from shapeviewer.runtime.progress import scaled


def report_and_return_pid(steps: int, *, progress, cancel) -> int:
    for i in range(steps + 1):
        progress(i / steps)
    return os.getpid()


def fail(*, progress, cancel) -> None:
    raise ValueError("no faces to grasp")


def wait_for_cancel(*, progress, cancel) -> str:
    t0 = time.monotonic()
    while not cancel():
        if time.monotonic() - t0 > 30:
            return "never cancelled"
        time.sleep(0.01)
    return "stopped"


def stop_when_cancelled(*, progress, cancel) -> None:
    """Stop as the grasp planner and the robustness ranking do: raise Cancelled once asked."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < 30:
        if cancel():
            raise Cancelled("stopped on request")
        time.sleep(0.01)


def ignore_cancel(*, progress, cancel) -> None:
    time.sleep(60)


def die(code: int, *, progress, cancel) -> None:
    os._exit(code)


def start_a_child(*, progress, cancel) -> int:
    """Start a long subprocess (as V-HACD is started) and hang."""
    import subprocess

    child = subprocess.Popen(["sleep", "60"])
    progress(float(child.pid))  # tells the test which process it started
    time.sleep(60)
    return child.pid


@pytest.fixture
def pool():
    p = ProcessPool(1, name="test-worker")
    yield p
    p.shutdown()


def test_a_job_runs_in_another_process_and_reports_progress(pool):
    seen: list[float] = []
    pid = pool.run(report_and_return_pid, 200, progress=seen.append)
    assert pid != os.getpid()
    # Whole percents only, in order, ending at 1.
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) == 101
    assert pool.run(report_and_return_pid, 1) == pid  # the worker is kept for the next job


def test_an_error_is_raised_with_the_workers_traceback(pool):
    with pytest.raises(ValueError, match="no faces") as info:
        pool.run(fail)
    assert isinstance(info.value.__cause__, RemoteTraceback) and "def fail" not in str(info.value.__cause__)
    assert "in fail" in str(info.value.__cause__)


def test_cancel_reaches_the_worker(pool):
    cancel = threading.Event()
    threading.Timer(0.3, cancel.set).start()
    t0 = time.monotonic()
    assert pool.run(wait_for_cancel, cancel=cancel) == "stopped"
    assert time.monotonic() - t0 < 5


def test_a_job_that_stops_on_cancel_raises_cancelled_in_the_caller(pool):
    cancel = threading.Event()
    threading.Timer(0.3, cancel.set).start()
    with pytest.raises(Cancelled, match="stopped on request") as info:
        pool.run(stop_when_cancelled, cancel=cancel)
    assert isinstance(info.value.__cause__, RemoteTraceback)  # raised in the worker, not by the pool
    assert pool.run(report_and_return_pid, 1) != os.getpid()  # the worker stopped by itself: kept


def test_a_job_cancelled_before_it_has_a_worker_never_starts(pool):
    cancel = threading.Event()
    cancel.set()
    release = threading.Event()

    def hold() -> None:
        with contextlib.suppress(Cancelled):
            pool.run(stop_when_cancelled, cancel=release)

    holder = threading.Thread(target=hold)
    holder.start()
    try:
        t0 = time.monotonic()
        while not pool.full:  # until the one worker is taken
            assert time.monotonic() - t0 < 10
            time.sleep(0.01)
        with pytest.raises(Cancelled, match="waiting for a worker"):
            pool.run(report_and_return_pid, 1, cancel=cancel)
    finally:
        release.set()
        holder.join(30)


def test_progress_of_a_stage_is_its_share_of_the_job():
    seen: list[float] = []
    stage = scaled(seen.append, 0.25, 0.75)
    assert stage is not None and scaled(None, 0.0, 0.5) is None
    for fraction in (0.0, 0.5, 1.0):
        stage(fraction)
    assert seen == [0.25, 0.5, 0.75]


def test_the_pools_errors_are_the_packages_and_keep_their_builtin_base():
    assert issubclass(WorkerDied, ShapeviewerError) and issubclass(WorkerDied, RuntimeError)
    assert issubclass(Cancelled, ShapeviewerError) and issubclass(RemoteTraceback, ShapeviewerError)


def test_a_worker_that_ignores_cancel_is_killed_and_replaced(pool, monkeypatch):
    monkeypatch.setattr(processes, "CANCEL_GRACE_SECONDS", 0.5)
    first = pool.run(report_and_return_pid, 1)
    cancel = threading.Event()
    threading.Timer(0.2, cancel.set).start()
    t0 = time.monotonic()
    with pytest.raises(Cancelled):
        pool.run(ignore_cancel, cancel=cancel)
    assert time.monotonic() - t0 < 5
    second = pool.run(report_and_return_pid, 1)
    assert second != first  # a fresh worker
    with pytest.raises(ProcessLookupError):
        os.kill(first, 0)


def test_killing_a_worker_also_kills_the_processes_it_started(pool, monkeypatch):
    monkeypatch.setattr(processes, "CANCEL_GRACE_SECONDS", 0.5)
    cancel = threading.Event()
    child: list[int] = []

    def started(pid: float) -> None:
        child.append(int(pid))
        cancel.set()

    with pytest.raises(Cancelled):
        pool.run(start_a_child, progress=started, cancel=cancel)
    time.sleep(0.2)
    assert not alive(child[0])


def test_a_worker_that_dies_is_reported_and_replaced(pool):
    with pytest.raises(WorkerDied, match="exit code 3"):
        pool.run(die, 3)
    assert pool.run(report_and_return_pid, 1) != os.getpid()


def test_jobs_wait_for_a_free_worker_and_shutdown_leaves_no_child():
    pool = ProcessPool(1, name="test-worker")
    results: list[object] = []
    cancel = threading.Event()
    first = threading.Thread(target=lambda: results.append(pool.run(wait_for_cancel, cancel=cancel)))
    first.start()
    time.sleep(0.5)
    assert pool.full
    second = threading.Thread(target=lambda: results.append(pool.run(report_and_return_pid, 1)))
    second.start()
    time.sleep(0.3)
    assert results == []  # the second waits behind the first
    cancel.set()
    first.join(10)
    second.join(10)
    assert results[0] == "stopped" and isinstance(results[1], int)
    pid = results[1]
    t0 = time.monotonic()
    pool.shutdown()
    assert time.monotonic() - t0 < 2
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)
    with pytest.raises(RuntimeError, match="stopping"):
        pool.run(report_and_return_pid, 1)


def test_shutdown_ends_a_running_job_at_once():
    pool = ProcessPool(1, name="test-worker")
    raised: list[BaseException] = []

    def run() -> None:
        try:
            pool.run(ignore_cancel)
        except BaseException as e:
            raised.append(e)

    job = threading.Thread(target=run)
    job.start()
    deadline = time.monotonic() + 30
    while pool.workers_alive() < 1 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)  # the worker has the job and sleeps in it
    t0 = time.monotonic()
    pool.shutdown()
    job.join(5)
    assert not job.is_alive() and time.monotonic() - t0 < 3
    assert len(raised) == 1 and isinstance(raised[0], WorkerDied), raised
