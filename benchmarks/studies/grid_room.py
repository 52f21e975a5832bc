"""How much of the true object the paper's 40^3 placement leaves outside the grid, on tabletop views.

The paper places the visible points' bounding box with its centre at voxel (20, 20, 18) and its
largest side 32 voxels long (:func:`shapeviewer.completion.voxel.frame_for_points`). The visible points are the
object's front, so what the network must add lies behind them; whatever lies past the grid's back
face (z = 40) cannot be completed at all, and the fast and detailed meshes end there.

For tabletop views of the catalogue's holdout household objects (the views of
``benchmarks/studies/novel_kinds.py``: the object resting on a table among neighbours, a Kinect or RealSense
20-70 degrees above it), this prints per shape kind the true object's farthest and nearest depth in
grid voxels (medians), the share of views whose object reaches past the back face, and the share of
its surface (even samples) outside the grid; then the share of views past the back face if the
placement moved the object ``k`` voxels towards the camera (keeping the visible front at least
``--front`` voxels inside the grid).

    python -m benchmarks.studies.grid_room [--per-kind 4] [--views 3] [--seed 0] [--processes 2]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
from collections import defaultdict

import numpy as np

SHIFTS = (2, 4, 6)  # voxels towards the camera
SURFACE_SAMPLES = 20_000


def extent(name: str, view: int, seed: int) -> dict | None:
    """One view: the true surface's grid coordinates, summarised (None when the object is hidden)."""
    import trimesh

    from shapeviewer.completion.voxel import GRID_DIM, frame_for_points
    from shapeviewer.perception.camera import transform_points
    from shapeviewer.sim import catalogue
    from shapeviewer.sim.tabletop import render_tabletop_view

    v = render_tabletop_view(name, view, seed=seed)
    if v is None:
        return None
    frame = frame_for_points(v.points_cam)
    mesh = catalogue.centred_mesh(name)
    surface, _ = trimesh.sample.sample_surface_even(mesh, SURFACE_SAMPLES, seed=0)
    g = frame.to_grid(transform_points(v.T_cam_obj, surface))  # continuous grid coordinates, voxels
    seen = frame.to_grid(np.asarray(v.points_cam, dtype=np.float64))
    return {
        "kind": catalogue.shape_kind(name),
        "z_far": float(g[:, 2].max()),
        "z_near": float(g[:, 2].min()),
        "front": float(seen[:, 2].min()),
        "outside": float((~((g >= 0) & (g <= GRID_DIM)).all(axis=1)).mean()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--per-kind", type=int, default=4, help="holdout objects of each household kind")
    ap.add_argument("--views", type=int, default=3, help="tabletop views of each object")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--front", type=float, default=2.0, help="voxels kept in front of the visible points")
    ap.add_argument("--processes", type=int, default=2)
    args = ap.parse_args()

    from benchmarks.studies.novel_kinds import holdout_household, tabletop_views  # the same views
    from shapeviewer.completion.voxel import GRID_DIM

    jobs = [(n, view, args.seed) for n, view in tabletop_views(holdout_household(args.per_kind), args.views, args.seed)]
    with mp.get_context("spawn").Pool(args.processes) as pool:
        rows = [r for r in pool.starmap(extent, jobs, chunksize=2) if r is not None]
    by_kind: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        by_kind[r["kind"]].append(r)
        by_kind["all"].append(r)
    print(f"{len(rows)} of {len(jobs)} views; depths in voxels of the 40^3 grid (back face at {GRID_DIM})")
    head = " ".join(f"k={k}".rjust(6) for k in SHIFTS)
    print(
        f"{'kind':13s} {'views':>5s} {'far':>5s} {'near':>5s} {'past back':>9s} {'surface out':>11s}"
        f"   past back at {head}"
    )
    for kind in [*sorted(k for k in by_kind if k != "all"), "all"]:
        rs = by_kind[kind]
        far = np.array([r["z_far"] for r in rs])
        room = np.array([max(0.0, r["front"] - args.front) for r in rs])
        past = " ".join(f"{np.mean(far - np.minimum(k, room) > GRID_DIM):6.2f}" for k in SHIFTS)
        print(
            f"{kind:13s} {len(rs):5d} {np.median(far):5.1f} {np.median([r['z_near'] for r in rs]):5.1f} "
            f"{np.mean(far > GRID_DIM):9.2f} {np.mean([r['outside'] for r in rs]):11.3f}   {'':12s}{past}"
        )


if __name__ == "__main__":
    main()
