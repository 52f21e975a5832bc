"""Ablation of what makes completion hold up on tabletops: the same tabletop test views
(``shapeviewer evaluate --views tabletop``'s sample) completed by variants, scored by J80 and the
mean surface distance against the true mesh.

Variants (each a weights file, with or without the context):
  * ``<label>``: the CNN reads the context and known-empty space is zeroed, and both meshes mesh
    the mean of its 8 mirrored answers (the app's path, ``pipeline.complete_points``);
  * ``<label>-noctx``: occupancy only, no zeroing, one answer (how the paper's pipeline ran);
  * ``Hull``: the convex hull of the segment's points.

    python -m benchmarks.studies.ablation \
        --weights old=static_assets/weights/unet3d.pt new=runs/ctx3/best_holdout_model.pt \
        [--views-per-set 30] [--seed 0] [--mode fast|detailed|both] [--levels 0.5 0.6] [--csv out.csv]

``--levels`` meshes each answer at several iso levels (variant names gain ``@level``): the scan
that chooses a model's ``mesh_level`` (``Completer.mesh_level``). ``--upsample vote linear`` compares the ways
the detailed mesh up-samples the CNN output (``reconstruct.detailed_mesh``; names gain ``+linear``).

Prints mean J80 / distance per variant, per view set and per shape kind, and how often each beats Hull.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import math
from collections import defaultdict

import numpy as np

from shapeviewer.completion.baselines import hull_mesh
from shapeviewer.completion.model import load_completer
from shapeviewer.completion.reconstruct import detailed_mesh, fast_mesh
from shapeviewer.completion.voxel import context_grids, partial_to_grid
from shapeviewer.evaluation.metrics import hausdorff, sampled_jaccard
from shapeviewer.evaluation.viewsets import render_view, sample_views
from shapeviewer.sim import catalogue


def score(mesh, truth) -> tuple[float, float]:
    return sampled_jaccard(mesh, truth), hausdorff(mesh, truth)["mean_mm"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--weights", nargs="+", required=True, metavar="LABEL=PATH")
    ap.add_argument("--views-per-set", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--mode", default="both", choices=["fast", "detailed", "both"])
    ap.add_argument("--no-ablation", action="store_true", help="only the full variant of each weights file")
    ap.add_argument(
        "--levels", nargs="+", type=float, default=None, help="iso levels to mesh at (default: each model's own)"
    )
    ap.add_argument("--upsample", nargs="+", default=["vote"], choices=["vote", "linear"])
    ap.add_argument("--csv", default=None)
    args = ap.parse_args()
    completers = {label: load_completer(path) for label, path in (w.split("=", 1) for w in args.weights)}
    modes = ("fast", "detailed") if args.mode == "both" else (args.mode,)
    rows = []
    views = sample_views(args.views_per_set, args.seed, "tabletop")
    for i, (name, view, view_set) in enumerate(views):
        try:
            v = render_view(name, view, view_set, args.seed)
        except ValueError as e:
            print(f"skip {name} {view}: {e}")
            continue
        kind = catalogue.shape_kind(name)
        base = {"object": name, "view": view, "view_set": view_set, "kind": kind, "sensor": v.sensor}
        j, d = score(hull_mesh(v.points_cam), v.truth_cam)
        rows.append({**base, "variant": "Hull", "j80": j, "distance_mm": d})
        for label, c in completers.items():
            grid, frame = partial_to_grid(v.points_cam, depth_shift=c.depth_shift)
            ctx = context_grids(v.points_cam, frame, support_plane=v.support_plane)
            variants = [(label, ctx, v.support_plane)]
            if not args.no_ablation:
                variants.append((f"{label}-noctx", None, None))
            for vname, context, plane in variants:
                # The app's output: the mean of the 8 mirrored answers; the paper's: one answer.
                p = c.predict_samples(grid, context=context).mean(axis=0) if context is not None else c.predict(grid)
                runs = [("fast", "vote")] if "fast" in modes else []
                runs += [("detailed", u) for u in args.upsample] if "detailed" in modes else []
                levels = args.levels or [c.mesh_level]
                for (mode, upsample), level in itertools.product(runs, levels):
                    try:
                        mesh = (
                            fast_mesh(p, frame, level=level)
                            if mode == "fast"
                            else detailed_mesh(
                                p, frame, v.points_cam, support_plane=plane, level=level, upsample=upsample
                            )
                        )
                        j, d = score(mesh, v.truth_cam)
                    except ValueError:
                        j, d = 0.0, math.nan
                    variant = f"{vname}/{mode}"
                    variant += f"+{upsample}" if len(args.upsample) > 1 and mode == "detailed" else ""
                    variant += f"@{level:g}" if len(levels) > 1 else ""
                    rows.append({**base, "variant": variant, "j80": j, "distance_mm": d})
        print(f"{i + 1}/{len(views)} {name} {view_set} {kind}", flush=True)
    report(rows)
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)


def report(rows: list[dict]) -> None:
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    hull = {(r["object"], r["view"]): r["j80"] for r in rows if r["variant"] == "Hull"}
    print(f"\n{'variant':28s} {'set':24s} {'n':>4s} {'J80':>6s} {'dist mm':>8s} {'> Hull':>7s}")
    for var in variants:
        for s in ("tabletop_train_object", "tabletop_holdout_model", "all"):
            sel = [r for r in rows if r["variant"] == var and s in ("all", r["view_set"])]
            if not sel:
                continue
            wins = np.mean([r["j80"] > hull[(r["object"], r["view"])] for r in sel])
            print(
                f"{var:28s} {s:24s} {len(sel):4d} {np.mean([r['j80'] for r in sel]):6.3f} "
                f"{np.nanmean([r['distance_mm'] for r in sel]):8.2f} {100 * wins:6.0f}%"
            )
    by_kind: dict = defaultdict(lambda: defaultdict(list))
    for r in rows:
        by_kind[r["kind"]][r["variant"]].append(r["j80"])
    print("\nJ80 per kind: " + " | ".join(variants))
    for k in sorted(by_kind):
        print(f"{k:14s} n={len(by_kind[k]['Hull']):3d} " + " ".join(f"{np.mean(by_kind[k][v]):.3f}" for v in variants))


if __name__ == "__main__":
    main()
