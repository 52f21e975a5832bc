"""The ``shapeviewer`` command: ``complete``, ``grasp``, ``serve``, ``generate``, ``train``, ``evaluate`` and more."""

from .main import main

__all__ = ["main"]
