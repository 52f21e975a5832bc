"""How long jobs report progress and learn that they should stop.

A job takes ``progress: Progress | None`` and ``cancel: CancelCheck | None`` keywords:

* ``progress(fraction)``: the share of the job done, 0..1 (a job may report the same fraction
  again; callers should not rely on it reaching exactly 1);
* ``cancel()``: True once the caller wants the job to stop; the job then raises
  :class:`~shapeviewer.errors.Cancelled` (or returns what it has, when its result says so).

The grasp planner, the robustness ranking and the viewer's worker processes
(:mod:`shapeviewer.runtime.processes`, which carry both across the process boundary) use these.
"""

from __future__ import annotations

from collections.abc import Callable

Progress = Callable[[float], None]
"""``progress(fraction)``: the share of a job done so far, 0..1."""

CancelCheck = Callable[[], bool]
"""``cancel()``: whether the job's caller asked it to stop."""


def scaled(progress: Progress | None, start: float, end: float) -> Progress | None:
    """The progress of one stage that takes the share ``start``..``end`` (fractions, 0..1) of a job:
    the stage reports 0..1, ``progress`` gets ``start + fraction * (end - start)``. None stays None."""
    if progress is None:
        return None
    parent = progress  # narrowed for the closure

    def report(fraction: float) -> None:
        parent(start + fraction * (end - start))

    return report


def clamped(fraction: float) -> float:
    """``fraction`` limited to 0..1 (a stage may overshoot by a rounding error)."""
    return min(max(float(fraction), 0.0), 1.0)
