"""The paper's completion tables (Tables I-III, SPEC §7): Partial, Mirror, Ours-fast, Ours-detailed.

Test set (as in the paper): ``n_per_set`` views of each of the three evaluation sets,
*training views*, *holdout views* and *holdout models* (:func:`catalogue.view_split`), drawn with a
seed from the catalogue objects and the 726-view orientation grid. Each view is rendered exactly as
the training data is (:func:`generate.view_pose`, :func:`generate.render_view` with the live camera
model ``Intrinsics.kinect()`` and ``KinectNoise``, the same noise seed as ``generate``), so a
*training view* here is the very view the network may have trained on.

Per view and method: the completed mesh (camera frame), the completion time, and the three metrics
of :func:`metrics.completion_metrics` against the ground-truth mesh (the catalogue mesh centred on
its bounding-box centroid, as ``generate`` does, moved by ``T_cam_obj``).

Mirror baseline and the support plane: the rendered object floats alone in an arbitrary
orientation on the roll-pitch-yaw grid (no table, as in the paper's views), so no support plane
is given (``support_plane_cam=None``) and :func:`baselines.mirror_mesh` runs its documented
no-table rule (mirror plane normal = horizontal direction from the camera to the points, only the
position searched). Constructing a "table" from the true object pose would leak the ground truth
into a baseline, which a real robot looking at a floating object could not know.

Times: Ours-fast = voxelize + CNN + marching cubes; Ours-detailed = voxelize + CNN + Algorithm 1
(the CNN is run once and its time counted in both).

Grasps (Tables IV and V, SPEC §8; ``grasps=True``): for every view and each of ``GRASP_METHODS``
(Partial, Mirror, Ours-fast and Ours-detailed: planning costs about the same on every mesh, so
both of our meshes are evaluated; the paper's one "Ours" is compared with Ours-detailed), up to
``n_grasps`` grasps are planned on the completion (:func:`grasp.plan.plan`) and every one is
executed on the ground-truth mesh (:func:`grasp.execute.execute_grasps`, the paper's protocol,
then the dynamic lift test). Both run with ``table=False`` (the object floats, as rendered) in
the *evaluation world frame* ``T_WORLD_CAM``: the body frame of a level camera at the origin
(x forward = camera z, y left = -camera x, z up = -camera y), so that the lift test's gravity
(-z) points down the image. Recorded per grasp: planned epsilon and volume, executed epsilon,
joint error (deg), pose error (mm), lift success; per view and method their means.

Outputs in ``out_dir``: ``views/<object>__<view>.json`` (one per view, see :func:`view_record`;
the run resumes by skipping finished work: the completions of a view, then each grasp method),
``rows.csv`` (all completion rows), ``meshes/<object>__<view>__<method>.ply`` plus
``__truth.ply`` and ``__points.ply`` (camera frame), ``grasps/<object>__<view>__<method>.json``
(:func:`grasp.export.grasps_to_json`, planned and executed, evaluation world frame; a hand other
than the Barrett adds ``__<hand>``), ``grasp_rows.csv`` (one row per executed grasp), and
``tables.md`` / ``tables.csv``.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import multiprocessing as mp
import os
import time
import traceback
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..sim import catalogue
from .viewsets import SET_TITLES, VIEW_SETS, render_view, sample_views

log = logging.getLogger(__name__)

METHODS = ("Partial", "Mirror", "Hull", "Ours-fast", "Ours-detailed")
METRICS = ("jaccard", "j80", "hausdorff_mean_mm", "hausdorff_max_mm", "hausdorff_rms_mm", "geodesic")
ROW_FIELDS = ("object", "view", "view_set", "kind", "sensor", "method", *METRICS, "seconds", "error")
# SPEC §7: the paper's figures, {metric: {view_set: (Partial, Mirror, Ours)}}.
PAPER = {
    "jaccard": {"training_view": (0.118, 0.233, 0.777), "holdout_view": (0.131, 0.239, 0.749),
                "holdout_model": (0.093, 0.192, 0.650)},
    "hausdorff_mean_mm": {"training_view": (11.4, 7.5, 3.6), "holdout_view": (12.3, 8.2, 4.0),
                          "holdout_model": (13.6, 10.7, 5.9)},
    "geodesic": {"training_view": (0.377, 0.291, 0.087), "holdout_view": (0.494, 0.337, 0.093),
                 "holdout_model": (0.341, 0.280, 0.141)},
}
TABLES = (("I", "jaccard", "Jaccard similarity (higher is better)"),
          ("II", "hausdorff_mean_mm", "Hausdorff distance, mean, mm (lower is better)"),
          ("III", "geodesic", "Geodesic divergence (lower is better)"),
          ("J80", "j80", "Jaccard of the solids sampled at 80^3 points, J80 (higher is better)"))

GRASP_METHODS = METHODS  # every completion, the baselines and both of our meshes (see the docstring)
# Per view and method, means over its grasps (the keys of a view's "grasps" entries).
GRASP_MEANS = ("joint_error_deg", "pose_error_mm", "epsilon_planned", "volume_planned", "epsilon_executed",
               "volume_executed", "force_closure_planned", "force_closure_executed", "start_clear", "lift_success")
GRASP_ROW_FIELDS = ("object", "view", "view_set", "method", "hand", "rank", "epsilon_planned", "volume_planned",
                    "energy_planned", "epsilon_executed", "volume_executed", "joint_error_deg", "pose_error_mm",
                    "start_clear", "approach_contact", "lift_success", "lift_rise_mm", "lift_slip_mm")
# SPEC §8: the paper's Table IV, {quantity: {view_set: (Partial, Mirror, Ours)}}. SPEC gives the
# training-view and holdout-model rows only; the holdout-view row is left blank rather than guessed.
PAPER_GRASP = {
    "joint_error_deg": {"training_view": (6.09, 4.20, 1.75), "holdout_model": (7.59, 5.82, 4.56)},
    "pose_error_mm": {"training_view": (16.0, 11.5, 4.3), "holdout_model": (18.3, 15.0, 13.2)},
}
# SPEC §8: the paper's Table V, real-robot grasp success (15 objects), Partial / Mirror / Ours.
PAPER_LIFT = (0.714, 0.733, 0.933)
# The paper's one "Ours" is compared with our detailed mesh; -1: the paper has no such column.
PAPER_COLUMN = {"Partial": 0, "Mirror": 1, "Hull": -1, "Ours-fast": -1, "Ours-detailed": 2}


def paper_figure(metric: str, view_set: str, method: str) -> float:
    """The paper's Table I-III figure for a cell (NaN where the paper has none)."""
    col = PAPER_COLUMN.get(method, -1)
    row = PAPER.get(metric, {}).get(view_set)
    return math.nan if row is None or col < 0 else row[col]


