"""Grasps planned on the grasp envelope of the CNN's sample completions and ranked by robustness over
them, against the grasps an evaluation planned on the completion itself, on the same views.

For every view of a results folder of ``shapeviewer evaluate --grasps --robust`` (which saved each
view's 8 sample completions and the Ours-detailed grasps with their outcomes): the envelope
(:func:`shapeviewer.grasp.robust.envelope_mesh`: the mean answer's mesh at p = 0.3, which keeps what
the network hedges on) is planned on with the evaluation's planner and seed, every grasp is executed
and lifted on the true object with the evaluation's protocol, and the grasps are ranked by
:func:`~shapeviewer.grasp.robust.robustness` over the sample meshes (p = 0.5), as the evaluation
ranks Ours-detailed's. Prints the best grasp's lift success for:

* ``completion, planner`` / ``completion, robust``: the folder's own Ours-detailed grasps (planned on
  the detailed mesh), the planner's best and the robust ranking's best as saved;
* ``envelope, planner`` / ``envelope, robust``: the envelope's grasps, the planner's best and the
  robust ranking's best;
* ``envelope, any``: a view where any envelope grasp lifted the object (the ceiling of a ranking).

    shapeviewer evaluate --out results/s14_table3_20 --views tabletop --views-per-set 50 --seed 3 \\
        --workers 2 --grasps --grasp-methods Ours-detailed --robust
    python -m benchmarks.studies.envelope_grasps results/s14_table3_20 [--n-grasps 20] [--level 0.3] [--processes 2]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
from pathlib import Path

from benchmarks.common.shares import add, new_shares, print_shares


def view_outcomes(root: Path, file: Path, n_grasps: int, level: float) -> dict | None:
    """One view's best-grasp outcomes ({ranking: lifted the true object}), or None without the
    folder's robust Ours-detailed grasps."""
    from shapeviewer.evaluation.records import samples_file, view_stem
    from shapeviewer.evaluation.run import grasp_meshes, load_samples, plan_seed
    from shapeviewer.grasp.execute import execute_grasps
    from shapeviewer.grasp.plan import plan
    from shapeviewer.grasp.robust import envelope_mesh, rank_robust, robustness, sample_meshes
    from shapeviewer.grasp.serialize import grasps_from_json

    record = json.loads(file.read_text())
    entry = next((g for g in record.get("grasps", []) if g["method"] == "Ours-detailed"), None)
    if entry is None or entry["error"] or not entry["file"]:
        return None
    saved = grasps_from_json((root / entry["file"]).read_text())
    ranks = saved.meta.get("robustness")
    if not ranks:
        return None
    completion, truth, T_world_cam, table = grasp_meshes(root, record, "Ours-detailed")
    samples, frame, mesh_level = load_samples(root / samples_file(view_stem(record["object"], int(record["view"]))))
    meshes = sample_meshes(samples, frame, T_world_cam, level=mesh_level)
    envelope = envelope_mesh(samples, frame, T_world_cam, level=level)
    seed = plan_seed(record["seed"], record["object"], int(record["view"]))
    grasps = plan(envelope, n_grasps=n_grasps, seed=seed, table=table).grasps
    lifted = [bool(r.lift.success) for r in execute_grasps(grasps, truth, table=table, lift=True)]
    before = [bool(e.lift is not None and e.lift.success) for e in saved.executions]
    # The samples are cut along the completion's convex parts, as the evaluation's ranking cuts them.
    best = rank_robust(robustness(grasps, meshes, completion, table=table), [g.lift for g in grasps])[:1]
    return {
        "view_set": record["view_set"],
        "completion, planner": before[0] if before else False,
        "completion, robust": before[next(i for i, r in enumerate(ranks) if r["rank"] == 0)] if before else False,
        "envelope, planner": lifted[0] if lifted else False,
        "envelope, robust": bool(best and lifted[best[0]]),
        "envelope, any": any(lifted),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", type=Path, help="a results folder of shapeviewer evaluate --grasps --robust")
    ap.add_argument("--n-grasps", type=int, default=20)
    ap.add_argument("--level", type=float, default=None, help="the envelope's level (default: ENVELOPE_LEVEL)")
    ap.add_argument("--processes", type=int, default=2)
    args = ap.parse_args()

    from shapeviewer.grasp.robust import ENVELOPE_LEVEL

    files = sorted((args.results / "views").glob("*.json"))
    if not files:
        raise SystemExit(f"no views in {args.results}: run shapeviewer evaluate --grasps --robust --out {args.results}")
    level = ENVELOPE_LEVEL if args.level is None else args.level
    jobs = [(args.results, f, args.n_grasps, level) for f in files]
    with mp.get_context("fork").Pool(args.processes) as pool:
        rows = [r for r in pool.starmap(view_outcomes, jobs, chunksize=1) if r is not None]
    shares = new_shares()
    for r in rows:
        for k, v in r.items():
            if k != "view_set":
                add(shares, k, r["view_set"], v)
    print(f"best grasp's lift success, {len(rows)} views (envelope at p = {level})")
    print_shares(shares, "grasps, ranking")


if __name__ == "__main__":
    main()
