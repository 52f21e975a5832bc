"""pybullet, imported without the build banner its C code prints on stderr, and DIRECT clients
connected without the ``argv[0]=`` line pybullet prints on stdout when given an options string.

Import pybullet through this module (``from ..runtime.bullet import pybullet as p``) so that neither
the command's stderr (its own one-line messages) nor a library user's output carries them.
"""

from __future__ import annotations

import os
import sys
from types import ModuleType


def _import_quietly() -> ModuleType:
    """``import pybullet`` with file descriptor 2 pointed at /dev/null while its C code loads."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
        import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    return pybullet


pybullet = _import_quietly()


def direct_client():
    """A ``pybullet_utils`` :class:`BulletClient` in DIRECT mode (headless, in this process).

    ``BulletClient(connection_mode=DIRECT)`` passes an empty options string to ``pybullet.connect``,
    which makes pybullet print ``argv[0]=``; this connects without one."""
    from pybullet_utils.bullet_client import BulletClient

    class _DirectClient(BulletClient):
        def __init__(self) -> None:  # BulletClient's own attributes, set as its __init__ does
            self._shapes: dict = {}
            self._pid = os.getpid()
            self._client = pybullet.connect(pybullet.DIRECT)

    return _DirectClient()