def _stem(name: str, view: int) -> str:
    return f"{name.replace('/', '__')}__{view:03d}"


def evaluate_view(name: str, view: int, completer, out_dir: str | Path, seed: int = 0,
                  view_set: str | None = None) -> list[dict]:
    """Every method on one view: one row per method (a failing method records its error).

    Tabletop views give the support plane the segmentation found to Mirror and to our completion.
    """
    from ..baselines import hull_mesh, mirror_mesh, partial_mesh
    from ..metrics import completion_metrics
    from ..reconstruct import detailed_mesh, fast_mesh
    from ..voxel import context_grids, partial_to_grid

    view_set = view_set or catalogue.view_split(name, view)
    mesh_dir = Path(out_dir) / "meshes"
    mesh_dir.mkdir(parents=True, exist_ok=True)
    stem = _stem(name, view)
    base = {"object": name, "view": int(view), "view_set": view_set, "kind": catalogue.shape_kind(name), "sensor": ""}
    try:
        observed = render_view(name, view, view_set, seed)
    except Exception as e:  # unrenderable view: every method records it
        return [{**base, "method": m, **{k: math.nan for k in METRICS}, "seconds": math.nan,
                 "error": f"render: {e}"} for m in METHODS]
    points, truth, plane = observed.points_cam, observed.truth_cam, observed.support_plane
    base["sensor"] = observed.sensor
    # Carried by the rows to the view's record (see view_record), where the grasp stage finds it.
    base["support_plane"] = None if plane is None else [float(v) for v in plane]
    truth.export(mesh_dir / f"{stem}__truth.ply")
    if len(points):
        import trimesh

        trimesh.PointCloud(points).export(mesh_dir / f"{stem}__points.ply")

    cnn: dict = {}

    def cnn_output():
        if not cnn:
            t0 = time.perf_counter()
            x, frame = partial_to_grid(points)
            probs = completer.predict(x, context=context_grids(points, frame, plane))
            cnn.update(probs=probs, frame=frame, seconds=time.perf_counter() - t0)
        return cnn

    def ours_fast():
        c = cnn_output()
        t0 = time.perf_counter()
        return fast_mesh(c["probs"], c["frame"]), c["seconds"] + time.perf_counter() - t0

    def ours_detailed():
        c = cnn_output()
        t0 = time.perf_counter()
        return (detailed_mesh(c["probs"], c["frame"], points, support_plane=plane),
                c["seconds"] + time.perf_counter() - t0)

    def timed(fn):
        def run():
            t0 = time.perf_counter()
            return fn(), time.perf_counter() - t0
        return run

    methods = {"Partial": timed(lambda: partial_mesh(points)),
               "Mirror": timed(lambda: mirror_mesh(points, plane)),
               "Hull": timed(lambda: hull_mesh(points)),
               "Ours-fast": ours_fast, "Ours-detailed": ours_detailed}
    rows = []
    for method, run in methods.items():
        row = {**base, "method": method, **{k: math.nan for k in METRICS}, "seconds": math.nan, "error": ""}
        try:
            mesh, seconds = run()
            row["seconds"] = float(seconds)
            mesh.export(mesh_dir / f"{stem}__{method}.ply")
            row.update({k: float(v) for k, v in completion_metrics(mesh, truth, seed=seed).items()})
        except Exception as e:  # one method failing must not stop the others
            row["error"] = f"{type(e).__name__}: {e}"
            log.info("%s view %d %s failed:\n%s", name, view, method, traceback.format_exc())
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------------------------
# Per-view records


