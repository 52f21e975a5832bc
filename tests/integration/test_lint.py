"""The linter, the formatter check and the type checker pass on the whole repository (configured in
pyproject.toml), so that CI catches a lint or type error like any other failing test."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SOURCES = ["shapeviewer", "tests", "benchmarks", "examples", "tools", "app.py"]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=600)


def test_ruff_check_is_clean():
    out = _run(sys.executable, "-m", "ruff", "check", "--no-cache", *SOURCES)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]


def test_ruff_format_is_clean():
    out = _run(sys.executable, "-m", "ruff", "format", "--check", "--no-cache", *SOURCES)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]


def test_mypy_is_clean():
    out = _run(sys.executable, "-m", "mypy", "--cache-dir", "/tmp/shapeviewer-mypy-cache")
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
