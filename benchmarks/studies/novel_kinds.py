"""Completion on kinds of objects no training data holds: tabletop views of the novel families
(:mod:`shapeviewer.sim.novel`: rings, dumbbells, L-brackets, teapots, wedges, stools, stars, vases),
completed through the public entry point as an outside caller would, against the Hull.

Each view is a tabletop view like the evaluation's (the object resting on a table among holdout
neighbours, a Kinect or RealSense 20-70 degrees above the table at 0.4-1.2 m, the app's segmentation
cutting the segment and finding the table). Its points (``--input mask``: every pixel of the object,
as a caller with known poses or a detector's mask has them; ``segment``: the app's segment) and
the support plane the segmentation found go to
``shapeviewer.complete(points_cam, support_plane=plane, mode=...)``; the fast and detailed meshes
and the Hull (:func:`shapeviewer.completion.baselines.hull_mesh`) are scored against the true mesh by J80
(:func:`shapeviewer.evaluation.metrics.sampled_jaccard`) and the mean symmetric surface distance (mm).

    python -m benchmarks.studies.novel_kinds [--per-kind 4] [--views 2] [--seed 0] [--input mask] [--processes 2] \
        [--weights PATH] [--sensor realsense] [--noise-scale 2]
    python -m benchmarks.studies.novel_kinds --objects holdout   # the same on the catalogue's holdout household objects

Prints one line per view, then the means per kind and over all views, and how many views each
completion beats the Hull on.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
from collections import defaultdict
from functools import cache

import numpy as np

METHODS = ("Hull", "Ours-fast", "Ours-detailed")
WEIGHTS: str | None = None  # the worker's CNN weights (None: the shipped model)


@cache
def _completer():
    from shapeviewer.completion.model import load_completer

    return load_completer(WEIGHTS)


def score(name: str, view: int, seed: int, source: str, sensor: str | None, noise_scale: float) -> dict | None:
    """One view's J80 and mean distance per method (None when the object was hidden or not segmented)."""
    import shapeviewer as sv
    from shapeviewer.completion.baselines import hull_mesh
    from shapeviewer.evaluation.metrics import hausdorff, sampled_jaccard
    from shapeviewer.sim.tabletop import render_tabletop_view

    v = render_tabletop_view(name, view, seed=seed, sensor=sensor, noise_scale=noise_scale)
    if v is None:
        return None
    truth = v.truth_cam()
    points = v.points_cam
    if source == "mask":
        points = v.capture.points_cam.reshape(-1, 3)[v.capture.labels.reshape(-1) == 0]
    meshes = {
        "Hull": hull_mesh(points),
        "Ours-fast": sv.complete(points, support_plane=v.plane_cam, mode="fast", completer=_completer()),
        "Ours-detailed": sv.complete(points, support_plane=v.plane_cam, mode="detailed", completer=_completer()),
    }
    row = {"name": name, "view": view, "sensor": v.sensor, "watertight": all(m.is_watertight for m in meshes.values())}
    for method, mesh in meshes.items():
        row[method] = (sampled_jaccard(mesh, truth), hausdorff(mesh, truth)["mean_mm"])
    return row


def holdout_household(per_kind: int) -> list[str]:
    """The first ``per_kind`` holdout models of each household kind (catalogue names)."""
    from shapeviewer.sim import catalogue, household

    holdout = sorted(e.name for e in catalogue.catalogue() if e.split == "holdout_model")
    return [n for k in household.KINDS for n in [h for h in holdout if h.startswith(f"household/{k}_")][:per_kind]]


def tabletop_views(names: list[str], views: int, seed: int) -> list[tuple[str, int]]:
    """``views`` seeded tabletop view ids of each object, ``(name, view)``, numbered as the
    evaluation's tabletop set numbers its own (past ``TABLETOP_VIEW_OFFSET``)."""
    from shapeviewer.evaluation.viewsets import TABLETOP_VIEW_OFFSET

    rng = np.random.default_rng([seed, 17])
    return [(name, TABLETOP_VIEW_OFFSET + int(rng.integers(1_000_000))) for name in names for _ in range(views)]


def _init(threads: int, weights: str | None) -> None:
    import torch

    global WEIGHTS
    WEIGHTS = weights
    torch.set_num_threads(threads)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--per-kind", type=int, default=4, help="objects of each novel kind")
    ap.add_argument("--views", type=int, default=2, help="tabletop views of each object")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--input", choices=("mask", "segment"), default="mask", help="the object's pixels or the app's segment"
    )
    ap.add_argument(
        "--objects",
        choices=("novel", "holdout"),
        default="novel",
        help="the novel kinds, or for comparison the catalogue's holdout household objects (the first of each kind)",
    )
    ap.add_argument("--sensor", choices=("kinect", "realsense"), default=None, help="default: each view draws one")
    ap.add_argument(
        "--noise-scale", type=float, default=1.0, help="the sensor's depth error times this (a worse sensor or surface)"
    )
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--weights", default=None, help="CNN weights (.pt); default: the shipped model")
    args = ap.parse_args()

    from shapeviewer.sim import novel

    names = novel.names(args.per_kind) if args.objects == "novel" else holdout_household(args.per_kind)
    jobs = [
        (name, view, args.seed, args.input, args.sensor, args.noise_scale)
        for name, view in tabletop_views(names, args.views, args.seed)
    ]
    threads = max(1, (mp.cpu_count() or 1) // args.processes)
    with mp.get_context("spawn").Pool(args.processes, initializer=_init, initargs=(threads, args.weights)) as pool:
        rows = [r for r in pool.starmap(score, jobs, chunksize=1) if r is not None]
    by_kind: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        kind = r["name"].partition("/")[2].rsplit("_", 1)[0]
        by_kind[kind].append(r)
        by_kind["all"].append(r)
        print(
            f"{r['name']:20s} {r['view']:6d} {r['sensor']:9s} "
            + "  ".join(f"{m} {r[m][0]:.3f}/{r[m][1]:.1f}mm" for m in METHODS),
            flush=True,
        )
    print(f"\n{len(rows)} of {len(jobs)} views segmented; J80 / mean distance (mm)")
    print(f"{'kind':10s} {'views':>5s} " + " ".join(f"{m:>20s}" for m in METHODS) + "   beats Hull (fast, detailed)")
    for kind in [*sorted(k for k in by_kind if k != "all"), "all"]:
        rs = by_kind[kind]
        means = [
            f"{np.mean([r[m][0] for r in rs]):.3f} / {np.mean([r[m][1] for r in rs]):5.1f}".rjust(20) for m in METHODS
        ]
        beats = [sum(r[m][0] > r["Hull"][0] for r in rs) for m in ("Ours-fast", "Ours-detailed")]
        print(f"{kind:10s} {len(rs):5d} " + " ".join(means) + f"   {beats[0]}/{len(rs)}, {beats[1]}/{len(rs)}")
    print(f"every mesh watertight: {all(r['watertight'] for r in rows)}")


if __name__ == "__main__":
    main()
