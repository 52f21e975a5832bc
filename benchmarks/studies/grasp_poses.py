"""Tabletop grasp success by shape kind and resting pose: which vessels the robust pick misses.

A bowl or a plate dropped on a table rests rim up or rim down (a dome); a cup, mug or pitcher may
also lie on its side. The pose is read off the true mesh in the grasp world (the table at z = 0, z
up): *rim up* when the mesh's top (its vertices within 3 mm of its highest) reaches out to 85 % of
its largest distance from the vertical line through its centre (a rim), *rim down* when its bottom
does, else *side*. Kinds that are not vessels are reported as one row each.

    shapeviewer evaluate --out results/table7 --views tabletop --views-per-set 50 --seed 7 \\
        --grasps --grasp-methods Ours-detailed --robust
    python -m benchmarks.studies.grasp_poses results/table7 [results/table8 ...] [--method Ours-detailed]

Prints, per (kind, pose), the views and the share whose robust pick and whose planner's best grasp
lifted the true object.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

VESSELS = ("bowl", "plate", "cup", "mug", "pitcher")
RIM_SHARE = 0.85  # the top (or bottom) reaches this share of the mesh's radius: a rim
RIM_BAND = 0.003  # metres: the vertices within this of the top (bottom)


def resting_pose(vertices_world: np.ndarray) -> str:
    """``rim up``, ``rim down`` or ``side`` of a vessel's true mesh (world frame, z up, metres)."""
    v = np.asarray(vertices_world, dtype=np.float64)
    radius = np.linalg.norm(v[:, :2] - v[:, :2].mean(axis=0), axis=1)
    z = v[:, 2]
    if radius[z > z.max() - RIM_BAND].max() > RIM_SHARE * radius.max():
        return "rim up"
    if radius[z < z.min() + RIM_BAND].max() > RIM_SHARE * radius.max():
        return "rim down"
    return "side"


def view_outcome(root: Path, file: Path, method: str) -> tuple[str, float, float] | None:
    """``(group, robust pick lifted, planner's best lifted)`` of one view, None if not grasped."""
    from shapeviewer.evaluation.results import read_mesh
    from shapeviewer.evaluation.run import grasp_world

    record = json.loads(file.read_text())
    entry = next((g for g in record.get("grasps", []) if g["method"] == method and not g["error"]), None)
    if entry is None or not record.get("rows"):
        return None
    kind = record["rows"][0].get("kind", "?")
    group = kind
    if kind in VESSELS:
        T_world_cam, _ = grasp_world(record)
        truth = read_mesh(root / record["files"]["truth"]).apply_transform(T_world_cam)
        group = f"{kind}, {resting_pose(truth.vertices)}"
    return group, float(entry["lift_success_best_robust"]), float(entry["lift_success_best"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", type=Path, nargs="+", help="results folders of shapeviewer evaluate --grasps --robust")
    ap.add_argument("--method", default="Ours-detailed")
    args = ap.parse_args()
    groups: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for root in args.results:
        for file in sorted((root / "views").glob("*.json")):
            out = view_outcome(root, file, args.method)
            if out is not None:
                groups[out[0]].append(out[1:])
    print(f"{'kind, pose':22s} {'views':>5s} {'robust':>7s} {'planner':>8s}")
    everything = [x for rows in groups.values() for x in rows]
    for name, rows in sorted(groups.items()) + [("all", everything)]:
        a = np.asarray(rows, dtype=np.float64)
        print(f"{name:22s} {len(a):5d} {np.nanmean(a[:, 0]):7.1%} {np.nanmean(a[:, 1]):8.1%}")


if __name__ == "__main__":
    main()