def _view_file(out_dir, name: str, view: int) -> Path:
    return Path(out_dir) / "views" / f"{_stem(name, view)}.json"


def _mesh_files(out_dir, stem: str) -> dict[str, str]:
    """Paths relative to ``out_dir`` of the view's meshes that exist: ``truth``, ``points`` and
    each method's completion (all camera frame, metres)."""
    files = {}
    for key in ("truth", "points", *METHODS):
        rel = f"meshes/{stem}__{key}.ply"
        if (Path(out_dir) / rel).exists():
            files[key] = rel
    return files


def view_record(out_dir, name: str, view: int, view_set: str, seed: int, rows: list[dict]) -> dict:
    """A view's record, as saved in ``views/<stem>.json``::

        {"object", "view", "view_set", "seed", "support_plane": [a, b, c, d] (camera frame) or None,
         "files": {"truth": "meshes/..", "points": "meshes/..", "<method>": "meshes/.."},
         "rows": [completion rows, ROW_FIELDS],
         "grasps": [one entry per (method, hand), see grasp_view]}

    ``files`` lists only meshes that exist (a failed method has none); paths are relative to
    ``out_dir``.
    """
    planes = [r.pop("support_plane", None) for r in rows]
    return {"object": name, "view": int(view), "view_set": view_set, "seed": int(seed),
            "support_plane": next((p for p in planes if p is not None), None),
            "files": _mesh_files(out_dir, _stem(name, view)), "rows": rows, "grasps": []}


def load_view(out_dir, name: str, view: int, seed: int | None = None) -> dict | None:
    """The record of a view (see :func:`view_record`), or None when it has not been computed.

    Files of the first format (a bare list of completion rows, which did not store the seed)
    are returned as records with ``seed`` (the caller's run seed) and the meshes found on disk.
    """
    path = _view_file(out_dir, name, view)
    if not path.exists():
        return None
    data = json.loads(path.read_text())
    if isinstance(data, list):
        view_set = data[0]["view_set"] if data else catalogue.view_split(name, view)
        return view_record(out_dir, name, view, view_set, -1 if seed is None else seed, data)
    data.setdefault("grasps", [])
    return data


def _save_view(out_dir, record: dict) -> None:
    path = _view_file(out_dir, record["object"], record["view"])
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(record, indent=1))  # NaN is written as NaN, which json reads back
    os.replace(tmp, path)


# ----------------------------------------------------------------------------------------------
# Grasps (Tables IV and V)

# The evaluation world frame (see the module docstring): a level camera's body frame, camera at
# the origin. Rows map camera axes: world x = camera z (forward), y = -camera x, z = -camera y (up).
T_WORLD_CAM = np.array([[0.0, 0.0, 1.0, 0.0],
                        [-1.0, 0.0, 0.0, 0.0],
                        [0.0, -1.0, 0.0, 0.0],
                        [0.0, 0.0, 0.0, 1.0]])
GRASP_FRAME = ("evaluation world: level camera body frame, camera at the origin, x forward (camera z), "
               "y left (-camera x), z up (-camera y); no table")


@dataclass(frozen=True)
class GraspOptions:
    """The grasp stage of :func:`evaluate`: completion ``methods`` grasped, the ``hand``, grasps
    planned per view and method, the planner's wall-clock ``budget_seconds`` (None: its full
    deterministic search) and its search sizes (``settings``; None: the planner's defaults)."""

    methods: tuple[str, ...] = GRASP_METHODS
    hand: str = "barrett"
    n_grasps: int = 20
    budget_seconds: float | None = None
    settings: object | None = None  # grasp.plan.PlanSettings (imported lazily: pybullet is heavy)

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown or not self.methods:
            raise ValueError(f"grasp methods must be some of {', '.join(METHODS)}; got {list(self.methods)}")
        if self.hand not in ("barrett", "panda"):
            raise ValueError(f"unknown hand {self.hand!r} (barrett or panda)")
        if self.n_grasps < 1:
            raise ValueError(f"n_grasps must be at least 1, got {self.n_grasps}")


def grasp_file(stem: str, method: str, hand: str = "barrett") -> str:
    """Path (relative to the results folder) of a view's grasps for one method and hand."""
    return f"grasps/{stem}__{method}{'' if hand == 'barrett' else '__' + hand}.json"


def plan_seed(seed: int, name: str, view: int) -> int:
    """The planner's seed for a view: the same for every method, so that the methods differ only
    in the mesh they plan on."""
    return int(np.random.SeedSequence([seed, zlib.crc32(name.encode()), int(view), 13]).generate_state(1)[0])


def _world_mesh(path: Path, T_world_cam: np.ndarray = T_WORLD_CAM):
    """A saved camera-frame mesh moved into a world frame (metres)."""
    import trimesh

    mesh = trimesh.load(path, force="mesh")
    mesh.apply_transform(T_world_cam)
    return mesh


