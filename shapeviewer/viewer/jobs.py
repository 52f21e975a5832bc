"""How the viewer runs jobs: one bounded pool of workers shared by every session, a queue per
session, the status line's idle text and downloads.

viser runs plain ``def`` GUI callbacks in its own thread pool, so jobs of several browsers (and two
clicks of one) arrive at once. Each session's :class:`JobQueue` runs its jobs one at a time, in
the caller's thread, and hands their computations (the CNN, meshing, segmenting a capture) to
the :class:`WorkerPool`: at most ``workers`` computations run at once whoever started them, one
user's job never refuses another user's click (it waits its turn in the pool), and a session with
too many jobs waiting is told at once.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

import viser

log = logging.getLogger(__name__)
T = TypeVar("T")

READY = "Ready. Click a segment to complete it."
# notify(client, title, body, color=None, auto_close=8.0): tell a browser (see Audience.notify).
Notify = Callable[..., None]
WAIT_STEP = 0.05  # seconds between looks at a closed session while a job waits


class WorkerPool:
    """A fixed set of ``workers`` threads that run the sessions' computations: at most that many
    compute at once, whoever asked (the model and the meshers are CPU-bound: more at once would
    only slow each one down), and the per-thread state of torch and the C allocator stays bounded
    however many browsers come and go."""

    def __init__(self, workers: int = 2, name: str = "viewer-job") -> None:
        if workers < 1:
            raise ValueError(f"a worker pool needs at least one worker, not {workers}")
        self.workers = workers
        self._executor = ThreadPoolExecutor(max_workers=workers, thread_name_prefix=name)
        self._count = threading.Lock()
        self._submitted = 0  # running + queued

    @property
    def full(self) -> bool:
        """Whether every worker is busy (new work waits)."""
        return self._submitted >= self.workers

    def run(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """``fn(*args, **kwargs)`` computed in a worker (after the work queued before it); returns
        or raises what it does."""
        with self._count:
            self._submitted += 1
        try:
            return self._executor.submit(fn, *args, **kwargs).result()
        finally:
            with self._count:
                self._submitted -= 1

    def shutdown(self) -> None:
        """Drop queued work; the running ones finish in the background."""
        self._executor.shutdown(wait=False, cancel_futures=True)


def send_download(
    client: viser.ClientHandle | None,
    make: Callable[[], tuple[str, bytes]],
    notify: Notify,
    errors: tuple[type[Exception], ...] = (ValueError,),
) -> None:
    """Send the ``(file name, content)`` that ``make`` returns to ``client``'s browser; when it
    raises one of ``errors`` (a message for the user), show that instead."""
    try:
        name, data = make()
    except errors as e:
        notify(client, "Nothing to export", str(e), "red")
        return
    if client is not None:
        client.send_file_download(name, data, save_immediately=True)


class JobQueue:
    """One session's jobs, run one at a time in order (each computes in the shared
    :class:`WorkerPool`); the buttons that start jobs are disabled while one runs (a double click
    would only queue a second job).

    Args:
        buttons: the session's job buttons.
        notify: tells the session's browser that its queue is full.
        max_waiting: jobs that may wait behind the running one; more are refused at once.
    """

    def __init__(
        self,
        buttons: tuple[viser.GuiButtonHandle, ...],
        notify: Notify,
        max_waiting: int = 2,
    ) -> None:
        self.buttons = buttons
        self.notify = notify
        self.max_waiting = max_waiting
        self.closed = threading.Event()  # set when the session closes: waiting jobs give up
        self._turn = threading.Lock()  # held by the session's running job
        self._count = threading.Lock()
        self._queued = 0  # running + waiting

    @property
    def busy(self) -> bool:
        """Whether a job of this session runs or waits."""
        return self._queued > 0

    def close(self) -> None:
        """Refuse new jobs and let waiting ones give up (the running one finishes)."""
        self.closed.set()

    @contextlib.contextmanager
    def take(self, client: viser.ClientHandle | None) -> Iterator[bool]:
        """Yields True while this job runs, or False: the queue was full (the client is told) or
        the session closed while the job waited."""
        with self._count:
            full = self._queued > self.max_waiting
            admitted = not full and not self.closed.is_set()
            if admitted:
                self._queued += 1
        if full:
            self.notify(
                client,
                "Busy",
                f"{self._queued} of your jobs are running or waiting; try again once they are done.",
                auto_close=3.0,
            )
            yield False
            return
        if not admitted:  # the session closed
            yield False
            return
        try:
            with self._wait_turn() as mine:
                if not mine:
                    yield False
                    return
                self._set_buttons(disabled=True)
                try:
                    yield True
                finally:
                    self._set_buttons(disabled=False)
        finally:
            with self._count:
                self._queued -= 1

    @contextlib.contextmanager
    def _wait_turn(self) -> Iterator[bool]:
        while not self._turn.acquire(timeout=WAIT_STEP):
            if self.closed.is_set():
                yield False
                return
        try:
            yield True
        finally:
            self._turn.release()

    def _set_buttons(self, disabled: bool) -> None:
        for b in self.buttons:
            try:
                b.disabled = disabled
            except Exception:  # the tab closed: its buttons are gone
                log.debug("button update failed", exc_info=True)
