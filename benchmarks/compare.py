"""Speed regression guard: the working tree's stages against an older revision's, on the same machine load.

    python benchmarks/compare.py REV [--repeats 3] [--only pipeline detailed grasp pick] [--json PATH]

REV (any git revision, e.g. ``e1fa60f``) is checked out in a temporary ``git worktree`` (removed afterwards).
Every measurement runs ``benchmarks/common/stages.py`` (this tree's copy: one piece of measuring code for
both) in a fresh Python process with ``PYTHONPATH`` and the working directory set to REV's tree or to the
working tree, ALTERNATING (REV, tree, REV, tree, ...), so that both see the same machine load; the table
gives each stage's median over ``--repeats`` measurements and the ratio tree / REV (below 1: faster now).
A stage that a revision lacks (or that fails there) prints "n/a" and the run goes on.

Groups of stages (``--only``): ``pipeline`` (segmentation of a 640x480 cloud, the CNN passes for one
segment, click -> fast mesh), ``detailed`` (detailed mesh end to end), ``grasp`` (20 Barrett grasps
planned), ``pick`` (the app's pick for one object). ``--repeats 1 --only pipeline`` takes a few minutes.
The inputs are the organized captures in static_assets/captures of the working tree (the same files for
both) and each revision's own generated default scene.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
STAGES_SCRIPT = ROOT / "benchmarks" / "common" / "stages.py"
CAPTURES = ROOT / "static_assets" / "captures"
GROUPS = {
    "pipeline": ("segmentation", "cnn", "fast_mesh"),
    "detailed": ("detailed_mesh",),
    "grasp": ("grasp",),
    "pick": ("pick",),
}
LABELS = {
    "segmentation": "segmentation (640x480 cloud)",
    "cnn": "CNN passes, one segment",
    "fast_mesh": "click -> fast mesh",
    "detailed_mesh": "detailed mesh, end to end",
    "grasp": "20 Barrett grasps planned",
    "pick": "the pick, one object",
}
# Timed calls inside one measurement (its median): cheap stages more, the grasp work once.
RUNS = {"segmentation": 5, "cnn": 5, "fast_mesh": 5, "detailed_mesh": 3, "grasp": 1, "pick": 1}
TIMEOUT = 1800.0  # s for one measurement


def measure_once(stage: str, tree: Path, captures: Path, runs: int) -> tuple[float | None, str]:
    """``(seconds, note)`` of one measurement of ``stage`` with ``tree`` on PYTHONPATH; None when n/a."""
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "2")}
    command = [sys.executable, str(STAGES_SCRIPT), stage, "--captures", str(captures), "--runs", str(runs)]
    try:
        done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        return None, f"timed out after {TIMEOUT:.0f} s"
    lines = done.stdout.strip().splitlines()
    try:
        result = json.loads(lines[-1]) if done.returncode == 0 and lines else None
    except json.JSONDecodeError:
        result = None
    if not isinstance(result, dict):
        error = (done.stderr.strip().splitlines() or ["no output"])[-1]
        return None, f"failed (exit {done.returncode}): {error[:200]}"
    module = Path(str(result.get("module", ""))).resolve()
    if tree.resolve() not in module.parents:
        return None, f"measured {module}, not this tree (is PYTHONPATH overridden?)"
    seconds = result.get("seconds")
    return (float(seconds) if seconds is not None else None), str(result.get("note", ""))


def compare(
    rev_tree: Path, work_tree: Path, stages: list[str], *, repeats: int, captures: Path, runs: int | None
) -> dict[str, dict[str, Any]]:
    """Per stage: each side's measurements (alternating REV, tree), medians and the ratio tree / REV."""
    figures: dict[str, dict[str, Any]] = {}
    for stage in stages:
        sides: dict[str, list[float]] = {"rev": [], "tree": []}
        notes: dict[str, str] = {"rev": "", "tree": ""}
        for repeat in range(repeats):
            for side, tree in (("rev", rev_tree), ("tree", work_tree)):
                if repeat and not sides[side]:
                    continue  # n/a or failed the first time: it will not come back
                seconds, note = measure_once(stage, tree, captures, runs or RUNS[stage])
                if seconds is None:
                    notes[side] = note or "n/a"
                else:
                    sides[side].append(seconds)
                print(
                    f"  {stage} {side} #{repeat + 1}: " + (f"{seconds:.4f} s" if seconds is not None else note),
                    file=sys.stderr,
                    flush=True,
                )
        medians = {side: statistics.median(v) if v else None for side, v in sides.items()}
        ratio = medians["tree"] / medians["rev"] if medians["tree"] is not None and medians["rev"] else None
        figures[stage] = {
            "rev_seconds": sides["rev"],
            "tree_seconds": sides["tree"],
            "median_rev": medians["rev"],
            "median_tree": medians["tree"],
            "ratio": ratio,
            "notes": notes,
        }
    return figures


