"""The scripts in examples/ run as a user would run them and do what they print."""

from __future__ import annotations

import ast
import csv
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

import shapeviewer

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
SCRIPTS = sorted(p.name for p in EXAMPLES.glob("*.py"))
TIMEOUT = 180  # seconds; each example takes 10-20 s on 2 idle cores


def run_example(name: str, out: Path) -> str:
    """Run ``examples/name OUT`` from a foreign working directory; its stdout."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.run(
        [sys.executable, str(EXAMPLES / name), str(out)],
        cwd=out.parent,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def test_the_three_examples_exist():
    assert SCRIPTS == ["complete_capture.py", "evaluate_two_views.py", "plan_grasps.py"]


@pytest.mark.parametrize("name", SCRIPTS)
def test_examples_are_short_and_use_only_the_public_api(name):
    source = (EXAMPLES / name).read_text()
    assert len(source.splitlines()) <= 45, f"{name} should stay a short example"
    tree = ast.parse(source)
    assert ast.get_docstring(tree), f"{name} should say what it does"
    imported = [a.name for node in ast.walk(tree) if isinstance(node, ast.Import) for a in node.names]
    imported += [node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)]
    assert [m for m in imported if m and m.startswith("shapeviewer")] == ["shapeviewer"], name
    used = {
        node.attr
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "sv"
    }
    assert used and used <= set(shapeviewer.__all__), f"{name} uses {sorted(used - set(shapeviewer.__all__))}"


@pytest.mark.slow
def test_complete_capture_writes_a_closed_mesh(tmp_path):
    out = tmp_path / "out"
    stdout = run_example("complete_capture.py", out)
    (path,) = out.glob("segment_*_detailed.ply")
    assert f"wrote {path}" in stdout and "watertight: True" in stdout
    mesh = trimesh.load(path, force="mesh")
    assert mesh.is_watertight and mesh.volume > 0
    # The printed size is the file's, and that of a bottle or carton: 5-40 cm on every side.
    size = re.search(r"size: ([\d.]+) x ([\d.]+) x ([\d.]+) cm, volume (\d+) cm\^3", stdout)
    assert size, stdout
    printed = np.array([float(v) for v in size.groups()[:3]])
    assert np.allclose(printed, 100 * mesh.extents, atol=0.06)
    assert np.all((printed > 5) & (printed < 40))
    assert float(size.group(4)) == pytest.approx(1e6 * mesh.volume, abs=1)


@pytest.mark.slow
def test_plan_grasps_prints_and_writes_the_best_grasps(tmp_path):
    out = tmp_path / "out"
    stdout = run_example("plan_grasps.py", out)
    mesh = trimesh.load(out / "object_world.ply", force="mesh")
    assert mesh.is_watertight and mesh.bounds[0, 2] > -0.03  # standing on the table, z up
    with open(out / "grasps.csv") as f:
        rows = list(csv.DictReader(f))
    assert 1 <= len(rows) <= 3
    printed = re.findall(r"^#\d+: (lifts|does not lift) the object, epsilon (-?[\d.]+)", stdout, flags=re.M)
    assert [float(e) for _, e in printed] == pytest.approx([float(r["epsilon"]) for r in rows], abs=1e-4)
    lifted = [r["lifted"] == "True" for r in rows]
    assert [w == "lifts" for w, _ in printed] == lifted
    # Best first: the planner's lift check holds the completed object, and those that lift come first.
    assert lifted[0] and lifted == sorted(lifted, reverse=True)
    # Each palm is at the object, not somewhere else in the scene.
    for r in rows:
        palm = np.array([float(r[k]) for k in "xyz"])
        assert np.min(np.linalg.norm(mesh.vertices - palm, axis=1)) < 0.1


@pytest.mark.slow
def test_evaluate_two_views_writes_the_tables(tmp_path):
    out = tmp_path / "out"
    stdout = run_example("evaluate_two_views.py", out)
    assert "2 views computed, 0 reused" in stdout
    for name in ("tables.md", "tables.csv", "rows.csv"):
        assert (out / name).is_file(), name
    assert (out / "tables.md").read_text().strip() in stdout
    with open(out / "rows.csv") as f:
        rows = list(csv.DictReader(f))
    assert len({(r["object"], r["view"]) for r in rows}) == 2
    assert {r["method"] for r in rows} == {"Partial", "Mirror", "Hull", "Ours-fast", "Ours-detailed"}
    ours = [float(r["jaccard"]) for r in rows if r["method"] == "Ours-fast"]
    assert all(0.0 < j <= 1.0 for j in ours), ours
    assert re.search(r"\| Tabletop, training objects \| \d\.\d{3} ", stdout)
