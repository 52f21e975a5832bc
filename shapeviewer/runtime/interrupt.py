"""Ctrl-C (SIGINT) and SIGTERM stop a ``shapeviewer`` command within seconds, leaving no child process.

Python turns SIGINT into ``KeyboardInterrupt`` in the main thread, but only between bytecodes: a
main thread inside a long C call, an interpreter exit that joins a busy thread pool, or a child
process (V-HACD, pool workers, Ray) that never got the signal can each keep the command alive for
as long as their work lasts. :func:`interrupt_watch` therefore also hears the signal on a thread
of its own (through ``signal.set_wakeup_fd``, which the C-level handler writes at once), kills every
descendant process straight away, lets the main thread unwind normally (``finally`` blocks, an empty
``--out`` folder removed), and ends the process with exit code 130 if it is still alive
:data:`HARD_EXIT_SECONDS` later.

Descendants are found in ``/proc`` (Linux); elsewhere only the main-thread ``KeyboardInterrupt`` applies.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

# Ctrl-C to exit: within the 3 s a user waits, after the main thread had its chance to clean up.
HARD_EXIT_SECONDS = 2.5
# Children get SIGTERM first (pool workers and Ray clean up on it), then SIGKILL this much later.
TERM_GRACE_SECONDS = 0.3


def descendants(pid: int | None = None) -> list[int]:
    """Process ids of every descendant of ``pid`` (default: this process), children first."""
    root = os.getpid() if pid is None else pid
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir() if Path("/proc").is_dir() else ():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # gone meanwhile
            continue
        # "pid (comm) state ppid ...": comm may hold spaces and parentheses, so split after the last ')'.
        ppid = int(stat[stat.rindex(")") + 2 :].split()[1])
        children.setdefault(ppid, []).append(int(entry.name))
    out: list[int] = []
    todo = [root]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def kill_descendants(grace: float = TERM_GRACE_SECONDS) -> list[int]:
    """SIGTERM every descendant, SIGKILL those still there after ``grace`` seconds; returns their ids.

    multiprocessing's resource tracker is spared: it ends by itself when this process does, and
    killing it makes the pool's clean-up start a new one that prints tracebacks.
    """
    pids = [pid for pid in descendants() if pid != _resource_tracker_pid()]
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        deadline = time.monotonic() + grace
        while sig == signal.SIGTERM and time.monotonic() < deadline and any(alive(p) for p in pids):
            time.sleep(0.02)
    for pid in pids:  # reap our own children so that they do not linger as zombies
        with contextlib.suppress(ChildProcessError, OSError):
            os.waitpid(pid, os.WNOHANG)
    return pids


def _resource_tracker_pid() -> int | None:
    tracker = sys.modules.get("multiprocessing.resource_tracker")
    return getattr(getattr(tracker, "_resource_tracker", None), "_pid", None)


def alive(pid: int) -> bool:
    """Whether process ``pid`` exists and has not exited (a zombie only waits to be reaped)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return state[state.rindex(")") + 2] != "Z"  # a zombie has exited already


@contextlib.contextmanager
def interrupt_watch(hard_exit_seconds: float = HARD_EXIT_SECONDS) -> Iterator[None]:
    """While the block runs, SIGINT/SIGTERM kill the descendants at once and end the process
    ``hard_exit_seconds`` later if the main thread has not finished by then (see the module docstring).

    Only in the main thread (signals are delivered there); elsewhere it does nothing. Restores the
    previous handlers and wakeup fd on leaving.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)  # the C handler must never block on a full pipe
    previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    previous_term = signal.getsignal(signal.SIGTERM)
    previous_int = signal.getsignal(signal.SIGINT)

    def raise_interrupt(signum, frame):  # SIGTERM (e.g. from `timeout`) unwinds like Ctrl-C
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, raise_interrupt)
    if previous_int in (signal.SIG_IGN, signal.SIG_DFL, None):
        signal.signal(signal.SIGINT, signal.default_int_handler)
    _signalled.clear()
    watcher = threading.Thread(target=_watch, args=(read_fd, hard_exit_seconds), name="interrupt-watch", daemon=True)
    watcher.start()
    try:
        yield
    finally:
        signal.set_wakeup_fd(previous_fd)
        signal.signal(signal.SIGTERM, previous_term)
        signal.signal(signal.SIGINT, previous_int)
        os.close(write_fd)  # ends the watcher, unless it is already counting down to the hard exit


_signalled = threading.Event()  # set once a watched block gets SIGINT/SIGTERM


def interrupted() -> bool:
    """Whether the running (or last) :func:`interrupt_watch` block got SIGINT or SIGTERM: its
    killing of the children may surface in the main thread as their failure before the
    ``KeyboardInterrupt`` does."""
    return _signalled.is_set()


def _watch(read_fd: int, hard_exit_seconds: float) -> None:
    wanted = {int(signal.SIGINT), int(signal.SIGTERM)}
    try:
        while True:
            data = os.read(read_fd, 64)
            if not data:  # the block ended without a signal
                return
            if wanted & set(data):
                break
    finally:
        os.close(read_fd)
    _signalled.set()
    kill_descendants()
    time.sleep(hard_exit_seconds)
    # Still here: the main thread is stuck (a C call, a thread pool joined at exit). Nothing it
    # could still do is worth more than stopping now, as the user asked.
    with contextlib.suppress(Exception):
        sys.stderr.write("shapeviewer: interrupted\n")
        sys.stderr.flush()
    kill_descendants(grace=0.0)
    os._exit(130)
