"""The detailed mesh of the network's answer revolved about the table's normal, against the shipped one.

For each tabletop view of an evaluation folder: the vertical axis fitted to the observed points
(:func:`shapeviewer.revolve.fit_axis`), whether it is accepted as a surface of revolution, and, for the
accepted views (every view with ``--all``), Algorithm 1's mesh of the mean of the revolved sample
completions (:func:`shapeviewer.revolve.revolve` on the saved samples, the seen free space left
empty: what ``complete_points(..., revolve_answers=True)`` gives) scored against the true mesh beside
the folder's own Ours-detailed scores (the folder evaluated without revolving, the default).

    shapeviewer evaluate --out results/table7 --views tabletop --views-per-set 50 --seed 7
    python benchmarks/revolve.py results/table7 [--all] [--kinds bowl cup]

Prints one line per view (J80 and mean surface distance, shipped -> revolved; the axis's angular
coverage and relative residual), then the means per kind.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np


def view_scores(root: Path, file: Path, every: bool) -> dict | None:
    """One view's figures, None without a table, samples or Ours-detailed row."""
    from shapeviewer.evaluation.records import samples_file, view_stem
    from shapeviewer.evaluation.results import read_mesh, read_points
    from shapeviewer.evaluation.run import load_samples
    from shapeviewer.metrics import hausdorff, sampled_jaccard
    from shapeviewer.reconstruct import detailed_mesh
    from shapeviewer.revolve import fit_axis, revolve
    from shapeviewer.voxel import context_grids

    record = json.loads(file.read_text())
    shipped = next((r for r in record.get("rows", []) if r["method"] == "Ours-detailed" and not r["error"]), None)
    samples = root / samples_file(view_stem(record["object"], record["view"]))
    if record.get("support_plane") is None or shipped is None or not samples.exists():
        return None
    plane = np.asarray(record["support_plane"], dtype=np.float64)
    points = read_points(root / record["files"]["points"])
    axis = fit_axis(points, plane)
    out = {
        "kind": shipped.get("kind", "?"),
        "object": record["object"],
        "accepted": axis.accepted,
        "coverage_deg": axis.coverage_deg,
        "relative_residual": axis.residual / max(axis.radius, 1e-9),
        "j80": shipped["j80"],
        "mm": shipped["hausdorff_mean_mm"],
    }
    if not (axis.accepted or every):
        return out
    answers, frame, level = load_samples(samples)
    free = context_grids(points, frame, support_plane=plane)[0]
    mean = revolve(answers, frame, axis, free=free).mean(axis=0)
    mesh = detailed_mesh(mean, frame, points, support_plane=plane, level=level)
    truth = read_mesh(root / record["files"]["truth"])
    out["j80_revolved"] = sampled_jaccard(mesh, truth)
    out["mm_revolved"] = hausdorff(mesh, truth)["mean_mm"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", type=Path, nargs="+", help="results folders of shapeviewer evaluate --views tabletop")
    ap.add_argument("--all", action="store_true", help="revolve every view, not only the accepted ones")
    ap.add_argument("--kinds", nargs="*", help="only these shape kinds")
    args = ap.parse_args()
    per_kind: dict[str, list[dict]] = defaultdict(list)
    for root in args.results:
        for file in sorted((root / "views").glob("*.json")):
            s = view_scores(root, file, args.all)
            if s is None or (args.kinds and s["kind"] not in args.kinds):
                continue
            per_kind[s["kind"]].append(s)
            after = f"-> {s['j80_revolved']:.3f} / {s['mm_revolved']:5.2f} mm" if "j80_revolved" in s else "(kept)"
            print(
                f"{s['object']:32s} {'accepted' if s['accepted'] else 'rejected':8s} coverage {s['coverage_deg']:3.0f} "
                f"residual {s['relative_residual']:.3f}  J80 / mm {s['j80']:.3f} / {s['mm']:5.2f} {after}",
                flush=True,
            )
    print(f"\n{'kind':14s} {'views':>5s} {'revolved':>8s} {'J80':>13s} {'mean mm':>13s}")
    everything = [r for views in per_kind.values() for r in views]
    for kind, rows in sorted(per_kind.items()) + [("all", everything)]:
        new_j = [r.get("j80_revolved", r["j80"]) for r in rows]
        new_mm = [r.get("mm_revolved", r["mm"]) for r in rows]
        n_rev = sum("j80_revolved" in r for r in rows)
        print(
            f"{kind:14s} {len(rows):5d} {n_rev:8d} {np.mean([r['j80'] for r in rows]):.3f} -> {np.mean(new_j):.3f} "
            f"{np.mean([r['mm'] for r in rows]):5.2f} -> {np.mean(new_mm):5.2f}"
        )


if __name__ == "__main__":
    main()
