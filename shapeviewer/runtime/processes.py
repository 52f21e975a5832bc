"""Worker processes for the viewer's grasp jobs (kept out of :mod:`shapeviewer.viewer` so that a
worker imports only what its jobs need, not viser and torch).

Planning, executing and ranking grasps run pybullet and numpy in Python loops that hold the GIL
for seconds. In a thread of the server they delay every other session's click (its CNN and mesh
wait for the interpreter, and so do the websocket writes). A :class:`ProcessPool` runs them in
separate processes instead: the server's threads only wait on a pipe. Each worker is started
on first use (``spawn``: the server has threads, so it must not ``fork``) and kept for the next
job; progress and cancel cross the process boundary, and a worker that will not stop or dies is
killed and replaced.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any, TypeVar

from ..errors import Cancelled, ShapeviewerError
from .progress import Progress, clamped

log = logging.getLogger(__name__)
T = TypeVar("T")

POLL_SECONDS = 0.1  # how often a waiting job looks at its cancel flag
CANCEL_GRACE_SECONDS = 5.0  # a cancelled job not answering within this is killed with its worker
STOP_SECONDS = 0.2  # what shutdown waits for a worker to leave before killing it (it keeps no state)
# What a kill waits for the killed process to be reaped: SIGKILL cannot be refused, so this only
# bounds a kernel that is slow to end it on a loaded machine (a reaped child leaves no zombie).
REAP_SECONDS = 5.0


# How often a worker looks whether its parent is still there (see die_with_parent).
PARENT_POLL_SECONDS = 0.5
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(parent: int | None = None, *, kernel: bool = True) -> None:
    """Make this worker process end as soon as its parent does, even when the parent is killed
    with SIGKILL and can clean nothing up (a worker left running would go on writing results).

    Called first thing in a worker. ``parent``: the parent's process id as the parent knew it
    (default: the current parent). Two ways, both kept:

    * ``kernel``: Linux's ``prctl(PR_SET_PDEATHSIG, SIGKILL)``, the kernel kills us the moment the
      parent dies. It fires when the parent's *thread* that started us ends, so it suits workers
      started by a parent's main thread only (a pool made in ``evaluate``), not by a server's
      short-lived threads.
    * a daemon thread that looks every :data:`PARENT_POLL_SECONDS` whether the parent is still
      ours (an orphan is re-parented), and then ends this process, and its process group when the
      worker leads one (so that what it started goes too).

    A parent that died before this call is noticed at once.
    """
    parent = os.getppid() if parent is None else parent
    if kernel and sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):  # no prctl: the thread below still does it
            pass
    if os.getppid() != parent:
        _end_orphan()
    threading.Thread(target=_watch_parent, args=(parent,), name="watch-parent", daemon=True).start()


def _watch_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_SECONDS)
    _end_orphan()


def _end_orphan() -> None:
    if os.getpgrp() == os.getpid():  # a group of our own: what we started goes with us
        os.killpg(os.getpgrp(), signal.SIGKILL)
    os._exit(1)


# The name this module used for :class:`~shapeviewer.errors.Cancelled` (a job cancelled before
# it had a worker, or whose worker did not stop in time and was killed); viewer.grasps.work uses it.


class WorkerDied(ShapeviewerError, RuntimeError):
    """A worker process ended in the middle of a job (killed, out of memory, a crash in C)."""


class RemoteTraceback(ShapeviewerError):
    """The traceback of an exception raised in a worker (set as the raised exception's cause)."""

    def __str__(self) -> str:
        return str(self.args[0])


def _serve(conn: Connection, nice: int, parent: int | None = None) -> None:
    """A worker's loop: run each ``(fn, args, kwargs)`` received with ``progress`` and ``cancel``
    keywords, answer with its result or exception, until ``None`` or the pipe closes. During a
    job the only message that can arrive is ``"cancel"``. The worker (and what it started) ends
    with its ``parent``, the server, however the server ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the server's to handle: it stops us
    os.setpgrp()  # a group of its own, so that killing it also kills what it started (V-HACD)
    # Not the kernel's parent-death signal: the server starts workers from its threads, which may end first.
    die_with_parent(parent, kernel=False)
    if nice:
        os.nice(nice)
    last = [-1]
    cancelled = [False]

    def cancel() -> bool:
        while not cancelled[0] and conn.poll():
            cancelled[0] = conn.recv() == "cancel"
        return cancelled[0]

    def progress(fraction: float) -> None:
        pct = int(100 * clamped(fraction))
        if pct != last[0]:  # whole percents only: the bar shows no more
            last[0] = pct
            conn.send(("progress", fraction))

    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        if msg == "cancel":  # it came after the job it was for had ended
            continue
        fn, args, kwargs = msg
        last[0], cancelled[0] = -1, False
        try:
            result = fn(*args, progress=progress, cancel=cancel, **kwargs)
            conn.send(("result", result))
        except BaseException as e:
            tb = traceback.format_exc()
            try:
                conn.send(("error", (e, tb)))
            except Exception:  # an exception that does not pickle
                conn.send(("error", (RuntimeError(f"{type(e).__name__}: {e}"), tb)))


class _Worker:
    """One worker process and its pipe (started on first use)."""

    def __init__(self, ctx: Any, name: str, nice: int) -> None:
        self._ctx = ctx
        self.name = name
        self.nice = nice
        self.process: Any = None
        self.conn: Connection | None = None

    def _start(self) -> None:
        parent, child = self._ctx.Pipe()
        self.process = self._ctx.Process(
            target=_serve, args=(child, self.nice, os.getpid()), name=self.name, daemon=True
        )
        self.process.start()
        child.close()
        self.conn = parent

    def call(
        self,
        fn: Callable[..., T],
        args: tuple,
        kwargs: dict,
        progress: Progress | None,
        cancel: threading.Event | None,
    ) -> T:
        if self.process is None or not self.process.is_alive():
            self._start()
        # Locals: shutdown() may kill the worker (and reset these) from another thread meanwhile.
        process, conn = self.process, self.conn
        assert conn is not None
        cancelled_at: float | None = None
        sent = False
        while True:
            try:
                if not sent:
                    conn.send((fn, args, kwargs))
                    sent = True
                if cancel is not None and cancel.is_set() and cancelled_at is None:
                    conn.send("cancel")
                    cancelled_at = time.monotonic()
                if cancelled_at is not None and time.monotonic() - cancelled_at > CANCEL_GRACE_SECONDS:
                    self.kill()
                    raise Cancelled(f"the job did not stop within {CANCEL_GRACE_SECONDS:.0f} s of Cancel")
                if not conn.poll(POLL_SECONDS):
                    if not process.is_alive():
                        raise EOFError
                    continue
                kind, value = conn.recv()
            except (EOFError, OSError):
                process.join(1.0)  # the pipe closes a moment before the process is reaped
                code = process.exitcode
                self.kill()
                raise WorkerDied(f"the worker process stopped in the middle of the job (exit code {code})") from None
            if kind == "progress":
                if progress is not None:
                    progress(value)
            elif kind == "result":
                return value
            else:
                error, tb = value
                raise error from RemoteTraceback(tb)

    def kill(self) -> None:
        """End the process now (it is started again for the next job)."""
        conn, self.conn = self.conn, None
        process, self.process = self.process, None
        if conn is not None:
            conn.close()
        if process is not None:
            try:
                os.killpg(process.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):  # gone, or not yet in its own group
                process.kill()
            process.join(REAP_SECONDS)

    def stop(self) -> None:
        """Ask the process to leave; kill it if it does not within :data:`STOP_SECONDS`."""
        process, conn = self.process, self.conn
        if process is None:
            return
        try:
            if conn is not None:
                conn.send(None)
        except (OSError, ValueError):
            pass
        process.join(STOP_SECONDS)
        self.kill()


class ProcessPool:
    """``workers`` worker processes that run module-level functions for the sessions: at most
    that many at once, the rest wait their turn. Functions must accept ``progress`` and ``cancel``
    keywords (a :data:`~.progress.Progress` and a :data:`~.progress.CancelCheck`, as the grasp planner does).

    ``nice``: added to the workers' niceness, so that where cores are short the server's own
    threads (a user's click) come first and the jobs take the time left over.
    """

    def __init__(self, workers: int = 1, name: str = "viewer-grasp", *, nice: int = 10) -> None:
        if workers < 1:
            raise ValueError(f"a process pool needs at least one worker, not {workers}")
        self.workers = workers
        ctx = mp.get_context("spawn")
        self._all = [_Worker(ctx, f"{name}-{i}", nice) for i in range(workers)]
        self._idle = list(self._all)
        self._cond = threading.Condition()
        self._submitted = 0  # running + waiting
        self._closed = False

    @property
    def full(self) -> bool:
        """Whether every worker is busy (new work waits)."""
        return self._submitted >= self.workers

    def run(
        self,
        fn: Callable[..., T],
        *args: Any,
        progress: Progress | None = None,
        cancel: threading.Event | None = None,
        **kwargs: Any,
    ) -> T:
        """``fn(*args, progress=..., cancel=..., **kwargs)`` computed in a worker process; returns
        or raises what it does (arguments and result are pickled). ``progress`` is called in
        this thread; setting ``cancel`` makes the worker's ``cancel()`` true.

        Raises:
            Cancelled: ``cancel`` was set before a worker was free, or the worker had to be killed to
                stop it (a job that stops by itself raises what it raises, often ``Cancelled`` too).
            WorkerDied: the worker process ended during the job.
            RuntimeError: the pool is shut down.
        """
        with self._cond:
            self._submitted += 1
            try:
                while not self._idle and not self._closed:
                    if cancel is not None and cancel.is_set():
                        raise Cancelled("cancelled while waiting for a worker")
                    self._cond.wait(POLL_SECONDS)
                if self._closed:
                    raise RuntimeError("the viewer is stopping")
                worker = self._idle.pop()
            except BaseException:
                self._submitted -= 1
                raise
        try:
            return worker.call(fn, args, kwargs, progress, cancel)
        finally:
            with self._cond:
                self._submitted -= 1
                self._idle.append(worker)
                self._cond.notify()

    def workers_alive(self) -> int:
        """How many worker processes run now (they start on first use)."""
        return sum(w.process is not None and w.process.is_alive() for w in self._all)

    def shutdown(self) -> None:
        """Stop every worker process (running jobs end with :class:`WorkerDied`)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        for w in self._all:
            try:
                w.stop()
            except Exception:
                log.debug("could not stop %s", w.name, exc_info=True)
