"""The README names only files of this repository, and its Test block is what CI runs."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()


def code_blocks(text: str) -> list[str]:
    return re.findall(r"```(?:bash|python)\n(.*?)```", text, flags=re.S)


def section(title: str) -> str:
    """The README's section ``## title``, up to the next section."""
    start = README.index(f"## {title}\n")
    return README[start : README.index("\n## ", start + 1)]


def test_readme_names_only_files_in_the_repository():
    assert "shared/data" not in README, "README examples must use the shipped captures, not ../shared"
    named = set(re.findall(r"(?:static_assets|tools|benchmarks|examples|\.ci)/[\w./-]+\w", README))
    assert "static_assets/captures/milk_cartoon_all_small_clorox.pcd" in named
    missing = sorted(p for p in named if not (ROOT / p).exists())
    assert not missing, f"the README names files the repository lacks: {missing}"
    captures = ROOT / "static_assets" / "captures"
    assert (captures / "LICENSE").is_file() and "BSD" in (captures / "LICENSE").read_text()


def test_run_and_test_blocks_install_what_they_need():
    run = code_blocks(section("Run"))[0].strip()
    test = code_blocks(section("Test"))[0].strip()
    # In the order a user works: run it, test it, then the quickstart and the rest.
    order = [README.index(f"## {t}\n") for t in ("Run", "Test", "Quickstart", "Python API", "Results")]
    assert order == sorted(order)
    assert run.startswith("bash tools/install.sh") and run.endswith("python app.py")
    assert test == "bash tools/install.sh --test && python -m pytest -q"
    ci = (ROOT / ".ci" / "run").read_text()
    assert all(cmd in ci for cmd in test.split(" && ")), "CI must run the README's Test command"
    script = (ROOT / "tools" / "install.sh").read_text()
    assert "sudo" in script and "id -u" in script  # root runs apt-get itself, anyone else through sudo
    assert "chromium" in script and ".[test]" in script
    subprocess.run(["bash", "-n", str(ROOT / "tools" / "install.sh")], check=True)


@pytest.mark.slow
def test_python_api_examples_run_as_written(monkeypatch):
    """The README's Python blocks (the quickstart, then the staged example), run in order from the
    repository root: the public API they show exists and does what they say (a closed mesh and ranked
    grasps from a real capture, in the frames the text gives)."""
    import numpy as np

    monkeypatch.chdir(ROOT)
    blocks = re.findall(r"```python\n(.*?)```", section("Quickstart") + section("Python API"), flags=re.S)
    assert len(blocks) >= 2, "the README lost its quickstart or its Python API example"
    scope: dict = {}
    exec(compile("\n".join(blocks), "README.md", "exec"), scope)  # noqa: S102 - our own README
    assert scope["mesh"].is_watertight and scope["fast"].is_watertight and scope["detailed"].is_watertight
    assert scope["samples"].shape == (8, 40, 40, 40)
    pick = scope["pick"]
    assert pick.ranked and pick.best is pick.ranked[0] and len(pick.ranked) == len(pick.grasps)
    assert np.asarray(pick.best.T_world_palm).shape == (4, 4)
    # T_world_cam takes the object's camera-frame points to the planner's world: on the table, z up.
    T = np.asarray(pick.T_world_cam)
    heights = scope["points"] @ T[:3, :3].T + T[:3, 3]
    assert np.median(heights[:, 2]) > 0.01


def test_python_api_section_lists_exactly_the_public_api():
    """One row per name of ``shapeviewer.__all__`` in the section's table, and the section's text and
    examples use no other ``shapeviewer`` name."""
    import shapeviewer

    api = section("Python API")
    listed = re.findall(r"^\| `(\w+)` \|", api, flags=re.M)
    assert len(listed) == len(set(listed)), f"listed twice: {sorted(n for n in listed if listed.count(n) > 1)}"
    public = set(shapeviewer.__all__)
    assert set(listed) == public, (
        f"missing from the README: {sorted(public - set(listed))}; not public: {sorted(set(listed) - public)}"
    )
    text = section("Quickstart") + api
    used = set(re.findall(r"\b(?:shapeviewer|sv)\.(\w+)", text))
    for names in re.findall(r"from shapeviewer import ([\w, ]+)", text):
        used |= {n.strip() for n in names.split(",")}
    assert used - {"__all__"} <= public, f"the sections use non-public names: {sorted(used - public - {'__all__'})}"
    for name in ("complete_capture.py", "plan_grasps.py", "evaluate_two_views.py"):
        assert f"examples/{name}" in api and (ROOT / "examples" / name).is_file(), name
