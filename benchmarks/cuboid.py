"""The detailed mesh of a fitted box against the network's, on the views of an evaluation folder.

For each tabletop view: the cuboid fitted to the observed points (:func:`shapeviewer.cuboid.fit_cuboid`)
and whether it is accepted as a box; for the accepted views (every view with ``--all``) the segment is
completed again, as the network answers it (``complete_points(..., fit_boxes=False)``) and as the
box (its occupancy in place of the answers, what the pipeline does by default for an accepted box),
and both detailed meshes are scored against the true mesh.

    shapeviewer evaluate --out results/table7 --views tabletop --views-per-set 50 --seed 7
    python benchmarks/cuboid.py results/table7 [--all] [--kinds box]

Prints one line per view (the fit's fill, aligned share and residual; J80 and mean surface distance,
network -> box), then the means per kind (views not boxed: the folder's Ours-detailed scores).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np


@cache
def _completer():
    from shapeviewer.model import load_completer

    return load_completer()


def view_scores(root: Path, file: Path, every: bool) -> dict | None:
    """One view's figures, None without a table or an Ours-detailed row."""
    from shapeviewer.cuboid import fit_cuboid, occupancy
    from shapeviewer.evaluation.results import read_mesh, read_points
    from shapeviewer.metrics import hausdorff, sampled_jaccard
    from shapeviewer.pipeline import complete_points, completion_detailed_mesh

    record = json.loads(file.read_text())
    shipped = next((r for r in record.get("rows", []) if r["method"] == "Ours-detailed" and not r["error"]), None)
    if record.get("support_plane") is None or shipped is None:
        return None
    plane = np.asarray(record["support_plane"], dtype=np.float64)
    points = read_points(root / record["files"]["points"])
    box = fit_cuboid(points, plane)
    out = {
        "kind": shipped.get("kind", "?"),
        "object": record["object"],
        "accepted": box.accepted,
        "fill": box.fill,
        "aligned": box.aligned,
        "residual_mm": box.residual * 1000,
        "j80": shipped["j80"],
        "mm": shipped["hausdorff_mean_mm"],
    }
    if not (box.accepted or every):
        return out
    truth = read_mesh(root / record["files"]["truth"])
    (network,) = complete_points([points], _completer(), support_plane=plane, fit_boxes=False)
    occupied = occupancy(box, network.frame)
    boxed = replace(network, probabilities=occupied, samples=np.broadcast_to(occupied, network.samples.shape))
    for key, c in (("network", network), ("boxed", boxed)):
        mesh = completion_detailed_mesh(c, points)
        out[f"j80_{key}"] = sampled_jaccard(mesh, truth)
        out[f"mm_{key}"] = hausdorff(mesh, truth)["mean_mm"]
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
            scores = (
                f"J80 / mm {s['j80_network']:.3f} / {s['mm_network']:5.2f} -> "
                f"{s['j80_boxed']:.3f} / {s['mm_boxed']:5.2f}"
                if "j80_boxed" in s
                else "(the network's answer)"
            )
            print(
                f"{s['object']:32s} {s['kind']:14s} {'accepted' if s['accepted'] else 'rejected':8s} "
                f"fill {s['fill']:.2f} aligned {s['aligned']:.2f} residual {s['residual_mm']:5.1f} mm  {scores}",
                flush=True,
            )
    print(f"\n{'kind':14s} {'views':>5s} {'boxed':>6s} {'J80':>15s} {'mean mm':>15s}")
    everything = [r for views in per_kind.values() for r in views]
    for kind, rows in sorted(per_kind.items()) + [("all", everything)]:
        # A view not boxed is scored by the folder's own Ours-detailed row, the network's answer.
        old_j, new_j = ([r.get(f"j80_{k}", r["j80"]) for r in rows] for k in ("network", "boxed"))
        old_mm, new_mm = ([r.get(f"mm_{k}", r["mm"]) for r in rows] for k in ("network", "boxed"))
        n_box = sum("j80_boxed" in r for r in rows)
        print(
            f"{kind:14s} {len(rows):5d} {n_box:6d} {np.mean(old_j):.3f} -> {np.mean(new_j):.3f} "
            f"{np.mean(old_mm):5.2f} -> {np.mean(new_mm):5.2f}"
        )


if __name__ == "__main__":
    main()