def grasp_world(record: dict) -> tuple[np.ndarray, bool]:
    """``(T_world_cam, table)`` of a view's grasp stage: the table frame of the support plane the
    segmentation found (z up, the table at z = 0) with the table in the world, or, for a floating
    object, the evaluation world frame ``T_WORLD_CAM`` without a table."""
    if record.get("support_plane") is None:
        return T_WORLD_CAM, False
    from ..segment import table_frame

    return table_frame(np.asarray(record["support_plane"], dtype=np.float64)), True


def grasp_rows(base: dict, grasps, executions) -> list[dict]:
    """One row (``GRASP_ROW_FIELDS``) per planned grasp and its execution on the true object.

    ``base``: object, view, view_set, method, hand. Units: joint error in degrees (mm for the
    Panda's prismatic fingers), pose error, lift rise and slip in mm; booleans as 0/1.
    """
    rows = []
    for rank, (g, e) in enumerate(zip(grasps, executions)):
        lift = e.lift
        rows.append({**base, "rank": rank, "epsilon_planned": float(g.epsilon), "volume_planned": float(g.volume),
                     "energy_planned": float(g.energy), "epsilon_executed": float(e.epsilon),
                     "volume_executed": float(e.volume), "joint_error_deg": float(e.joint_error),
                     "pose_error_mm": float(e.pose_error), "start_clear": float(e.start_clear),
                     "approach_contact": float(e.approach_contact),
                     "lift_success": math.nan if lift is None else float(lift.success),
                     "lift_rise_mm": math.nan if lift is None else 1000.0 * lift.rise,
                     "lift_slip_mm": math.nan if lift is None else 1000.0 * lift.slip})
    return rows


def grasp_means(rows: list[dict]) -> dict:
    """Means over one view's grasp rows (``GRASP_MEANS``; NaN without grasps) and
    ``lift_success_best``: whether the planner's best grasp (rank 0, the one a robot would
    execute) lifted the object; 0 when no grasp was found (a robot would have had nothing to try)."""
    planned_fc = [float(r["epsilon_planned"] > 0) for r in rows]
    executed_fc = [float(r["epsilon_executed"] > 0) for r in rows]
    out = {"force_closure_planned": planned_fc, "force_closure_executed": executed_fc}
    means = {k: (float(np.mean(out[k] if k in out else [r[k] for r in rows])) if rows else math.nan)
             for k in GRASP_MEANS}
    means["lift_success_best"] = float(rows[0]["lift_success"]) if rows else 0.0
    return means


def grasp_view(out_dir, record: dict, method: str, options: GraspOptions = GraspOptions()) -> dict:
    """Plan grasps on one view's ``method`` completion and execute each on its true mesh.

    Both meshes are read from ``out_dir`` (camera frame) and moved to the evaluation world frame
    (``T_WORLD_CAM``); planning and execution run without a table (the object floats). The
    grasps, planned and executed, go to ``grasp_file(...)`` with the frame in their ``meta``.
    Returns the view's entry: ``{"method", "hand", "file", "n", <GRASP_MEANS means>,
    "lift_success_best", "n_requested", "plan_seed", "seconds_plan", "seconds_execute", "frame",
    "error"}``; a failure (no mesh, planner error) records ``error`` and NaN means.
    """
    from ..grasp.execute import execute_grasps
    from ..grasp.serialize import grasps_to_json
    from ..grasp.plan import PlanSettings, plan

    out = Path(out_dir)
    name, view = record["object"], int(record["view"])
    stem = _stem(name, view)
    seed = plan_seed(record["seed"], name, view)
    entry = {"method": method, "hand": options.hand, "file": "", "n": 0,
             **grasp_means([]), "lift_success_best": math.nan, "n_requested": int(options.n_grasps),
             "plan_seed": seed, "seconds_plan": math.nan, "seconds_execute": math.nan, "frame": "evaluation_world",
             "error": ""}
    missing = [k for k in ("truth", method) if k not in record["files"]]
    if missing:
        entry["error"] = f"no {' or '.join(missing)} mesh"
        return entry
    T_world_cam, table = grasp_world(record)
    try:
        completion = _world_mesh(out / record["files"][method], T_world_cam)
        truth = _world_mesh(out / record["files"]["truth"], T_world_cam)
        if table:  # the estimated table may sit a few mm high: the true object must not start inside it
            truth.apply_translation([0.0, 0.0, max(0.0, -float(truth.bounds[0, 2]))])
        t0 = time.perf_counter()
        result = plan(completion, options.hand, options.n_grasps, seed=seed, table=table,
                      budget_seconds=options.budget_seconds, settings=options.settings or PlanSettings())
        t1 = time.perf_counter()
        executions = execute_grasps(result.grasps, truth, table=table, lift=True)
        t2 = time.perf_counter()
    except Exception as e:  # one mesh the planner cannot handle must not stop the run
        entry["error"] = f"{type(e).__name__}: {e}"
        log.info("%s view %d %s grasps failed:\n%s", name, view, method, traceback.format_exc())
        return entry
    rel = grasp_file(stem, method, options.hand)
    meta = {"object": name, "view": view, "view_set": record["view_set"], "method": method,
            "frame": GRASP_FRAME if not table else "table frame of the segmentation's support plane (z up, table at z = 0)",
            "T_world_cam": T_world_cam.tolist(), "planned_on": record["files"][method],
            "executed_on": record["files"]["truth"], "table": table, "plan_seed": seed,
            "plan_stats": {"evaluations": result.stats.evaluations, "simulated": result.stats.simulated,
                           "seconds": result.stats.seconds, "cancelled": result.stats.cancelled}}
    path = out / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(grasps_to_json(result.grasps, executions, meta))
    os.replace(tmp, path)
    base = {"object": name, "view": view, "view_set": record["view_set"], "method": method, "hand": options.hand}
    entry.update(file=rel, n=len(result.grasps), **grasp_means(grasp_rows(base, result.grasps, executions)),
                 seconds_plan=t1 - t0, seconds_execute=t2 - t1)
    return entry


