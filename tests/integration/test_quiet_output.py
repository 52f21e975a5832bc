"""The command and the library print only their own messages: no pybullet build banner on import,
no ``argv[0]=`` line when a simulated scene is made."""

from __future__ import annotations

import subprocess
import sys

import pytest

SCRIPT = """
import shapeviewer.grasp.plan  # imports pybullet
from shapeviewer.sim.demo_scene import direct_client
client = direct_client()
print("ready", client.getPhysicsEngineParameters()["fixedTimeStep"] > 0)
"""


def test_library_prints_no_pybullet_banner():
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ready True"
    assert "pybullet build time" not in out.stderr and "argv[0]" not in out.stdout + out.stderr


@pytest.mark.slow
def test_complete_prints_only_its_own_lines(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "shapeviewer", "complete", "default", "--segment", "0", "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr
    assert "argv[0]" not in out.stdout + out.stderr and "pybullet build time" not in out.stderr
    assert out.stdout.strip().splitlines()[-1].startswith("1/1 segments completed")
