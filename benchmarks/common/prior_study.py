"""The driver of the shape-prior studies (``benchmarks/studies/revolve.py``, ``benchmarks/studies/cuboid.py``): a
prior's effect on the detailed meshes of the tabletop views of evaluation folders.

A study gives ``view_scores(root, view_file, every) -> dict | None``: for one view (None to skip it)
its ``object``, ``kind``, whether the prior ``accepted`` it, its ``j80`` / ``mm`` (J80 and mean
surface distance without the prior) and, where the prior was applied (every view with ``--all``),
``j80_after`` / ``mm_after``; and ``describe(scores) -> str``, the prior's own figures for the line.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np


def tabletop_view(root: Path, file: Path) -> tuple[dict, dict, np.ndarray, np.ndarray] | None:
    """``(record, scores, plane_cam, points_cam)`` of one view of results folder ``root``: its record,
    the ``scores`` a study starts from (``object``, ``kind``, ``j80``, ``mm`` of its Ours-detailed
    row), the support plane and the segment's points (camera frame, metres); None without a table or
    an Ours-detailed mesh."""
    from shapeviewer.evaluation.results import read_points

    record = json.loads(file.read_text())
    shipped = next((r for r in record.get("rows", []) if r["method"] == "Ours-detailed" and not r["error"]), None)
    if record.get("support_plane") is None or shipped is None:
        return None
    scores = {
        "object": record["object"],
        "kind": shipped.get("kind", "?"),
        "j80": shipped["j80"],
        "mm": shipped["hausdorff_mean_mm"],
    }
    plane = np.asarray(record["support_plane"], dtype=np.float64)
    return record, scores, plane, read_points(root / record["files"]["points"])


def main(doc: str, view_scores: Callable[[Path, Path, bool], dict | None], describe: Callable[[dict], str]) -> None:
    """Parse the command line (results folders, ``--all``, ``--kinds``), print one line per view and
    then the means per kind and over all views, without -> with the prior."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", type=Path, nargs="+", help="results folders of shapeviewer evaluate --views tabletop")
    ap.add_argument("--all", action="store_true", help="apply the prior to every view, not only the accepted ones")
    ap.add_argument("--kinds", nargs="*", help="only these shape kinds")
    args = ap.parse_args()
    per_kind: dict[str, list[dict]] = defaultdict(list)
    for root in args.results:
        for file in sorted((root / "views").glob("*.json")):
            s = view_scores(root, file, args.all)
            if s is None or (args.kinds and s["kind"] not in args.kinds):
                continue
            per_kind[s["kind"]].append(s)
            after = f"-> {s['j80_after']:.3f} / {s['mm_after']:5.2f} mm" if "j80_after" in s else "(kept)"
            print(
                f"{s['object']:32s} {s['kind']:14s} {'accepted' if s['accepted'] else 'rejected':8s} {describe(s)}  "
                f"J80 / mm {s['j80']:.3f} / {s['mm']:5.2f} {after}",
                flush=True,
            )
    print(f"\n{'kind':14s} {'views':>5s} {'applied':>7s} {'J80':>15s} {'mean mm':>15s}")
    everything = [r for views in per_kind.values() for r in views]
    for kind, rows in sorted(per_kind.items()) + [("all", everything)]:
        new_j = [r.get("j80_after", r["j80"]) for r in rows]
        new_mm = [r.get("mm_after", r["mm"]) for r in rows]
        applied = sum("j80_after" in r for r in rows)
        print(
            f"{kind:14s} {len(rows):5d} {applied:7d} {np.mean([r['j80'] for r in rows]):.3f} -> {np.mean(new_j):.3f} "
            f"{np.mean([r['mm'] for r in rows]):5.2f} -> {np.mean(new_mm):5.2f}"
        )