def pending_grasps(record: dict, options: GraspOptions) -> list[str]:
    """Methods of ``options`` still to grasp on this view: no entry for (method, hand), or one
    with an error (retried: it may have been a crash)."""
    done = {(g["method"], g["hand"]) for g in record.get("grasps", []) if not g["error"]}
    return [m for m in options.methods if (m, options.hand) not in done]


def load_grasp_rows(out_dir, records: list[dict]) -> list[dict]:
    """Every executed grasp of the records' grasp entries, read back from their grasp files."""
    from ..grasp.serialize import grasps_from_json

    rows = []
    for rec in records:
        for g in rec.get("grasps", []):
            if g["error"] or not g["file"]:
                continue
            gs = grasps_from_json((Path(out_dir) / g["file"]).read_text())
            base = {"object": rec["object"], "view": int(rec["view"]), "view_set": rec["view_set"],
                    "method": g["method"], "hand": g["hand"]}
            rows += grasp_rows(base, gs.grasps, gs.executions)
    return rows


# ----------------------------------------------------------------------------------------------
# Runner


_WORKER: dict = {}


def _init_worker(weights, threads: int) -> None:
    import torch

    torch.set_num_threads(threads)
    _WORKER.clear()
    _WORKER["weights"] = weights


def _completer():
    """The worker's CNN, loaded on first use (a grasp-only rerun never needs it)."""
    if "completer" not in _WORKER:
        from ..model import load_completer

        _WORKER["completer"] = load_completer(_WORKER.get("weights"))
    return _WORKER["completer"]


def _run_one(task) -> str:
    """One view: its completions unless saved, then each pending grasp method (saved after each,
    so an interrupted run loses at most one method's grasps)."""
    name, view, view_set, out_dir, seed, options = task
    record = load_view(out_dir, name, view, seed)
    if record is None:
        rows = evaluate_view(name, view, _completer(), out_dir, seed=seed, view_set=view_set)
        record = view_record(out_dir, name, view, view_set, seed, rows)
        _save_view(out_dir, record)
    if options is not None:
        for method in pending_grasps(record, options):
            entry = grasp_view(out_dir, record, method, options)
            record["grasps"] = [g for g in record["grasps"] if (g["method"], g["hand"]) != (method, options.hand)]
            record["grasps"].append(entry)
            _save_view(out_dir, record)
    return name


def _upgrade_old_views(out: Path, views: list[tuple[str, int, str]], seed: int) -> None:
    """Rewrite first-format view files (bare row lists) as records, so that every file in
    ``views/`` has the current format."""
    for n, v, _ in views:
        path = _view_file(out, n, v)
        if path.exists() and isinstance(json.loads(path.read_text()), list):
            _save_view(out, load_view(out, n, v, seed))


