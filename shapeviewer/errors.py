"""The package's own exceptions: every error shapeviewer raises on purpose derives from
:class:`ShapeviewerError`.

Each one also keeps the built-in base that says what kind of problem it is (``CaptureError`` is a
``ValueError``, ``WorkerDied`` a ``RuntimeError``), so a caller may catch either: ``except
ShapeviewerError`` for anything the package reports, ``except ValueError`` for bad input alone.
"""

from __future__ import annotations


class ShapeviewerError(Exception):
    """The base of every error this package raises on purpose (a bad file, a segment too small to
    complete, a worker that died, a cancelled job, ...)."""


class Cancelled(ShapeviewerError):
    """A long job stopped because its caller asked it to (its cancel check returned True, its cancel
    event was set, or the viewer is stopping).

    Planning, ranking and execution of grasps, the viewer's worker processes and the Dataset tab's
    sample build all raise this one class, so a caller tells "stopped on request" from "failed"
    with one ``except Cancelled``.
    """
