"""The command line on bad input and Ctrl-C: a one-line message on stderr, a non-zero exit code, no
traceback, within 30 s; no child process and no empty ``--out`` folder left behind; every V-HACD run
and wait bounded; the V-HACD cache bounded.

Commands run as subprocesses (``python -m shapeviewer``) with a private cache folder.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from shapeviewer.grasp import world as W
from shapeviewer.runtime.interrupt import alive, descendants

from helpers import free_port

ROOT = Path(__file__).resolve().parents[2]
MUG = ROOT / "static_assets" / "captures" / "table_scene_mug_stereo_textured.pcd"
LIMIT = 30.0  # seconds any bad-input case may take
# Seconds after which a Ctrl-C counts as hung. The 3 s target is measured by benchmarks/load.py,
# not here: a loaded machine may take a little longer without anything being wrong.
STOP_LIMIT = 10.0


@pytest.fixture()
def env(tmp_path: Path) -> dict[str, str]:
    cache = tmp_path / "cache"
    cache.mkdir()
    return {**os.environ, "SHAPEVIEWER_CACHE": str(cache), "OMP_NUM_THREADS": "1"}


def run_cli(args: list, env: dict, cwd: Path, timeout: float = LIMIT) -> subprocess.CompletedProcess:
    t0 = time.monotonic()
    out = subprocess.run(
        [sys.executable, "-m", "shapeviewer", *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout + 30,
    )
    out.seconds = time.monotonic() - t0
    return out


def assert_one_line_error(out: subprocess.CompletedProcess, *words: str) -> str:
    """A clean failure: non-zero, one line on stderr naming ``words``, no traceback, in time."""
    assert out.returncode != 0, out.stdout
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, out.stderr
    assert "Traceback" not in out.stderr and "Traceback" not in out.stdout
    for w in words:
        assert w in lines[0], lines[0]
    assert out.seconds < LIMIT, f"took {out.seconds:.1f} s"
    return lines[0]


def test_complete_out_is_an_existing_file(tmp_path, env):
    (tmp_path / "taken.txt").write_text("mine")
    out = run_cli(["complete", MUG, "--out", "taken.txt"], env, tmp_path)
    assert_one_line_error(out, "taken.txt", "not a folder")
    assert (tmp_path / "taken.txt").read_text() == "mine"


def test_complete_without_segments_says_so_and_leaves_no_out_folder(tmp_path, env):
    np.save(tmp_path / "empty_room.npy", np.random.default_rng(0).uniform([-1, -1, 0.5], [1, 1, 2.5], (2000, 3)))
    out = run_cli(["complete", "empty_room.npy", "--segment", "all", "--out", "out/run1"], env, tmp_path)
    assert_one_line_error(out, "no segments found", "empty_room.npy")
    assert not (tmp_path / "out").exists(), "a failed command left its empty --out folder"


def test_complete_of_a_missing_file(tmp_path, env):
    out = run_cli(["complete", "nothing.pcd", "--out", "out"], env, tmp_path)
    assert_one_line_error(out, "nothing.pcd", "not found")
    assert not (tmp_path / "out").exists()


def _write_meshes(folder: Path) -> None:
    trimesh.PointCloud(np.random.default_rng(1).uniform(0, 0.1, (200, 3))).export(folder / "points.ply")
    (folder / "nothing.obj").write_text("# no faces\nv 0 0 0\nv 0.1 0 0\n")
    trimesh.Trimesh([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], [[0, 1, 2]]).export(folder / "triangle.ply")
    (folder / "garbage.ply").write_bytes(b"ply\nformat nonsense\n\x00\x01\x02")
    box = trimesh.creation.box((0.05, 0.05, 0.1))
    box.export(folder / "box.ply")
    box.update_faces(np.arange(len(box.faces)) >= 2)  # the top face gone: an open box
    box.remove_unreferenced_vertices()
    box.export(folder / "open_box.ply")


@pytest.mark.parametrize(
    "mesh, words",
    [
        ("points.ply", ["points.ply", "no triangles"]),
        ("nothing.obj", ["nothing.obj", "no triangles"]),
        ("triangle.ply", ["triangle.ply", "flat"]),
        ("garbage.ply", ["garbage.ply", "not a readable mesh"]),
        ("missing.ply", ["missing.ply", "not found"]),
    ],
)
def test_grasp_on_a_bad_mesh(tmp_path, env, mesh, words):
    _write_meshes(tmp_path)
    out = run_cli(["grasp", mesh, "--out", "grasps.json", "--budget", "30"], env, tmp_path)
    assert_one_line_error(out, *words)
    assert not (tmp_path / "grasps.json").exists()


def test_grasp_out_in_a_missing_folder(tmp_path, env):
    _write_meshes(tmp_path)
    out = run_cli(["grasp", "box.ply", "--out", "no/such/grasps.json"], env, tmp_path)
    assert_one_line_error(out, "no/such", "does not exist")


@pytest.mark.slow
def test_grasp_on_an_open_mesh_warns(tmp_path, env):
    _write_meshes(tmp_path)
    out = run_cli(["grasp", "open_box.ply", "--out", "grasps.json", "--n", "2", "--budget", "20"], env, tmp_path)
    assert out.returncode == 0, out.stderr
    assert "not watertight" in out.stderr and "Traceback" not in out.stderr
    assert (tmp_path / "grasps.json").exists()


HANGING_VHACD = textwrap.dedent("""
    import sys
    from shapeviewer.cli import commands as cli
    cli._import_pybullet_quietly()
    from shapeviewer.grasp import world
    world._VHACD_CHILD = "import time; time.sleep(600)"  # a V-HACD that never returns
    sys.exit(cli.main(sys.argv[1:]))
