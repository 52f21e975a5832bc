"""The headless browser the load benchmark's ``--browser`` session drives: Debian's Chromium
(``apt-get install chromium``, which ``bash tools/install.sh --test`` installs) with WebGL drawn in
software (SwiftShader), so that it runs on a machine without a GPU. The browser tests launch the same
browser with the same flags (``tests/helpers.py``)."""

from __future__ import annotations

from pathlib import Path

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
