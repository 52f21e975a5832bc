"""The grasp planner's ceiling on an evaluation's views: grasps planned on the *true* mesh (a perfect
completion), executed and lifted on it with the evaluation's protocol, with and without the
planner's lift check.

Without the check the planner ranks by epsilon, which knows neither gravity nor the table nor how
the fingers squeeze; this measures what that costs when the shape is exactly right, so that the
completions' figures in Table V can be read against it.

    shapeviewer evaluate --out results/table15 --views tabletop --views-per-set 15   # the views
    python benchmarks/grasp_ceiling.py results/table15 [--n-grasps 10] [--budget 10]

Prints, per view, whether the planner's best grasp lifted the true object (epsilon ranking, then
with the lift check) and how many of its grasps did, then the shares over all views.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", type=Path, help="a results folder of shapeviewer evaluate")
    ap.add_argument("--n-grasps", type=int, default=10)
    ap.add_argument("--budget", type=float, default=10.0, help="planning time limit per view, seconds")
    args = ap.parse_args()

    from shapeviewer.evaluation.run import grasp_meshes, plan_seed
    from shapeviewer.grasp.execute import execute_grasps
    from shapeviewer.grasp.plan import plan

    files = sorted((args.results / "views").glob("*.json"))
    if not files:
        raise SystemExit(f"no views in {args.results}: run shapeviewer evaluate --out {args.results} first")
    best = {False: [], True: []}
    print(f"{'object':32s} {'set':24s} {'epsilon best':>12s} {'checked best':>12s} {'lifted (eps)':>12s}")
    for f in files:
        record = json.loads(f.read_text())
        _, truth, _, table = grasp_meshes(args.results, record, "truth")
        seed = plan_seed(record["seed"], record["object"], int(record["view"]))
        lifted = {}
        for check in (False, True):
            grasps = plan(
                truth, n_grasps=args.n_grasps, seed=seed, table=table, budget_seconds=args.budget, lift_check=check
            ).grasps
            runs = execute_grasps(grasps, truth, table=table, lift=True)
            lifted[check] = [bool(r.lift.success) for r in runs]
            best[check].append(bool(lifted[check][:1] == [True]))
        print(
            f"{record['object']:32s} {record['view_set']:24s} {str(best[False][-1]):>12s} {str(best[True][-1]):>12s}"
            f" {sum(lifted[False]):>5d}/{len(lifted[False]):<6d}",
            flush=True,
        )
    print(
        f"\nbest grasp lifted the true object in {100 * np.mean(best[False]):.1f}% of {len(files)} views ranked "
        f"by epsilon, {100 * np.mean(best[True]):.1f}% with the lift check"
    )


if __name__ == "__main__":
    main()