def evaluate(out_dir: str | Path, n_per_set: int = 50, seed: int = 0, weights=None, workers: int | None = None,
             progress: bool = True, grasps: GraspOptions | bool | None = None, views: str = "paper") -> dict:
    """Run the test set (resumable), then write ``rows.csv``, ``tables.md`` and ``tables.csv``
    (and with ``grasps``, ``grasp_rows.csv`` and Tables IV/V).

    ``views``: ``paper`` (the paper's three view sets) or ``tabletop`` (:mod:`shapeviewer.evaluation.viewsets`).
    ``grasps``: True or a :class:`GraspOptions` adds the grasp stage; finished completions are
    read from ``meshes/``, never recomputed. Returns ``{"computed", "skipped", "rows", "summary",
    "grasp_rows", "grasp_summary", "tables_md", "seconds"}``; ``summary`` is ``{view_set:
    {method: {metric: mean, "seconds": mean, "n": ok rows, "failed": rows}}}``, ``grasp_summary``
    as :func:`summarize_grasps`. ``computed`` counts views with any work done.
    """
    options = GraspOptions() if grasps is True else (grasps or None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    views = sample_views(n_per_set, seed, views)
    _upgrade_old_views(out, views, seed)

    def needs_work(n: str, v: int) -> bool:
        record = load_view(out, n, v, seed)
        return record is None or (options is not None and bool(pending_grasps(record, options)))

    todo = [(n, v, s, str(out), seed, options) for n, v, s in views if needs_work(n, v)]
    workers = max(1, min(workers or os.cpu_count() or 1, len(todo) or 1))
    threads = max(1, (os.cpu_count() or 1) // workers)
    if todo:
        from tqdm import tqdm

        bar = tqdm(total=len(todo), desc="evaluate", unit="view", disable=not progress)
        if workers == 1:
            _init_worker(weights, threads)
            try:
                for task in todo:
                    _run_one(task)
                    bar.update()
            finally:
                _WORKER.clear()
        else:
            with mp.get_context("spawn").Pool(workers, initializer=_init_worker, initargs=(weights, threads)) as pool:
                for _ in pool.imap_unordered(_run_one, todo):
                    bar.update()
        bar.close()
    records = [load_view(out, n, v, seed) for n, v, _ in views]
    rows = [r for rec in records for r in rec["rows"]]
    _write_csv(out / "rows.csv", ROW_FIELDS, rows)
    summary = summarize(rows)
    g_rows = load_grasp_rows(out, records)
    g_summary = summarize_grasps(records, g_rows)
    if g_rows or any(rec["grasps"] for rec in records):
        _write_csv(out / "grasp_rows.csv", GRASP_ROW_FIELDS, g_rows)
    md = tables_markdown(summary, n_per_set=n_per_set, seed=seed) + kind_table_markdown(rows)
    if g_summary:
        md += grasp_tables_markdown(g_summary)
    (out / "tables.md").write_text(md)
    write_tables_csv(summary, out / "tables.csv", g_summary)
    return {"computed": len(todo), "skipped": len(views) - len(todo), "rows": rows, "summary": summary,
            "grasp_rows": g_rows, "grasp_summary": g_summary, "tables_md": md, "seconds": time.perf_counter() - t0}


def _write_csv(path: Path, fields: tuple[str, ...], rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)


# ----------------------------------------------------------------------------------------------
# Tables


def summarize(rows: list[dict]) -> dict:
    """Means per view set and method over the rows without error."""
    out: dict = {}
    for s in VIEW_SETS:
        out[s] = {}
        for m in METHODS:
            sel = [r for r in rows if r["view_set"] == s and r["method"] == m]
            ok = [r for r in sel if not r["error"]]
            cell = {k: (float(np.mean([r[k] for r in ok])) if ok else math.nan) for k in (*METRICS, "seconds")}
            cell.update(n=len(ok), failed=len(sel) - len(ok))
            out[s][m] = cell
    return out


def _nanmean(values) -> float:
    vals = [float(v) for v in values if not math.isnan(float(v))]
    return float(np.mean(vals)) if vals else math.nan


def summarize_grasps(records: list[dict], rows: list[dict]) -> dict:
    """``{hand: {view_set or "all": {method: cell}}}`` over every grasp entry of the records.

    A cell pools the grasps of its views: ``GRASP_MEANS`` means over grasps, medians of the joint
    and pose errors (``joint_error_deg_median``, ``pose_error_mm_median``), ``grasps`` (their
    number), ``lift_success_best`` (mean over views of the best grasp's lift, 0 for a view
    without grasps), ``views`` (entries without error), ``no_grasp`` (of those, views where the
    planner found none), ``failed`` (entries with an error) and ``seconds_plan`` (mean per view).
    """
    hands = sorted({g["hand"] for rec in records for g in rec.get("grasps", [])})
    out: dict = {}
    for hand in hands:
        out[hand] = {}
        for s in (*VIEW_SETS, "all"):
            out[hand][s] = {}
            for m in METHODS:
                entries = [g for rec in records if s in ("all", rec["view_set"]) for g in rec["grasps"]
                           if g["hand"] == hand and g["method"] == m]
                if not entries:
                    continue
                ok = [g for g in entries if not g["error"]]
                sel = [r for r in rows if r["hand"] == hand and r["method"] == m and s in ("all", r["view_set"])]
                cell = {k: _nanmean(r[k] for r in sel) if k not in ("force_closure_planned", "force_closure_executed")
                        else _nanmean(float(r[k.replace("force_closure", "epsilon")] > 0) for r in sel)
                        for k in GRASP_MEANS}
                # Medians too: a few grasps whose fingers meet the true object far ahead of the
                # completion stop 50-150 mm early and dominate the means.
                for k in ("joint_error_deg", "pose_error_mm"):
                    vals = [r[k] for r in sel if not math.isnan(r[k])]
                    cell[f"{k}_median"] = float(np.median(vals)) if vals else math.nan
                cell.update(grasps=len(sel), views=len(ok), failed=len(entries) - len(ok),
                            no_grasp=sum(1 for g in ok if g["n"] == 0),
                            lift_success_best=_nanmean(g["lift_success_best"] for g in ok),
                            seconds_plan=_nanmean(g["seconds_plan"] for g in ok))
                out[hand][s][m] = cell
    return out


def _fmt(v: float, metric: str) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    return f"{v:.1f}" if metric.startswith("hausdorff") else f"{v:.3f}"


def tables_markdown(summary: dict, n_per_set: int | None = None, seed: int | None = None) -> str:
    lines = ["# Completion results (paper Tables I–III)", ""]
    if n_per_set is not None:
        lines += [f"{n_per_set} views per set, seed {seed}. Our means, then the paper's figures (theirs, on their data, "
                  "SPEC §7; the paper has one \"Ours\"). Means over views where the method succeeded; "
                  "n = successes/views.", ""]
    sets = [s for s in VIEW_SETS if any(summary[s][m]["n"] + summary[s][m]["failed"] for m in METHODS)]
    for number, metric, title in TABLES:
        lines += [f"## Table {number}: {title}", "",
                  "| View set | " + " | ".join(METHODS) + " | paper Partial | paper Mirror | paper Ours |",
                  "|---" * (len(METHODS) + 4) + "|"]
        for s in sets:
            cells = [f"{_fmt(summary[s][m][metric], metric)} (n={summary[s][m]['n']}/"
                     f"{summary[s][m]['n'] + summary[s][m]['failed']})" for m in METHODS]
            paper = [_fmt(paper_figure(metric, s, m), metric) for m in ("Partial", "Mirror", "Ours-detailed")]
            lines.append(f"| {SET_TITLES[s]} | " + " | ".join(cells + paper) + " |")
        lines.append("")
    lines += ["## Mean completion time, seconds (all view sets)", "", "| " + " | ".join(METHODS) + " |",
              "|---" * len(METHODS) + "|"]
    times = []
    for m in METHODS:
        vals = [(summary[s][m]["seconds"], summary[s][m]["n"]) for s in sets if summary[s][m]["n"]]
        n = sum(c for _, c in vals)
        times.append(f"{sum(v * c for v, c in vals) / n:.2f}" if n else "–")
    lines += ["| " + " | ".join(times) + " |", "",
              "Other metrics (Hausdorff max and RMS) are in rows.csv and tables.csv.", ""]
    return "\n".join(lines)


def kind_table_markdown(rows: list[dict]) -> str:
    """J80 and mean surface distance per view set and shape kind (:func:`catalogue.shape_kind`), so
    that a weak family shows; empty when the rows carry no kinds."""
    kinds = sorted({r.get("kind", "") for r in rows} - {""})
    if not kinds:
        return ""
    lines = ["## Per shape kind: J80 / mean surface distance (mm)", "",
             "| View set | kind | views | " + " | ".join(METHODS) + " |", "|---" * (len(METHODS) + 3) + "|"]
    for s in VIEW_SETS:
        for k in kinds:
            sel = [r for r in rows if r["view_set"] == s and r.get("kind") == k]
            if not sel:
                continue
            cells = []
            for m in METHODS:
                ok = [r for r in sel if r["method"] == m and not r["error"]]
                cells.append(f"{_fmt(_nanmean(r['j80'] for r in ok), 'j80')} / "
                             f"{_fmt(_nanmean(r['hausdorff_mean_mm'] for r in ok), 'hausdorff')}" if ok else "–")
            lines.append(f"| {SET_TITLES[s]} | {k} | {len({(r['object'], r['view']) for r in sel})} | "
                         + " | ".join(cells) + " |")
    return "\n".join(lines + [""])


def _num(v: float, digits: int = 2, scale: float = 1.0, suffix: str = "") -> str:
    return "–" if v is None or math.isnan(v) else f"{scale * v:.{digits}f}{suffix}"


def _paper_grasp(quantity: str, view_set: str, method: str) -> float:
    col = PAPER_COLUMN.get(method, -1)
    row = PAPER_GRASP[quantity].get(view_set)
    return math.nan if row is None or col < 0 else row[col]


def grasp_tables_markdown(g_summary: dict) -> str:
    """Table IV (joint and pose error) and the simulated analogue of Table V (lift success) for
    each hand in ``g_summary`` (see :func:`summarize_grasps`), with the paper's figures."""
    lines = []
    for hand, by_set in g_summary.items():
        methods = [m for m in METHODS if any(m in by_set[s] for s in VIEW_SETS)]
        paper_methods = ("Partial", "Mirror", "Ours-detailed")
        lines += [f"# Grasp results (paper Tables IV and V), {hand} hand", "",
                  "Grasps planned on each completion (the paper's views: no table, the object floating as rendered; "
                  "tabletop views: on the table the segmentation found, in its frame), every planned grasp "
                  "executed on the true mesh with the paper's protocol (SPEC §8) and lifted in simulation. Means "
                  "over all executed grasps of the view set, shown as mean / median (the paper reports means); n = grasps "
                  "(views without a grasp: see the quality table). Paper figures: theirs, on their data; their \"Ours\" beside our Ours-detailed; SPEC §8 "
                  "has no holdout-view row for Table IV.", ""]
        for number, key, title, digits in (("IV", "joint_error_deg", "joint error, degrees (lower is better)", 2),
                                           ("IV", "pose_error_mm", "palm pose error, mm (lower is better)", 1)):
            lines += [f"## Table {number}: {title}", "",
                      "| View set | " + " | ".join(methods) + " | paper Partial | paper Mirror | paper Ours |",
                      "|---" * (len(methods) + 4) + "|"]
            for s in (s for s in VIEW_SETS if by_set[s]):
                cells = [f"{_num(c[key], digits)} / {_num(c[key + '_median'], digits)} (n={c['grasps']})"
                         if (c := by_set[s].get(m)) else "–" for m in methods]
                paper = [_num(_paper_grasp(key, s, m), digits) for m in paper_methods]
                lines.append(f"| {SET_TITLES[s]} | " + " | ".join(cells + paper) + " |")
            lines.append("")
        lines += ["## Table V analogue: simulated lift success, all grasps / best grasp per view (higher is better)",
                  "", "| View set | " + " | ".join(methods) + " |", "|---" * (len(methods) + 1) + "|"]
        for s in (*(s for s in VIEW_SETS if by_set[s]), "all"):
            cells = [f"{_num(c['lift_success'], 1, 100, '%')} / {_num(c['lift_success_best'], 1, 100, '%')} "
                     f"(n={c['grasps']}/{c['views']})" if (c := by_set[s].get(m)) else "–" for m in methods]
            lines.append(f"| {SET_TITLES.get(s, 'All views')} | " + " | ".join(cells) + " |")
        paper = {m: PAPER_LIFT[PAPER_COLUMN[m]] if PAPER_COLUMN[m] >= 0 else math.nan for m in methods}
        lines += ["| paper, real robot (15 objects) | " + " | ".join(_num(paper[m], 1, 100, "%") for m in methods)
                  + " |", "",
                  "Best grasp: the planner's top-ranked grasp of each view (what a robot would execute; a view "
                  "without any grasp counts as a failure), n = grasps/views. The paper's figures are real-robot "
                  "trials, ours a pybullet lift of 12 cm (the paper's views: object free, no table).", "",
                  "## Grasp quality and planning (all views)", "",
                  "| Method | epsilon planned | epsilon executed | force closure planned | force closure executed "
                  "| start clear | views without grasp | failed | plan s/view |", "|---" * 9 + "|"]
        for m in methods:
            c = by_set["all"][m]
            lines.append(f"| {m} | {_num(c['epsilon_planned'], 3)} | {_num(c['epsilon_executed'], 3)} | "
                         f"{_num(c['force_closure_planned'], 1, 100, '%')} | "
                         f"{_num(c['force_closure_executed'], 1, 100, '%')} | {_num(c['start_clear'], 1, 100, '%')} | "
                         f"{c['no_grasp']}/{c['views']} | {c['failed']} | {_num(c['seconds_plan'], 1)} |")
        lines += ["", "Per-grasp values are in grasp_rows.csv, per-view means in views/*.json.", ""]
    return "\n".join(lines)


CSV_FIELDS = ("table", "view_set", "method", "n", "failed", *METRICS, "seconds",
              "paper_jaccard", "paper_hausdorff_mean_mm", "paper_geodesic",
              "hand", "grasps", "no_grasp", *GRASP_MEANS, "joint_error_deg_median", "pose_error_mm_median",
              "lift_success_best", "seconds_plan",
              "paper_joint_error_deg", "paper_pose_error_mm", "paper_lift_success")


def write_tables_csv(summary: dict, path: Path, g_summary: dict | None = None) -> None:
    """Every table cell as a CSV row: completion cells (``table`` "I-III") and, with
    ``g_summary``, grasp cells (``table`` "IV-V", view set "all" too; ``n`` = views, ``failed`` =
    views whose grasp stage failed). Cells a row does not have are blank."""
    rows = []
    for s in VIEW_SETS:
        for m in METHODS:
            c = summary[s][m]
            if not c["n"] + c["failed"]:
                continue
            rows.append({"table": "I-III", "view_set": s, "method": m, "n": c["n"], "failed": c["failed"],
                         **{k: c[k] for k in (*METRICS, "seconds")},
                         **{f"paper_{k}": paper_figure(k, s, m) for k in ("jaccard", "hausdorff_mean_mm", "geodesic")}})
    for hand, by_set in (g_summary or {}).items():
        for s, cells in by_set.items():
            for m, c in cells.items():
                col = PAPER_COLUMN[m]
                rows.append({"table": "IV-V", "view_set": s, "method": m, "n": c["views"], "failed": c["failed"],
                             "hand": hand, **{k: c[k] for k in ("grasps", "no_grasp", *GRASP_MEANS,
                                                                "joint_error_deg_median", "pose_error_mm_median",
                                                                "lift_success_best", "seconds_plan")},
                             "paper_joint_error_deg": _paper_grasp("joint_error_deg", s, m),
                             "paper_pose_error_mm": _paper_grasp("pose_error_mm", s, m),
                             "paper_lift_success": PAPER_LIFT[col] if col >= 0 and s == "all" else math.nan})
    _write_csv(path, CSV_FIELDS, rows)
