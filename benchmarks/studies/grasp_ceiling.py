"""The grasp pipeline's ceiling on an evaluation's views: grasps planned on the *true* mesh (a perfect
completion) and executed and lifted on it with the evaluation's protocol.

Three rankings of the planner's grasps, each scored by whether its best grasp lifted the object:

* ``epsilon``: the planner without its lift check (GraspIt's epsilon, which knows neither gravity
  nor the table nor how the fingers squeeze);
* ``lift check``: the planner as the evaluation runs it;
* ``robust``: those grasps ranked by :func:`~shapeviewer.grasp.robust.robustness` over 8 copies of the
  true mesh, each grasped with the palm off by the ranking's pose errors: what the robust ranking
  does when the completion and its samples are exactly right, so only the pose error and the
  simulation are left to miss.

So the completions' figures in Table V read against what a perfect completion gets with the same
hand, planner and protocol.

    shapeviewer evaluate --out results/table15 --views tabletop --views-per-set 15   # the views
    python -m benchmarks.studies.grasp_ceiling results/table15 [--n-grasps 20] [--budget 0] [--no-epsilon] \\
        [--processes 2]

``--budget 0``: the full search, as ``evaluate`` plans by default. Prints per view whether each
ranking's best grasp lifted the true object and how many grasps did, then the shares per view set.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
from pathlib import Path

from benchmarks.common.shares import add, new_shares, print_shares

SAMPLES = 8  # copies of the true mesh, as many as the CNN's sample completions


def ceiling(root: Path, file: Path, n_grasps: int, budget: float | None, epsilon: bool) -> dict:
    """One view's rankings: {ranking: whether its best grasp lifted the true object}, and counts."""
    from shapeviewer.evaluation.run import grasp_meshes, plan_seed
    from shapeviewer.grasp.execute import execute_grasps
    from shapeviewer.grasp.plan import plan
    from shapeviewer.grasp.robust import rank_robust, robustness

    record = json.loads(file.read_text())
    _, truth, _, table = grasp_meshes(root, record, "truth")
    seed = plan_seed(record["seed"], record["object"], int(record["view"]))
    out = {"object": record["object"], "view_set": record["view_set"]}
    for check in [False, True] if epsilon else [True]:
        grasps = plan(truth, n_grasps=n_grasps, seed=seed, table=table, budget_seconds=budget, lift_check=check).grasps
        lifted = [bool(r.lift.success) for r in execute_grasps(grasps, truth, table=table, lift=True)]
        out["lift check" if check else "epsilon"] = bool(lifted[:1] == [True])
        out["lifted " + ("lift check" if check else "epsilon")] = f"{sum(lifted)}/{len(lifted)}"
        if check:
            scores = robustness(grasps, [truth] * SAMPLES, truth, table=table)
            out["robust"] = bool(lifted and lifted[rank_robust(scores, [g.lift for g in grasps])[0]])
            out["any"] = any(lifted)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", type=Path, help="a results folder of shapeviewer evaluate")
    ap.add_argument("--n-grasps", type=int, default=10)
    ap.add_argument("--budget", type=float, default=10.0, help="planning time limit per view, seconds (0: none)")
    ap.add_argument("--no-epsilon", action="store_true", help="skip the ranking without the lift check")
    ap.add_argument("--processes", type=int, default=1, help="views planned at once")
    args = ap.parse_args()

    files = sorted((args.results / "views").glob("*.json"))
    if not files:
        raise SystemExit(f"no views in {args.results}: run shapeviewer evaluate --out {args.results} first")
    budget = args.budget or None
    jobs = [(args.results, f, args.n_grasps, budget, not args.no_epsilon) for f in files]
    by_set = new_shares()
    with mp.get_context("fork").Pool(args.processes) as pool:
        for row in pool.starmap(ceiling, jobs, chunksize=1) if args.processes > 1 else (ceiling(*j) for j in jobs):
            print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
            for k, v in row.items():
                if isinstance(v, bool):
                    add(by_set, k, row["view_set"], v)
    print(f"\nbest grasp lifted the true object ({len(files)} views, {args.n_grasps} grasps planned on the true mesh)")
    print_shares(by_set, "ranking")


if __name__ == "__main__":
    main()
