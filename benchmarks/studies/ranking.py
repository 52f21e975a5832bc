"""How well each way of ranking a view's grasps picks one that lifts the true object, on the grasps
an evaluation already planned and executed (the robust ranking against the planner's).

``shapeviewer evaluate --grasps --robust`` plans each view's grasps on the completion, executes every
one of them on the true mesh, and re-closes each on the CNN's 8 sample completions
(:mod:`shapeviewer.grasp.robust`); its grasp files keep each grasp's epsilon on every sample. This
re-ranks those same grasps offline, so rankings compare on identical grasps and outcomes:

* ``planner``: the planner's order (its lift check on the completion, then epsilon);
* ``robust q=<q>``: :func:`~shapeviewer.grasp.robust.rank_robust` with the robust epsilon taken at the
  lower quantile ``q`` of the samples' epsilons (0: the worst sample);
* ``oracle``: a view counts as a success when any of its grasps lifted the true object (the ceiling
  of any ranking of these grasps);
* ``robust now`` (with ``--rerank``): the grasps ranked again by today's
  :func:`~shapeviewer.grasp.robust.robustness` on the view's saved sample completions, so that a
  change to the robust score is measured on the grasps and outcomes of an earlier evaluation;
  with ``--settings``, ``robust <lift_top>,<recheck_top>[,<hedge>]`` for each instead (how many
  grasps are lifted on every sample, how many of those again in a second round, and how far below
  the completion's level every other sample is meshed: ``grasp.robust.HEDGE``, 0 meshes all at it).

    shapeviewer evaluate --out results/table50 --views tabletop --views-per-set 50 --grasps \\
        --n-grasps 10 --grasp-budget 10 --grasp-methods Ours-detailed --robust
    python -m benchmarks.studies.ranking results/table50 [more results folders] [--quantiles 0 0.25 0.5] \\
        [--rerank [--processes 2] [--settings 3,2,0 3,2,0.2 5,0]]

Prints the best grasp's lift success per view set for each ranking (a view without grasps counts as
a failure, and a view whose grasping stage failed is left out, as in Table V).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
from pathlib import Path

import numpy as np

from benchmarks.common.shares import add, new_shares, print_shares


def rerank(root: Path, record: dict, method: str, grasps: list, wider: dict | None, options: dict) -> int:
    """The index of a view's best grasp by today's pick (:func:`~shapeviewer.grasp.pick.rank_grasps`,
    with ``options``), on its saved ``grasps`` and sample completions (the evaluation's own robust
    step). ``wider``: the grasp file's ``meta["wider"]`` when it holds the wider search's grasps
    (after the first ``wider["first"]``, planned on the envelope): they are scored against the
    envelope and compete when the first grasps' best is weak, as in the evaluation. A view that
    becomes weak only under ``options`` has no wider grasps saved to compete."""
    from shapeviewer.evaluation.records import samples_file, view_stem
    from shapeviewer.evaluation.run import grasp_meshes, sample_completions
    from shapeviewer.grasp.pick import rank_grasps

    if not grasps:
        # A view without grasps fails whatever the pick; and a StopIteration from next() below
        # would silently end the pool's chunk of results.
        return 0
    hedge = options.pop("hedge", None)
    completion, _, T_world_cam, table = grasp_meshes(root, record, method)
    samples = sample_completions(
        root / samples_file(view_stem(record["object"], int(record["view"]))), T_world_cam, hedge=hedge
    )
    first = len(grasps) if wider is None else int(wider["first"])

    def envelope():
        """The envelope the wider grasps were planned on, in the grasp world."""
        assert wider is not None
        files = {**record["files"], "envelope": wider["planned_on"]}
        return grasp_meshes(root, {**record, "files": files}, "envelope")[0]

    pick = rank_grasps(
        completion,
        samples,
        hand=grasps[0].hand,
        table=table,
        planned=grasps[:first],
        wider=grasps[first:],  # never planned again: only the saved ones compete
        widen=wider is not None,
        widen_below=0.0 if wider is None else float(wider["below"]),
        envelope=envelope,
        **options,
    )
    return pick.order[0]


def setting_options(setting: str) -> dict:
    """``"3,2"`` or ``"3,2,0.2"`` as :func:`rerank`'s options: ``lift_top`` and ``recheck_top`` of
    :func:`~shapeviewer.grasp.robust.robustness`, ``hedge`` of the sample meshes."""
    values = setting.split(",")
    if len(values) not in (2, 3):
        raise SystemExit(f"--settings {setting}: expected lift_top,recheck_top[,hedge]")
    options = {"lift_top": int(values[0]), "recheck_top": int(values[1])}
    return options | ({"hedge": float(values[2])} if len(values) == 3 else {})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("results", nargs="+", type=Path, help="results folders of shapeviewer evaluate --grasps --robust")
    ap.add_argument("--method", default="Ours-detailed")
    ap.add_argument("--quantiles", nargs="+", type=float, default=[0.0, 0.125, 0.25, 0.5])
    ap.add_argument("--rerank", action="store_true", help="also rank by today's robustness (recomputed)")
    ap.add_argument("--processes", type=int, default=2, help="views re-ranked at once, with --rerank")
    ap.add_argument(
        "--settings", nargs="+", default=None, help="with --rerank: lift_top,recheck_top[,hedge] (default hedge)"
    )
    args = ap.parse_args()

    from shapeviewer.grasp.robust import Robustness, rank_robust
    from shapeviewer.grasp.serialize import grasps_from_json

    success = new_shares()
    views = []
    for root in args.results:
        files = sorted((root / "views").glob("*.json"))
        if not files:
            raise SystemExit(f"no views in {root}: run shapeviewer evaluate --grasps --robust --out {root} first")
        for f in files:
            record = json.loads(f.read_text())
            entry = next((g for g in record.get("grasps", []) if g["method"] == args.method), None)
            if entry is None or entry["error"] or not entry["file"]:
                continue  # as Table V does: a view whose grasping failed is reported apart
            views.append((root, record, grasps_from_json((root / entry["file"]).read_text())))
    settings = (
        {"robust now": {}} if args.settings is None else {f"robust {s}": setting_options(s) for s in args.settings}
    )
    reranked: dict[str, list] = {}
    if args.rerank:
        with mp.get_context("fork").Pool(args.processes) as pool:
            for label, options in settings.items():
                jobs = [
                    (root, record, args.method, gs.grasps, gs.meta.get("wider"), dict(options))
                    for root, record, gs in views
                ]
                reranked[label] = pool.starmap(rerank, jobs)
    for k, (_, record, gs) in enumerate(views):
        lifted = [bool(e.lift is not None and e.lift.success) for e in gs.executions]
        robust = gs.meta.get("robustness")
        picks = {"planner": 0, "oracle": int(np.argmax(lifted)) if lifted else 0}
        if robust:
            for q in args.quantiles:
                scores = [Robustness.of(r["epsilons"], q, r.get("lifted"), r.get("lift_rounds")) for r in robust]
                picks[f"robust q={q:g}"] = rank_robust(scores, [g.lift for g in gs.grasps])[0]
        picks.update({label: picks_now[k] for label, picks_now in reranked.items()})
        for name, i in picks.items():
            add(success, name, record["view_set"], float(lifted[i]) if lifted else 0.0)
    print_shares(success, "ranking")


if __name__ == "__main__":
    main()
