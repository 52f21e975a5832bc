"""The ``shapeviewer`` command: ``complete``, ``grasp``, ``serve``, ``generate``, ``train``, ``evaluate`` and more."""

from .commands import main

__all__ = ["main"]
