"""The detailed mesh of a fitted box against the shipped completion, on an evaluation folder.

For each tabletop view: the cuboid fitted to the observed points (:func:`shapeviewer.cuboid.fit_cuboid`),
whether it is accepted as a box, and for the accepted views (every view with ``--all``) Algorithm 1's
mesh of the box's occupancy (what ``complete_points(..., fit_boxes=True)`` gives) scored against the
true mesh beside the folder's own Ours-detailed scores.

    shapeviewer evaluate --out results/table7 --views tabletop --views-per-set 50 --seed 7
    python benchmarks/cuboid.py results/table7 [--all] [--kinds box]

Prints one line per view (the fit's fill and residual; J80 and mean surface distance, shipped ->
boxed), then the means per kind.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np


def view_scores(root: Path, file: Path, every: bool) -> dict | None:
    """One view's figures, None without a table, samples or Ours-detailed row."""
    from shapeviewer.cuboid import fit_cuboid, occupancy
    from shapeviewer.evaluation.records import samples_file, view_stem
    from shapeviewer.evaluation.results import read_mesh, read_points
    from shapeviewer.evaluation.run import load_samples
    from shapeviewer.metrics import hausdorff, sampled_jaccard
    from shapeviewer.reconstruct import detailed_mesh

    record = json.loads(file.read_text())
    shipped = next((r for r in record.get("rows", []) if r["method"] == "Ours-detailed" and not r["error"]), None)
    samples = root / samples_file(view_stem(record["object"], record["view"]))
    if record.get("support_plane") is None or shipped is None or not samples.exists():
        return None
    plane = np.asarray(record["support_plane"], dtype=np.float64)
    points = read_points(root / record["files"]["points"])
    box = fit_cuboid(points, plane)
    out = {
        "kind": shipped.get("kind", "?"),
        "object": record["object"],
        "accepted": box.accepted,
        "fill": box.fill,
        "residual_mm": box.residual * 1000,
        "j80": shipped["j80"],
        "mm": shipped["hausdorff_mean_mm"],
    }
    if not (box.accepted or every):
        return out
    _, frame, level = load_samples(samples)
    mesh = detailed_mesh(occupancy(box, frame), frame, points, support_plane=plane, level=level)
    truth = read_mesh(root / record["files"]["truth"])
    out["j80_boxed"] = sampled_jaccard(mesh, truth)
    out["mm_boxed"] = hausdorff(mesh, truth)["mean_mm"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", type=Path, nargs="+", help="results folders of shapeviewer evaluate --views tabletop")
    ap.add_argument("--all", action="store_true", help="box every view, not only the accepted ones")
    ap.add_argument("--kinds", nargs="*", help="only these shape kinds")
    args = ap.parse_args()
    per_kind: dict[str, list[dict]] = defaultdict(list)
    for root in args.results:
        for file in sorted((root / "views").glob("*.json")):
            s = view_scores(root, file, args.all)
            if s is None or (args.kinds and s["kind"] not in args.kinds):
                continue
            per_kind[s["kind"]].append(s)
            after = f"-> {s['j80_boxed']:.3f} / {s['mm_boxed']:5.2f} mm" if "j80_boxed" in s else "(kept)"
            print(
                f"{s['object']:32s} {s['kind']:14s} {'accepted' if s['accepted'] else 'rejected':8s} "
                f"fill {s['fill']:.2f} residual {s['residual_mm']:5.1f} mm  J80 / mm {s['j80']:.3f} / "
                f"{s['mm']:5.2f} {after}",
                flush=True,
            )
    print(f"\n{'kind':14s} {'views':>5s} {'boxed':>6s} {'J80':>15s} {'mean mm':>15s}")
    everything = [r for views in per_kind.values() for r in views]
    for kind, rows in sorted(per_kind.items()) + [("all", everything)]:
        new_j = [r.get("j80_boxed", r["j80"]) for r in rows]
        new_mm = [r.get("mm_boxed", r["mm"]) for r in rows]
        n_box = sum("j80_boxed" in r for r in rows)
        print(
            f"{kind:14s} {len(rows):5d} {n_box:6d} {np.mean([r['j80'] for r in rows]):.3f} -> {np.mean(new_j):.3f} "
            f"{np.mean([r['mm'] for r in rows]):5.2f} -> {np.mean(new_mm):5.2f}"
        )


if __name__ == "__main__":
    main()