""")


def test_grasp_budget_bounds_a_hanging_decomposition(tmp_path, env):
    _write_meshes(tmp_path)
    t0 = time.monotonic()
    out = subprocess.run(
        [sys.executable, "-c", HANGING_VHACD, "grasp", "box.ply", "--out", "grasps.json", "--budget", "8"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=90,
    )
    out.seconds = time.monotonic() - t0
    assert_one_line_error(out, "V-HACD", "did not finish")
    assert out.seconds < 8 + 10, f"--budget 8 took {out.seconds:.1f} s"
    assert not list((Path(env["SHAPEVIEWER_CACHE"]) / "vhacd").glob("tmp*")), "the killed run's temp folder is left"


BOUNDED_RUN = textwrap.dedent("""
    import sys, time, trimesh
    from shapeviewer.grasp.world import Decomposition, DecompositionError, convex_decomposition
    from shapeviewer.runtime.interrupt import descendants
    triangle = trimesh.Trimesh([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], [[0, 1, 2]])  # V-HACD spins forever
    t0 = time.monotonic()
    try:
        convex_decomposition(triangle, timeout=2)
        print("no error")
    except DecompositionError as e:
        print(f"waited {time.monotonic() - t0:.1f} s: {e}")
    print("children", len(descendants()))
    d = Decomposition(triangle, timeout=2)  # nobody waits: the child stops itself
    time.sleep(4)
    print("abandoned child exited", d.process.poll() is not None)
""")


def test_every_vhacd_run_is_bounded(tmp_path, env):
    out = subprocess.run([sys.executable, "-c", BOUNDED_RUN], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("waited") and float(lines[0].split()[1]) < 5, lines
    assert "children 0" in lines and "abandoned child exited True" in lines


def test_vhacd_cache_is_bounded_least_recently_used_first(tmp_path, monkeypatch):
    monkeypatch.setenv("SHAPEVIEWER_CACHE", str(tmp_path))
    monkeypatch.setenv("SHAPEVIEWER_VHACD_CACHE_MB", "0.05")  # 52 kB
    folder = tmp_path / "vhacd"
    folder.mkdir()
    now = time.time()
    for i in range(10):  # 10 x 10 kB, file 0 the least recently used
        f = folder / f"old{i}_r100000.obj"
        f.write_bytes(b"#" * 10_000)
        os.utime(f, (now - 1000 + i, now - 1000 + i))
    os.utime(folder / "old0_r100000.obj")  # used just now: the most recent
    stale = folder / "tmpkilled"
    stale.mkdir()
    os.utime(stale, (now - 3600, now - 3600))
    path = W.convex_decomposition(trimesh.creation.box((0.05, 0.05, 0.1)))
    left = {p.name for p in folder.iterdir()}
    assert path.name in left and not stale.exists()
    assert sum(p.stat().st_size for p in folder.glob("old*")) <= 52_429
    assert "old0_r100000.obj" in left and "old1_r100000.obj" not in left and "old9_r100000.obj" in left


def _interrupt(proc: subprocess.Popen, children: list[int]) -> tuple[float, str]:
    """SIGINT to the command alone (not its process group, so its children get nothing): seconds
    until it exited and its stderr, after checking that it left no child alive."""
    proc.send_signal(signal.SIGINT)
    t0 = time.monotonic()
    _, stderr = proc.communicate(timeout=30)
    seconds = time.monotonic() - t0
    deadline = time.monotonic() + 1.0  # multiprocessing's tracker ends on its own when its parent does
    while any(map(alive, children)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(map(alive, children)), f"children left running: {[c for c in children if alive(c)]}"
    return seconds, stderr


def test_ctrl_c_stops_a_command_with_worker_processes(tmp_path, env):
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "shapeviewer.cli.commands",
            "generate",
            "--out",
            "gen",
            "--views",
            "1",
            "--workers",
            "2",
            "--objects",
            "ycb/002_master_chef_can",
            "ycb/003_cracker_box",
        ],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while len(descendants(proc.pid)) < 2 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(1.0)  # the workers are busy importing and generating
    children = descendants(proc.pid)
    assert len(children) >= 2 and proc.poll() is None
    seconds, _ = _interrupt(proc, children)
    assert seconds <= STOP_LIMIT, f"Ctrl-C took {seconds:.1f} s"
    assert proc.returncode == 130
    assert not (tmp_path / "gen").exists() or any(p.is_file() for p in (tmp_path / "gen").rglob("*"))


def test_ctrl_c_stops_grasp_planning_and_its_vhacd_child(tmp_path, env):
    """The hardest case: V-HACD never returns, and Ctrl-C still stops the command and its child."""
    _write_meshes(tmp_path)
    proc = subprocess.Popen(
        [sys.executable, "-c", HANGING_VHACD, "grasp", "box.ply", "--out", "grasps.json"],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while not descendants(proc.pid) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    children = descendants(proc.pid)
    assert children and proc.poll() is None
    seconds, stderr = _interrupt(proc, children)
    assert seconds <= STOP_LIMIT, f"Ctrl-C took {seconds:.1f} s"
    assert proc.returncode == 130, stderr
    assert not (tmp_path / "grasps.json").exists()


def test_ctrl_c_stops_the_app(tmp_path, env):
    (tmp_path / "results").mkdir()
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "app.py"), "--port", str(free_port()), "--cloud", MUG, "--results", "results"],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    lines = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if "ready on" in line or not line:
            break
    assert "ready on" in lines[-1], lines
    seconds, _ = _interrupt(proc, descendants(proc.pid))
    assert seconds <= STOP_LIMIT, f"Ctrl-C took {seconds:.1f} s"
