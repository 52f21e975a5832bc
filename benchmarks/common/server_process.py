"""The viewer server as a subprocess for the benchmarks: its log, its memory (with the processes it
started) and how it stops after Ctrl-C."""

from __future__ import annotations

import asyncio
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from shapeviewer.runtime.interrupt import alive, descendants

ROOT = Path(__file__).resolve().parents[2]  # the checkout whose app.py is served
STOP_TARGET = 3.0  # s from Ctrl-C until the server and every process it started have gone


def command(pid: int) -> str:
    """Process ``pid``'s command line (shortened)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")[:80]
    except OSError:
        return "?"


def _own_rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def rss_mb(pid: int) -> float | None:
    """Resident memory of process ``pid`` and every process it started (MB), or None when it has gone."""
    own = _own_rss_mb(pid)
    if own is None:
        return None
    return own + sum(filter(None, map(_own_rss_mb, descendants(pid))))


class Server:
    """The viewer server as a subprocess (``python app.py``), its log in a temporary file."""

    def __init__(self, port: int, extra_args: list[str], root: Path = ROOT) -> None:
        self.log = Path(tempfile.mkstemp(prefix="shapeviewer-load-", suffix=".log")[1])
        self.cmd = [sys.executable, str(root / "app.py"), "--port", str(port), *extra_args]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")])))
        with self.log.open("w") as out:
            self.proc = subprocess.Popen(
                self.cmd, cwd=root, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
            )
        self.pid = self.proc.pid
        self.stop_seconds: float | None = None
        self.children_left: list[str] = []  # 'pid command'  # processes it started that outlived it

    def wait_ready(self, timeout: float) -> str:
        """The URL the server prints once it serves (raises if it exits or takes longer than ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = re.search(r"ready on (\S+)", self.log.read_text(errors="replace"))
            if found:
                return found.group(1)
            if self.proc.poll() is not None:
                raise RuntimeError(f"the server exited ({self.proc.returncode}); its log:\n{self.log_tail()}")
            time.sleep(0.2)
        raise RuntimeError(f"the server was not ready within {timeout:.0f} s; its log:\n{self.log_tail()}")

    def log_tail(self, n: int = 30) -> str:
        return "\n".join(self.log.read_text(errors="replace").splitlines()[-n:])

    def tracebacks(self) -> int:
        return self.log.read_text(errors="replace").count("Traceback (most recent call last)")

    def stop(self, timeout: float = 15.0) -> None:
        """Ctrl-C (SIGINT) to the server, SIGKILL if it has not exited within ``timeout`` s."""
        if self.proc.poll() is not None:
            return
        children = descendants(self.pid)
        t0 = time.monotonic()
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout)
            self.stop_seconds = time.monotonic() - t0
            # The multiprocessing resource tracker leaves a moment after its last user: what still
            # runs STOP_TARGET seconds after Ctrl-C is left behind.
            while any(map(alive, children)) and time.monotonic() - t0 < STOP_TARGET:
                time.sleep(0.05)
            self.children_left = [f"{c} {command(c)}" for c in children if alive(c)]
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)


class MemoryWatch:
    """Samples a process's RSS every ``interval`` s in the background; ``peak`` since :meth:`reset_peak`."""

    def __init__(self, pid: int | None, interval: float = 0.25) -> None:
        self.pid = pid
        self.interval = interval
        self.peak: float | None = None
        self._task: asyncio.Task | None = None

    def now(self) -> float | None:
        return None if self.pid is None else rss_mb(self.pid)

    def reset_peak(self) -> None:
        self.peak = self.now()

    async def _run(self) -> None:
        while True:
            value = self.now()
            if value is not None:
                self.peak = value if self.peak is None else max(self.peak, value)
            await asyncio.sleep(self.interval)

    def start(self) -> None:
        if self.pid is not None:
            self._task = asyncio.create_task(self._run())

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
