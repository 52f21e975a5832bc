"""Running the evaluation: per-view completions (Tables I-III, SPEC §7), the grasp stage (Tables IV
and V, SPEC §8), and the runner over local processes or a Ray cluster
(the Dataset tab's sample store is :mod:`.sample_store`).

Test views: :mod:`.viewsets` (``paper``: the paper's three view sets of floating objects, rendered
exactly as the training data is; ``tabletop``: robot views of a table, segmented by the app).

Per view and method (Partial, Mirror, Hull, Ours-fast, Ours-detailed): the completed mesh (camera
optical frame, metres), the completion time (s), and the metrics of
:func:`metrics.completion_metrics` against the ground-truth mesh. Times: Ours-fast = voxelize + CNN
+ marching cubes; Ours-detailed = voxelize + CNN + Algorithm 1 (the CNN runs once, its time counted
in both).

Mirror baseline and the support plane: the paper's views float alone (no table), so no support
plane is given and :func:`baselines.mirror_mesh` runs its documented no-table rule. Constructing a
"table" from the true object pose would leak the ground truth into a baseline, which a real robot
looking at a floating object could not know. Tabletop views give the plane the segmentation found
to Mirror and to our completion.

Grasps (``grasps=True`` or a :class:`GraspOptions`): for every view and each of the options'
methods, up to ``n_grasps`` grasps are planned on the completion (:func:`grasp.plan.plan`) and
every one is executed on the ground-truth mesh (:func:`grasp.execute.execute_grasps`, the paper's
protocol, then the dynamic lift test). Planning costs about the same on every mesh, so both of our
meshes are evaluated; the paper's one "Ours" is compared with Ours-detailed (:mod:`.tables`). With
the options' ``robust``, the grasps of our meshes are also ranked by their robustness over the CNN's
sample completions of the view (:mod:`grasp.robust`), which the completion stage saves: the same
grasps, executed once, so Table V's best grasp compares the two rankings on the same completions.
``Ours-envelope`` is a mesh grasped but not scored as a completion: the grasp envelope of those
sample completions (:func:`grasp.robust.envelope_mesh`), written beside the view's meshes when grasped.
Floating views run without a table in the *evaluation world frame* ``T_WORLD_CAM`` (the body frame
of a level camera at the origin, so that the lift test's gravity, -z, points down the image);
tabletop views in the table frame of the plane the segmentation found.

Outputs in ``out_dir`` (layout: :mod:`.records`): one record per view in ``views/`` (the run
resumes by skipping finished work: a view's completions, then each grasp method), its meshes and
grasp files, ``rows.csv`` (completion rows), ``grasp_rows.csv`` (one row per executed grasp) and
``tables.md`` / ``tables.csv`` (:mod:`.tables`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import multiprocessing as mp
import os
import time
import traceback
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..fileio import atomic_write
from ..runtime.backends import BACKENDS, ray_init
from ..sim import catalogue
from .records import (
    ENVELOPE,
    GRASP_MEANS,
    GRASP_ROW_FIELDS,
    GRASP_TABLE_METHODS,
    METHODS,
    METRICS,
    ROW_FIELDS,
    envelope_file,
    grasp_file,
    grasp_rows,
    load_grasp_rows,
    load_view,
    samples_file,
    save_view,
    set_grasp_entry,
    upgrade_old_views,
    view_record,
    view_stem,
)
from .tables import (
    completion_tables_markdown,
    csv_text,
    grasp_tables_markdown,
    kind_grasp_table_markdown,
    kind_table_markdown,
    summarize,
    summarize_grasps,
    write_tables_csv,
)
from .viewsets import render_view, sample_views

if TYPE_CHECKING:  # imported lazily at run time: pybullet is heavy
    from ..grasp.plan import PlanSettings

log = logging.getLogger(__name__)


def evaluate_view(
    name: str, view: int, completer, out_dir: str | Path, seed: int = 0, view_set: str | None = None
) -> list[dict]:
    """Every method on one view: one completion row per method (a failing method records its
    error), each carrying the view's ``support_plane`` for :func:`records.view_record`. Meshes go
    to ``out_dir/meshes`` (camera optical frame, metres)."""
    from ..completion.baselines import hull_mesh, mirror_mesh, partial_mesh
    from ..completion.pipeline import complete_points, completion_detailed_mesh
    from .metrics import completion_metrics

    view_set = view_set or catalogue.view_split(name, view)
    mesh_dir = Path(out_dir) / "meshes"
    mesh_dir.mkdir(parents=True, exist_ok=True)
    stem = view_stem(name, view)
    base = {"object": name, "view": int(view), "view_set": view_set, "kind": catalogue.shape_kind(name), "sensor": ""}
    try:
        observed = render_view(name, view, view_set, seed)
    except Exception as e:  # unrenderable view: every method records it
        return [
            {**base, "method": m, **{k: math.nan for k in METRICS}, "seconds": math.nan, "error": f"render: {e}"}
            for m in METHODS
        ]
    points, truth, plane = observed.points_cam, observed.truth_cam, observed.support_plane
    base["sensor"] = observed.sensor
    base["support_plane"] = None if plane is None else [float(v) for v in plane]
    truth.export(mesh_dir / f"{stem}__truth.ply")
    if len(points):
        import trimesh

        trimesh.PointCloud(points).export(mesh_dir / f"{stem}__points.ply")

    cnn: dict = {}

    def cnn_output():
        # As the app completes a segment (pipeline.complete_points); the sample completions go to
        # disk for the grasp stage's robust ranking, which re-closes grasps on them.
        if not cnn:
            t0 = time.perf_counter()
            (c,) = complete_points([points], completer, support_plane=plane)
            cnn.update(completion=c, seconds=time.perf_counter() - t0 - c.timings["fast_mesh"])
            np.savez_compressed(
                Path(out_dir) / samples_file(stem),
                samples=c.samples,
                center=c.frame.center,
                voxel_size=c.frame.voxel_size,
                mesh_level=c.mesh_level,
            )
        return cnn

    def ours_fast():
        c = cnn_output()["completion"]
        return c.require_fast_mesh(), cnn["seconds"] + c.timings["fast_mesh"]

    def ours_detailed():
        c = cnn_output()["completion"]
        t0 = time.perf_counter()
        return completion_detailed_mesh(c, points), cnn["seconds"] + time.perf_counter() - t0

    def timed(fn):
        def run():
            t0 = time.perf_counter()
            return fn(), time.perf_counter() - t0

        return run

    methods = {
        "Partial": timed(lambda: partial_mesh(points)),
        "Mirror": timed(lambda: mirror_mesh(points, plane)),
        "Hull": timed(lambda: hull_mesh(points)),
        "Ours-fast": ours_fast,
        "Ours-detailed": ours_detailed,
    }
    rows = []
    for method, run in methods.items():
        row = {
            **base,
            "method": method,
            **{k: math.nan for k in METRICS},
            "seconds": math.nan,
            "error": "",
            "prior": "",
        }
        try:
            mesh, seconds = run()
            if method.startswith("Ours"):
                row["prior"] = cnn["completion"].prior
            row["seconds"] = float(seconds)
            mesh.export(mesh_dir / f"{stem}__{method}.ply")
            row.update({k: float(v) for k, v in completion_metrics(mesh, truth, seed=seed).items()})
        except Exception as e:  # one method failing must not stop the others
            row["error"] = f"{type(e).__name__}: {e}"
            log.info("%s view %d %s failed:\n%s", name, view, method, traceback.format_exc())
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------------------------
# Grasps (Tables IV and V)

# The evaluation world frame (see the module docstring): a level camera's body frame, camera at
# the origin. Rows map camera axes: world x = camera z (forward), y = -camera x, z = -camera y (up).
T_WORLD_CAM = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
GRASP_FRAME = (
    "evaluation world: level camera body frame, camera at the origin, x forward (camera z), "
    "y left (-camera x), z up (-camera y); no table"
)
TABLE_GRASP_FRAME = "table frame of the segmentation's support plane (z up, table at z = 0)"
# Every completion, the baselines and both of our meshes (see the docstring), and the grasp
# envelope of the CNN's sample completions (records.ENVELOPE).
GRASP_METHODS = GRASP_TABLE_METHODS
ROBUST_METHODS = ("Ours-fast", "Ours-detailed", ENVELOPE)  # the CNN's: they have sample completions


@dataclass(frozen=True)
class GraspOptions:
    """The grasp stage of :func:`evaluate`: the ``methods`` grasped (completions, and ``Ours-envelope``,
    the grasp envelope of the CNN's sample completions), the ``hand``, grasps
    planned per view and method, the planner's wall-clock ``budget_seconds`` (None: its full
    deterministic search), its search sizes (``settings``; None: the planner's defaults), whether
    the grasps of :data:`ROBUST_METHODS` are also ranked by robustness (``robust``), and below
    which lift share of the most robust grasp on the samples as many grasps again are planned on
    the grasp envelope and ranked with them (``widen_below``; None: :data:`grasp.robust.WIDEN_BELOW`,
    0: never; not for the envelope's own grasps)."""

    methods: tuple[str, ...] = GRASP_METHODS
    hand: str = "barrett"
    n_grasps: int = 20
    budget_seconds: float | None = None
    settings: PlanSettings | None = None
    robust: bool = False
    widen_below: float | None = None

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in GRASP_METHODS]
        if unknown or not self.methods:
            raise ValueError(f"grasp methods must be some of {', '.join(GRASP_METHODS)}; got {list(self.methods)}")
        if self.hand not in ("barrett", "panda"):
            raise ValueError(f"unknown hand {self.hand!r} (barrett or panda)")
        if self.n_grasps < 1:
            raise ValueError(f"n_grasps must be at least 1, got {self.n_grasps}")


def plan_seed(seed: int, name: str, view: int) -> int:
    """The planner's seed for a view: the same for every method, so that the methods differ only
    in the mesh they plan on."""
    return int(np.random.SeedSequence([seed, zlib.crc32(name.encode()), int(view), 13]).generate_state(1)[0])


def _world_mesh(path: Path, T_world_cam: np.ndarray):
    """A saved camera-frame mesh moved into a world frame (metres)."""
    import trimesh

    mesh = trimesh.load(path, force="mesh")
    mesh.apply_transform(T_world_cam)
    return mesh


def grasp_meshes(out_dir, record: dict, method: str):
    """``(completion, truth, T_world_cam, table)``: a view's ``method`` completion and its true mesh,
    read from ``out_dir`` and moved into the grasp world of :func:`grasp_world` (metres). On a
    table the true object is raised to stand on it: the estimated table may sit a few millimetres
    high, and the object must not start inside it."""
    out = Path(out_dir)
    T_world_cam, table = grasp_world(record)
    completion = _world_mesh(out / record["files"][method], T_world_cam)
    truth = _world_mesh(out / record["files"]["truth"], T_world_cam)
    if table:
        truth.apply_translation([0.0, 0.0, max(0.0, -float(truth.bounds[0, 2]))])
    return completion, truth, T_world_cam, table


def grasp_world(record: dict) -> tuple[np.ndarray, bool]:
    """``(T_world_cam, table)`` of a view's grasp stage: the table frame of the support plane the
    segmentation found (z up, the table at z = 0) with the table in the world, or, for a floating
    object, the evaluation world frame ``T_WORLD_CAM`` without a table."""
    if record.get("support_plane") is None:
        return T_WORLD_CAM, False
    from ..perception.segment import table_frame

    return table_frame(np.asarray(record["support_plane"], dtype=np.float64)), True


def grasp_means(rows: list[dict]) -> dict:
    """Means over one view's grasp rows (``GRASP_MEANS``; NaN without grasps) and
    ``lift_success_best``: whether the planner's best grasp (rank 0, the one a robot would
    execute) lifted the object; 0 when no grasp was found (a robot would have had nothing to try)."""
    derived = {
        "force_closure_planned": [float(r["epsilon_planned"] > 0) for r in rows],
        "force_closure_executed": [float(r["epsilon_executed"] > 0) for r in rows],
    }
    means = {
        k: (float(np.mean(derived[k] if k in derived else [r[k] for r in rows])) if rows else math.nan)
        for k in GRASP_MEANS
    }
    means["lift_success_best"] = float(rows[0]["lift_success"]) if rows else 0.0
    return means


def grasp_view(out_dir, record: dict, method: str, options: GraspOptions = GraspOptions()) -> dict:
    """Plan grasps on one view's ``method`` completion and execute each on its true mesh.

    Both meshes are read from ``out_dir`` (camera frame) and moved to the grasp world of
    :func:`grasp_world`. The grasps, planned and executed, go to ``grasp_file(...)`` with the frame
    in their ``meta`` (and, ranked by robustness, ``meta["robustness"]``: :func:`robust_entries`).
    When even the most robust grasp is weak (:func:`~shapeviewer.grasp.robust.is_weak`), as many
    grasps again are planned on the grasp envelope, executed, scored over the same samples and
    ranked with the first: they follow them in the file, ``meta["wider"]`` says from which index,
    and only the robust ranking sees them (the planner's best and the means over grasps are the
    completion's own).
    Returns the view's entry: ``{"method", "hand", "file", "n", "n_wider", <GRASP_MEANS means>,
    "lift_success_best", "robust", "lift_success_best_robust", "n_requested", "plan_seed",
    "seconds_plan", "seconds_execute", "seconds_robust", "frame", "error"}``: ``robust`` says whether
    the grasps were ranked by robustness (the options ask for it and ``method`` is one of
    :data:`ROBUST_METHODS`), ``lift_success_best_robust`` whether the grasp ranked first by it lifted
    the object (0 without grasps, NaN without the ranking). A failure (no mesh, planner error)
    records ``error`` and NaN means.
    """
    from ..grasp.execute import execute_grasps
    from ..grasp.plan import PlanSettings, plan
    from ..grasp.robust import WIDEN_BELOW, is_weak, robustness
    from ..grasp.serialize import grasps_to_json

    out = Path(out_dir)
    name, view = record["object"], int(record["view"])
    seed = plan_seed(record["seed"], name, view)
    entry = {
        "method": method,
        "hand": options.hand,
        "file": "",
        "n": 0,
        "n_wider": 0,
        **grasp_means([]),
        "lift_success_best": math.nan,
        "robust": options.robust and method in ROBUST_METHODS,
        "lift_success_best_robust": math.nan,
        "n_requested": int(options.n_grasps),
        "plan_seed": seed,
        "seconds_plan": math.nan,
        "seconds_execute": math.nan,
        "seconds_robust": math.nan,
        "frame": "evaluation_world",
        "error": "",
    }
    # The envelope is made from the view's sample completions below, not read like a completion.
    missing = [k for k in ("truth",) + (() if method == ENVELOPE else (method,)) if k not in record["files"]]
    if missing:
        entry["error"] = f"no {' or '.join(missing)} mesh"
        return entry
    try:
        if method == ENVELOPE:
            record = {**record, "files": {**record["files"], ENVELOPE: write_envelope(out, record)}}
        completion, truth, T_world_cam, table = grasp_meshes(out, record, method)
        t0 = time.perf_counter()

        def plan_on(mesh):
            return plan(
                mesh,
                hand=options.hand,
                n_grasps=options.n_grasps,
                seed=seed,
                table=table,
                budget_seconds=options.budget_seconds,
                settings=options.settings or PlanSettings(),
            )

        result = plan_on(completion)
        t1 = time.perf_counter()
        executions = execute_grasps(result.grasps, truth, table=table, lift=True)
        t2 = time.perf_counter()
        grasps, scores, wider = list(result.grasps), None, None
        if entry["robust"]:
            samples = sample_completions(out / samples_file(view_stem(name, view)), T_world_cam)
            scores = robustness(grasps, samples, completion, table=table)
            below = WIDEN_BELOW if options.widen_below is None else options.widen_below
            if method != ENVELOPE and is_weak(scores, [g.lift for g in grasps], below=below):
                # No grasp holds on most samples: as many again on the grasp envelope, ranked with them.
                try:
                    envelope_rel = write_envelope(out, record)
                    envelope = _world_mesh(out / envelope_rel, T_world_cam)
                    wider = plan_on(envelope)
                    more = execute_grasps(wider.grasps, truth, table=table, lift=True)
                    more_scores = robustness(wider.grasps, samples, envelope, table=table)
                except Exception:  # the completion's own grasps stand
                    log.info("%s view %d: the wider search failed:\n%s", name, view, traceback.format_exc())
                    wider = None
                else:
                    grasps, executions, scores = grasps + wider.grasps, executions + more, scores + more_scores
        t3 = time.perf_counter()
    except Exception as e:  # one mesh the planner cannot handle must not stop the run
        entry["error"] = f"{type(e).__name__}: {e}"
        log.info("%s view %d %s grasps failed:\n%s", name, view, method, traceback.format_exc())
        return entry
    rel = grasp_file(view_stem(name, view), method, options.hand)
    meta = {
        "object": name,
        "view": view,
        "view_set": record["view_set"],
        "method": method,
        "frame": TABLE_GRASP_FRAME if table else GRASP_FRAME,
        "T_world_cam": T_world_cam.tolist(),
        "planned_on": record["files"][method],
        "executed_on": record["files"]["truth"],
        "table": table,
        "plan_seed": seed,
        "plan_stats": {
            "evaluations": result.stats.evaluations,
            "simulated": result.stats.simulated,
            "seconds": result.stats.seconds,
            "cancelled": result.stats.cancelled,
        },
    }
    robust = None if scores is None else robust_entries(scores, [g.lift for g in grasps])
    if robust is not None:
        meta["robustness"] = robust
    if wider is not None:
        meta["wider"] = {
            "planned_on": envelope_rel,
            "first": len(result.grasps),
            "below": below,
            "plan_stats": {"evaluations": wider.stats.evaluations, "seconds": wider.stats.seconds},
        }
    atomic_write(out / rel, grasps_to_json(grasps, executions, meta))
    base = {"object": name, "view": view, "view_set": record["view_set"], "method": method, "hand": options.hand}
    rows = grasp_rows(base, grasps, executions, robust, first_round=len(result.grasps))
    entry.update(
        file=rel,
        n=len(result.grasps),
        n_wider=0 if wider is None else len(wider.grasps),
        **grasp_means(rows[: len(result.grasps)]),
        seconds_plan=t1 - t0,
        seconds_execute=t2 - t1,
    )
    if robust is not None:
        # As for the planner's best grasp, a view without grasps counts as a failed lift.
        entry["lift_success_best_robust"] = next((r["lift_success"] for r in rows if r["robust_rank"] == 0), 0.0)
        entry["seconds_robust"] = t3 - t2
    return entry


def load_samples(path: Path):
    """A view's saved sample completions (:func:`records.samples_file`): ``(samples, frame, level)``,
    the (n, 40, 40, 40) probabilities, their :class:`~shapeviewer.completion.voxel.GridFrame` and the level the
    network's meshes are taken at (files written before it was saved: ``MESH_LEVEL``)."""
    from ..completion.reconstruct import MESH_LEVEL
    from ..completion.voxel import GridFrame

    with np.load(path) as saved:
        frame = GridFrame(saved["center"], float(saved["voxel_size"]))
        level = float(saved["mesh_level"]) if "mesh_level" in saved else MESH_LEVEL
        return saved["samples"], frame, level


def write_envelope(out_dir, record: dict) -> str:
    """Write a view's grasp envelope (:func:`grasp.robust.envelope_mesh` of its saved sample
    completions, camera frame) to ``out_dir`` and return its path there (:func:`records.envelope_file`).

    Raises:
        FileNotFoundError: the view has no saved sample completions.
        EmptyCompletionError: nothing in their mean answer is above the envelope's level.
    """
    from ..grasp.robust import envelope_mesh

    stem = view_stem(record["object"], int(record["view"]))
    samples, frame, _ = load_samples(Path(out_dir) / samples_file(stem))
    rel = envelope_file(stem)
    envelope_mesh(samples, frame, np.eye(4)).export(Path(out_dir) / rel)
    return rel


def sample_completions(samples: Path, T_world_cam: np.ndarray, *, hedge: float | None = None) -> list:
    """A view's sample completions (the file ``samples``, see :func:`records.samples_file`) meshed
    as the robust ranking meshes them (:func:`~shapeviewer.grasp.robust.sample_meshes`; ``hedge``
    None: its default) and moved to the grasp world by ``T_world_cam`` (metres)."""
    from ..grasp.robust import HEDGE, sample_meshes

    grids, frame, level = load_samples(samples)
    return sample_meshes(grids, frame, T_world_cam, level=level, hedge=HEDGE if hedge is None else hedge)


def robust_entries(scores, lifts) -> list[dict]:
    """Each grasp's robustness (``scores``, :func:`~shapeviewer.grasp.robust.robustness`) and its
    rank by it after the planner's ``lifts`` (0 first), as a grasp file's ``meta["robustness"]``
    (:func:`records.grasp_rows`)."""
    from ..grasp.robust import rank_robust

    rank = {i: k for k, i in enumerate(rank_robust(scores, lifts))}
    return [{"rank": rank[i], **dataclasses.asdict(s)} for i, s in enumerate(scores)]


def pending_grasps(record: dict, options: GraspOptions) -> list[str]:
    """Methods of ``options`` still to grasp on this view: no entry for (method, hand), one with an
    error (retried: it may have been a crash), or, when the options rank by robustness, one of
    :data:`ROBUST_METHODS` grasped without that ranking."""
    done = {
        (g["method"], g["hand"])
        for g in record.get("grasps", [])
        if not g["error"] and (g.get("robust", False) or not (options.robust and g["method"] in ROBUST_METHODS))
    }
    return [m for m in options.methods if (m, options.hand) not in done]


# ----------------------------------------------------------------------------------------------
# One view's work (shared by the runner and the sample store)


def complete_view(out_dir, name: str, view: int, view_set: str, seed: int, completer) -> dict:
    """Compute and save a view's completions; returns its record."""
    rows = evaluate_view(name, view, completer, out_dir, seed=seed, view_set=view_set)
    record = view_record(out_dir, name, view, view_set, seed, rows)
    save_view(out_dir, record)
    return record


def grasp_and_save(out_dir, record: dict, method: str, options: GraspOptions) -> None:
    """Grasp one method of a view and save the record (an interrupted run loses at most this method)."""
    set_grasp_entry(record, grasp_view(out_dir, record, method, options))
    save_view(out_dir, record)


# ----------------------------------------------------------------------------------------------
# Runner

# Per worker process: the run's weights and the CNN, loaded on first use (a grasp-only rerun never needs it).
_WORKER: dict = {}


def _init_worker(weights, threads: int) -> None:
    import torch

    torch.set_num_threads(threads)
    _WORKER.clear()
    _WORKER.update(weights=weights, threads=threads)


def _completer():
    if "completer" not in _WORKER:
        from ..completion.model import load_completer

        _WORKER["completer"] = load_completer(_WORKER.get("weights"))
    return _WORKER["completer"]


def _run_one(task) -> str:
    """One view: its completions unless saved, then each pending grasp method."""
    name, view, view_set, out_dir, seed, options = task
    record = load_view(out_dir, name, view, seed)
    if record is None:
        record = complete_view(out_dir, name, view, view_set, seed, _completer())
    if options is not None:
        for method in pending_grasps(record, options):
            grasp_and_save(out_dir, record, method, options)
    return name


def _run_ray_task(task, weights) -> str:
    """:func:`_run_one` in a Ray worker: torch gets the CPUs Ray assigned to the task; the worker
    process keeps its CNN for the next task."""
    import ray

    threads = max(1, int(ray.get_runtime_context().get_assigned_resources().get("CPU", 1)))
    if (_WORKER.get("weights"), _WORKER.get("threads")) != (weights, threads):
        _init_worker(weights, threads)
    return _run_one(task)


def run_views(
    out_dir,
    views: list[tuple[str, int, str]],
    *,
    seed: int = 0,
    weights=None,
    workers: int | None = None,
    backend: str = "process",
    grasps: GraspOptions | None = None,
    progress: bool = True,
) -> int:
    """Do the pending work of ``views`` (``(object, view, view_set)``): completions of views without
    a record, then the grasp methods of ``grasps`` not yet done. Returns the number of views that
    had work.

    ``backend``: ``process`` (``workers`` local processes, default all cores; 1 runs in this
    process) or ``ray`` (a Ray cluster: ``RAY_ADDRESS``, or a local one on ``workers`` CPUs; one
    task per view, a CPU each). Both give the same records.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r} (use 'process' or 'ray')")
    out = Path(out_dir).resolve()  # workers may start in another folder

    def needs_work(n: str, v: int) -> bool:
        record = load_view(out, n, v, seed)
        return record is None or (grasps is not None and bool(pending_grasps(record, grasps)))

    todo = [(n, v, s, str(out), seed, grasps) for n, v, s in views if needs_work(n, v)]
    if not todo:
        return 0
    from tqdm import tqdm

    bar = tqdm(total=len(todo), desc="evaluate", unit="view", disable=not progress)
    try:
        if backend == "ray":
            import ray

            ray_init(workers)
            remote = ray.remote(_run_ray_task)
            weights = None if weights is None else str(Path(weights).resolve())
            pending = [remote.remote(t, weights) for t in todo]
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                ray.get(done[0])  # raises a task's error here
                bar.update()
            return len(todo)
        workers = max(1, min(workers or os.cpu_count() or 1, len(todo)))
        threads = max(1, (os.cpu_count() or 1) // workers)
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
        return len(todo)
    finally:
        bar.close()


def write_tables(out_dir, views: list[tuple[str, int, str]], seed: int, n_per_set: int | None = None) -> dict:
    """Tabulate the records of ``views``: ``rows.csv``, ``grasp_rows.csv`` (when any view has
    grasp entries), ``tables.md`` and ``tables.csv``. Returns ``{"rows", "summary", "grasp_rows",
    "grasp_summary", "tables_md"}`` (:func:`tables.summarize`, :func:`tables.summarize_grasps`)."""
    out = Path(out_dir)
    records = [record for n, v, _ in views if (record := load_view(out, n, v, seed)) is not None]
    rows = [r for rec in records for r in rec["rows"]]
    atomic_write(out / "rows.csv", csv_text(ROW_FIELDS, rows))
    summary = summarize(rows)
    g_rows = load_grasp_rows(out, records)
    g_summary = summarize_grasps(records, g_rows)
    md = completion_tables_markdown(summary, n_per_set=n_per_set, seed=seed) + kind_table_markdown(rows)
    if g_summary:
        atomic_write(out / "grasp_rows.csv", csv_text(GRASP_ROW_FIELDS, g_rows))
        md += grasp_tables_markdown(g_summary) + kind_grasp_table_markdown(records, rows, g_rows)
    atomic_write(out / "tables.md", md)
    write_tables_csv(summary, out / "tables.csv", g_summary)
    return {"rows": rows, "summary": summary, "grasp_rows": g_rows, "grasp_summary": g_summary, "tables_md": md}


def evaluate(
    out_dir: str | Path,
    *,
    n_per_set: int = 50,
    seed: int = 0,
    weights=None,
    workers: int | None = None,
    backend: str = "process",
    progress: bool = True,
    grasps: GraspOptions | bool | None = None,
    views: str = "paper",
) -> dict:
    """Run the test set (resumable), then write ``rows.csv``, ``tables.md`` and ``tables.csv``
    (and with ``grasps``, ``grasp_rows.csv`` and Tables IV/V).

    ``views``: ``paper`` (the paper's three view sets) or ``tabletop`` (:mod:`.viewsets`), ``n_per_set``
    of each. ``grasps``: True or a :class:`GraspOptions` adds the grasp stage; finished completions
    are read from ``meshes/``, never recomputed. ``backend`` and ``workers``: see :func:`run_views`.
    Returns ``{"computed", "skipped", "rows", "summary", "grasp_rows", "grasp_summary",
    "tables_md", "seconds"}`` (:func:`write_tables`); ``computed`` counts views with any work done.
    """
    options = GraspOptions() if grasps is True else (grasps or None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sample = sample_views(n_per_set, seed, views)
    upgrade_old_views(out, sample, seed)
    computed = run_views(
        out, sample, seed=seed, weights=weights, workers=workers, backend=backend, grasps=options, progress=progress
    )
    return {
        "computed": computed,
        "skipped": len(sample) - computed,
        **write_tables(out, sample, seed, n_per_set),
        "seconds": time.perf_counter() - t0,
    }
