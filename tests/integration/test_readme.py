"""The README names only files of this repository, and its Test block is what CI runs."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()


def code_blocks(text: str) -> list[str]:
    return re.findall(r"```(?:bash|python)\n(.*?)```", text, flags=re.S)


def python_api_section() -> str:
    start = README.index("## Python API")
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
    blocks = code_blocks(README[README.index("## Run") : README.index("### Dataset tab")])
    run = blocks[0].strip()
    test = code_blocks(README[README.index("## Test") : README.index("## Command line")])[0].strip()
    assert run.startswith("bash tools/install.sh") and run.endswith("python app.py")
    assert test == "bash tools/install.sh --test && python -m pytest -q"
    ci = (ROOT / ".ci" / "run").read_text()
    assert all(cmd in ci for cmd in test.split(" && ")), "CI must run the README's Test command"
    script = (ROOT / "tools" / "install.sh").read_text()
    assert "sudo" in script and "id -u" in script  # root runs apt-get itself, anyone else through sudo
    assert "chromium" in script and ".[test]" in script
    subprocess.run(["bash", "-n", str(ROOT / "tools" / "install.sh")], check=True)


def test_python_api_examples_run_as_written(monkeypatch):
    """The README's Python blocks, run in order from the repository root: the public API they show exists
    and does what they say (a closed mesh from a real capture)."""
    monkeypatch.chdir(ROOT)
    blocks = re.findall(r"```python\n(.*?)```", README[README.index("## Python API") :], flags=re.S)
    assert blocks, "the README lost its Python API examples"
    scope: dict = {}
    exec(compile("\n".join(blocks), "README.md", "exec"), scope)  # noqa: S102 - our own README
    assert scope["mesh"].is_watertight and scope["detailed"].is_watertight
    assert scope["samples"].shape == (8, 40, 40, 40)


def test_python_api_section_lists_exactly_the_public_api():
    """One row per name of ``shapeviewer.__all__`` in the section's table, and the section's text and
    examples use no other ``shapeviewer`` name."""
    import shapeviewer

    section = python_api_section()
    listed = re.findall(r"^\| `(\w+)` \|", section, flags=re.M)
    assert len(listed) == len(set(listed)), f"listed twice: {sorted(n for n in listed if listed.count(n) > 1)}"
    public = set(shapeviewer.__all__)
    assert set(listed) == public, (
        f"missing from the README: {sorted(public - set(listed))}; not public: {sorted(set(listed) - public)}"
    )
    used = set(re.findall(r"\b(?:shapeviewer|sv)\.(\w+)", section))
    for names in re.findall(r"from shapeviewer import ([\w, ]+)", section):
        used |= {n.strip() for n in names.split(",")}
    assert used - {"__all__"} <= public, f"the section uses non-public names: {sorted(used - public - {'__all__'})}"
    for name in ("complete_capture.py", "plan_grasps.py", "evaluate_two_views.py"):
        assert f"examples/{name}" in section and (ROOT / "examples" / name).is_file(), name
