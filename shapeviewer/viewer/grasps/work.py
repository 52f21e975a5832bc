"""Running a session's grasp jobs: one at a time, each in a background thread, outside the
session's job queue (:class:`~..jobs.JobQueue`), so the rest of the viewer keeps working meanwhile.
Planning, executing and ranking are the heaviest jobs there are and hold the GIL for seconds, so
they compute in worker processes (:class:`~shapeviewer.runtime.processes.ProcessPool`) shared by every session: other
users' clicks keep the server's interpreter and the main pool's workers.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
import viser

from ...errors import Cancelled
from ...grasp.pick import Runner
from ...grasp.search import ProgressFn
from ...runtime.processes import ProcessPool
from ..gui import set_value
from ..jobs import READY, Notify
from .controls import GraspPanel
from .state import GraspJob, GraspJobError

log = logging.getLogger(__name__)
T = TypeVar("T")

JOB_TITLES = {"plan": "planning", "execute": "execution", "rank": "ranking"}  # job kind -> what failed


class GraspJobs:
    """Starts grasp jobs and shows their progress in the Grasps folder.

    Args:
        panel: the Grasps folder (job buttons, Cancel, progress bar).
        pool: the worker processes grasp jobs compute in.
        notify: tells the browsers about failures and a busy runner.
        set_status: the panel's status line (:data:`~..jobs.READY` when a job ends).
        can_rank: whether there are grasps to rank (the listed segment has some).
    """

    def __init__(
        self,
        panel: GraspPanel,
        pool: ProcessPool,
        notify: Notify,
        set_status: Callable[[str], None],
        can_rank: Callable[[], bool],
    ) -> None:
        self.panel = panel
        self.can_rank = can_rank
        self.pool = pool
        self.notify = notify
        self.set_status = set_status
        self.job: GraspJob | None = None  # the running or last job
        self.busy = threading.Lock()  # held by the running job
        self._last_progress = -1

    def start(
        self,
        kind: str,
        segment_id: int,
        client: viser.ClientHandle | None,
        wait: bool,
        work: Callable[[GraspJob], object],
    ) -> GraspJob | None:
        """Run ``work(job)`` in a background thread unless a grasp job already runs (``wait``:
        return once it has finished). ``kind``: one of :data:`JOB_TITLES`."""
        if not self.busy.acquire(blocking=False):
            self.notify(client, "Busy", "A grasp job is running: wait for it or press Cancel.", auto_close=3.0)
            return None
        job = GraspJob(kind, segment_id)
        self.job = job
        self._set_running(True)

        def run() -> None:
            try:
                job.result = work(job)
            except Cancelled:  # Cancel (or a closed tab) stopped it: no news
                job.error = "cancelled"
            except GraspJobError as e:
                job.error = str(e)
                if not job.cancel_event.is_set():  # after Cancel (or a new scene) it is no news
                    self.notify(client, "Grasps", str(e), "red")
            except Exception as e:  # a bad mesh, pybullet, a vanished client...: keep the app alive
                log.exception("grasp %s job on segment %s failed", kind, segment_id)
                job.error = f"{type(e).__name__}: {e}"
                self.notify(
                    client,
                    f"Grasp {JOB_TITLES[kind]} failed",
                    f"Segment {segment_id}: {e}",
                    "red",
                )
            finally:
                job.cancelled = job.cancel_event.is_set()
                self._set_running(False)
                self.busy.release()
                job.done.set()

        job.thread = threading.Thread(target=run, name=f"grasp-{kind}-seg{segment_id}", daemon=True)
        job.thread.start()
        if wait:
            job.thread.join()
        return job

    def compute(self, job: GraspJob, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """``fn(*args, **kwargs)`` (a module-level function that takes ``progress`` and ``cancel``
        keywords) computed in a worker process, its progress on the bar; ``job``'s Cancel reaches it."""
        if self.pool.full:
            self.set_status("_Grasps: waiting for a free worker (others are planning)..._")
        return self.pool.run(fn, *args, progress=self.progress, cancel=job.cancel_event, **kwargs)

    def runner(self, job: GraspJob) -> Runner:
        """A :data:`~shapeviewer.grasp.pick.Runner` for the pick's stages in ``job``: each computed in a
        worker process as :meth:`compute` computes, with the pick's own progress (its share of the
        whole pick) on the bar."""

        def run(fn: Callable[..., T], *args: Any, progress: ProgressFn | None = None, **kwargs: Any) -> T:
            kwargs.pop("cancel", None)  # the worker's cancel() answers job's Cancel
            if self.pool.full:
                self.set_status("_Grasps: waiting for a free worker (others are planning)..._")
            return self.pool.run(fn, *args, progress=progress, cancel=job.cancel_event, **kwargs)

        return run

    def running(self) -> bool:
        """Whether a job runs now."""
        return self.running_job() is not None

    def running_job(self) -> GraspJob | None:
        """The job that runs now, or None."""
        job = self.job
        return job if job is not None and not job.done.is_set() else None

    def cancel(self) -> bool:
        """Ask the running job to stop; False when none runs."""
        job = self.running_job()
        if job is None:
            return False
        job.cancel()
        self.set_status("_Cancelling the grasp job..._")
        return True

    def shutdown(self, timeout: float = 10.0) -> None:
        """Cancel the running job and wait for its thread (before the session closes)."""
        job = self.job
        if job is not None and job.thread is not None:
            job.cancel()
            job.thread.join(timeout)

    def progress(self, fraction: float) -> None:
        """A job's progress (0..1) on the bar, sent only when a whole percent changes."""
        pct = int(np.clip(100 * fraction, 0, 100))
        if pct != self._last_progress:
            self._last_progress = pct
            set_value(self.panel.progress, float(pct))

    def refresh_rank(self, running: bool | None = None) -> None:
        """Enable Rank by robustness when no job runs (``running``; None: ask) and there are grasps."""
        self.panel.rank.disabled = (self.running() if running is None else running) or not self.can_rank()

    def _set_running(self, running: bool) -> None:
        """Buttons, progress bar and status while a job runs (and back when it ends)."""
        try:
            for b in self.panel.job_buttons:
                b.disabled = running
            # The job is not done yet when it ends here, so say whether one runs.
            self.refresh_rank(running)
            self.panel.cancel.disabled = not running
            set_value(self.panel.progress, 0.0)
            self.panel.progress.visible = running
            self._last_progress = -1
            if not running:
                self.set_status(READY)
        except Exception:  # the tab closed or the server is stopping
            log.debug("could not update the grasp panel", exc_info=True)
