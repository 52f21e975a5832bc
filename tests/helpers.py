"""Helpers shared by the test modules: a free port, polling, scene nodes and a headless browser.

Test modules import them as ``from helpers import ...`` (pytest puts ``tests/`` on ``sys.path``, as it
does for ``store_factory``). Nothing here imports shapeviewer's heavy modules.
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

try:
    from playwright.sync_api import sync_playwright
except ImportError:  # pragma: no cover - depends on the environment
    sync_playwright = None

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]

needs_browser = pytest.mark.skipif(
    not CHROMIUM.exists() or sync_playwright is None,
    reason="needs Debian chromium at /usr/bin/chromium (apt-get install chromium) and playwright "
    "(pip install playwright)",
)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(predicate: Callable[[], Any], timeout: float, what: str, step: float = 0.1) -> Any:
    """Poll ``predicate`` until it returns something truthy (returned) or fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def node(app, name: str):
    """The viewer's scene node called ``name`` (e.g. ``/fast_mesh/seg_0``), or None."""
    return app.server.scene.get_handle_by_name(name)


@contextlib.contextmanager
def browser_page(app, **page_options) -> Iterator:
    """A headless Chromium page connected to ``app`` (closed afterwards); ``page_options`` go to
    ``new_page`` (default viewport 1280x800)."""
    page_options.setdefault("viewport", {"width": 1280, "height": 800})
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(**page_options)
            page.goto(app.url)
            page.wait_for_function("!document.body.innerText.includes('Connecting')", timeout=30_000)
            yield page
        finally:
            browser.close()
