"""Speed of ranking grasps by robustness over the completion's uncertainty (target: the
planner's 20 grasps ranked over 8 sample completions in <= 3 s, median, on 2 CPU cores).

Cases are test views as ``shapeviewer evaluate --views tabletop`` sees them: the view's segment is
completed by the CNN with its 8 symmetry samples (:meth:`Completer.predict_samples`), grasps are
planned on the fast mesh (sample 0) in the table frame, and :func:`grasp.robust.robustness`
re-closes every grasp on every sample's mesh (the palm off by that sample's pose error) and lifts
the ``LIFT_TOP`` most robust on every sample. Planning is set-up, not timed; its V-HACD of the
fast mesh, which robustness cuts the samples along, is then in the cache as it is after any plan.

    python benchmarks/robust.py [--views 5] [--set tabletop_holdout_model] [--grasps 20] [--processes 2] \
        [--settings 4,2 5,0 3,2,0] [--wider]

``--settings``: ``lift_top,recheck_top[,hedge]`` (default: the module's ``LIFT_TOP,RECHECK_TOP``;
``hedge``: how far below the level every other sample is meshed, default ``HEDGE``), each timed on
every view right after the others, so that they compare under the same load. ``--wider``: where
the first setting's most robust grasp is weak (:func:`grasp.robust.is_weak`), also time the wider
search that "Rank by robustness" then adds: as many grasps planned on the grasp envelope, scored
over the same samples.

Wall-clock times depend on what else runs on the machine; "cpu s" is the CPU time of this process
and its workers together, a load-independent figure (on idle cores the wall time is about it
divided by the processes).
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time

import numpy as np

from common.ranking_settings import setting_options


def cpu_seconds() -> float:
    """User and system CPU time of this process and its finished child processes."""
    return sum(
        u.ru_utime + u.ru_stime
        for u in (resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", type=int, default=5)
    ap.add_argument("--set", default="tabletop_holdout_model", help="a view set of shapeviewer evaluate")
    ap.add_argument("--grasps", type=int, default=20)
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--settings", nargs="+", default=None, help="lift_top,recheck_top[,hedge] to time")
    ap.add_argument("--wider", action="store_true", help="also time the wider search where the ranking is weak")
    args = ap.parse_args()

    from shapeviewer.completion.model import load_completer
    from shapeviewer.completion.voxel import context_grids, partial_to_grid
    from shapeviewer.evaluation.run import grasp_world
    from shapeviewer.evaluation.viewsets import TABLETOP_SETS, render_view, sample_views
    from shapeviewer.grasp.plan import plan
    from shapeviewer.grasp.robust import (
        HEDGE,
        LIFT_TOP,
        RECHECK_TOP,
        envelope_mesh,
        is_weak,
        rank_robust,
        robustness,
        sample_meshes,
    )

    completer = load_completer()
    kind = "tabletop" if args.set in TABLETOP_SETS else "paper"
    views = [v for v in sample_views(args.views, args.seed, kind) if v[2] == args.set]
    settings = {s: {"hedge": HEDGE} | setting_options(s) for s in (args.settings or [f"{LIFT_TOP},{RECHECK_TOP}"])}
    print(
        f"{'view':36s} {'setting':>9s} {'faces':>6s} {'grasps':>6s} {'wall s':>7s} {'cpu s':>6s} {'held':>5s}"
        f" {'top held':>8s} {'robust top':>10s}"
    )
    walls: dict[str, list[float]] = {s: [] for s in settings}
    cpus: dict[str, list[float]] = {s: [] for s in settings}
    wider: list[float] = []  # per view: the wider search's wall time, 0 where the ranking was not weak
    for name, view, view_set in views:
        try:
            observed = render_view(name, view, view_set, args.seed)
        except ValueError as e:  # a tabletop view whose object was hidden
            print(f"(skipping {name} {view}: {e})")
            continue
        grid, frame = partial_to_grid(observed.points_cam, depth_shift=completer.depth_shift)
        context = context_grids(observed.points_cam, frame, support_plane=observed.support_plane)
        samples = completer.predict_samples(grid, 8, context=context)
        plane = observed.support_plane
        T_world_cam, table = grasp_world({"support_plane": None if plane is None else list(plane)})
        meshes = {
            h: sample_meshes(samples, frame, T_world_cam, hedge=h) for h in {o["hedge"] for o in settings.values()}
        }
        first = next(iter(meshes.values()))[0]  # sample 0 is meshed at the level whatever the hedge
        grasps = plan(first, n_grasps=args.grasps, seed=args.seed, table=table).grasps
        if not grasps:
            print(f"(skipping {name} {view}: no grasp planned)")
            continue
        for setting, options in settings.items():
            hedge = options["hedge"]
            cpu, t = cpu_seconds(), time.perf_counter()
            scores = robustness(
                grasps,
                meshes[hedge],
                meshes[hedge][0],
                table=table,
                processes=args.processes,
                lift_top=options["lift_top"],
                recheck_top=options["recheck_top"],
            )
            walls[setting].append(time.perf_counter() - t)
            cpus[setting].append(cpu_seconds() - cpu)
            order = rank_robust(scores, [g.lift for g in grasps])
            best = scores[order[0]]
            label = f"{options['lift_top']},{options['recheck_top']},{hedge:g}"
            print(
                f"{name + ' ' + str(view):36s} {label:>9s}"
                f" {len(meshes[hedge][0].faces):6d}"
                f" {len(grasps):6d} {walls[setting][-1]:7.2f} {cpus[setting][-1]:6.2f}"
                f" {np.mean([s.fraction for s in scores]):5.2f} {scores[0].fraction:8.2f}"
                f" {order[0]:>4d} ({best.fraction:.2f}, lifted {best.lifted if best.lifted is not None else 0:.2f})"
            )
            if args.wider and setting == next(iter(settings)):
                wider.append(0.0)
                if is_weak(scores, [g.lift for g in grasps]):
                    t = time.perf_counter()
                    envelope = envelope_mesh(samples, frame, T_world_cam)
                    more = plan(envelope, n_grasps=args.grasps, seed=args.seed, table=table).grasps
                    robustness(more, meshes[hedge], envelope, table=table, processes=args.processes)
                    wider[-1] = time.perf_counter() - t
                    print(f"{'':36s} wider search: {len(more)} grasps on the envelope, {wider[-1]:.2f} s wall")
    print()
    for s, o in settings.items():
        print(
            f"lift_top {o['lift_top']}, recheck_top {o['recheck_top']}, hedge {o['hedge']:g}:"
            f" median over {len(walls[s])} views"
            f" {statistics.median(walls[s]):.2f} s wall with {args.processes} processes (target 3),"
            f" {statistics.median(cpus[s]):.2f} s CPU"
        )
    if wider:
        weak = [w for w in wider if w > 0]
        print(
            f"wider search in {len(weak)} of {len(wider)} views"
            + (f", median {statistics.median(weak):.2f} s wall where it ran" if weak else "")
        )
    print(
        "'held': mean share of samples a grasp holds on, 'top held': the planner's top grasp's, 'robust top': "
        "the grasp ranked first by robustness (the shares it holds on and lifts)"
    )


if __name__ == "__main__":
    main()