def table(rev: str, figures: dict[str, dict[str, Any]]) -> str:
    """The markdown table: stage, median REV, median working tree, ratio."""

    def cell(seconds: float | None) -> str:
        return "n/a" if seconds is None else f"{seconds:.3f} s"

    lines = [f"| stage | median {rev} | median working tree | ratio (tree / {rev}) |", "|---|---:|---:|---:|"]
    notes = []
    for stage, f in figures.items():
        ratio = "n/a" if f["ratio"] is None else f"{f['ratio']:.2f}"
        lines.append(f"| {LABELS[stage]} | {cell(f['median_rev'])} | {cell(f['median_tree'])} | {ratio} |")
        for side, note in f["notes"].items():
            if note:
                notes.append(f"- {LABELS[stage]}, {rev if side == 'rev' else 'working tree'}: {note}")
    return "\n".join(lines + ([""] + notes if notes else []))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("rev", help="git revision to compare the working tree with")
    ap.add_argument("--repeats", type=int, default=3, help="measurements per stage and side (fresh processes)")
    ap.add_argument("--only", nargs="+", choices=sorted(GROUPS), default=list(GROUPS), help="groups of stages")
    ap.add_argument("--runs", type=int, default=None, help="timed calls inside one measurement (default per stage)")
    ap.add_argument("--captures", type=Path, default=CAPTURES, help="folder of organized .pcd captures")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    if args.repeats < 1 or (args.runs is not None and args.runs < 1):
        ap.error("--repeats and --runs must be at least 1")
    stages = [s for group in GROUPS if group in args.only for s in GROUPS[group]]

    commit = subprocess.run(
        ["git", "rev-parse", "--verify", f"{args.rev}^{{commit}}"], cwd=ROOT, capture_output=True, text=True
    )
    if commit.returncode:
        ap.error(f"unknown git revision {args.rev!r}")
    sha = commit.stdout.strip()
    load_before = os.getloadavg()
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="compare-") as scratch:
        rev_tree = Path(scratch) / "rev"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(rev_tree), sha], cwd=ROOT, check=True, capture_output=True
        )
        try:
            figures = compare(rev_tree, ROOT, stages, repeats=args.repeats, captures=args.captures, runs=args.runs)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(rev_tree)], cwd=ROOT, capture_output=True)
    load_after = os.getloadavg()
    print(table(args.rev, figures))
    print(
        f"\n{args.rev} = {sha[:10]}; {args.repeats} alternating measurements per stage and side, each in a fresh "
        f"process; {os.cpu_count()} CPUs; load average (1/5/15 min) {load_before[0]:.1f}/{load_before[1]:.1f}/"
        f"{load_before[2]:.1f} before, {load_after[0]:.1f}/{load_after[1]:.1f}/{load_after[2]:.1f} after; "
        f"{time.perf_counter() - started:.0f} s in all"
    )
    if args.json:
        report = {
            "rev": args.rev,
            "commit": sha,
            "repeats": args.repeats,
            "cpus": os.cpu_count(),
            "load_before": load_before,
            "load_after": load_after,
            "stages": figures,
        }
        args.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
