"""Running the evaluation: per-view completions (the paper's Tables I-III), the grasp stage (Tables IV
and V), and the runner over local processes or a Ray cluster
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

Grasps (``grasps=True`` or a :class:`~.grasping.GraspOptions`): the grasp stage of each view,
in :mod:`.grasping` (planned on the completions, executed on the true mesh, ranked by the app's pick
over the CNN's sample completions).

Outputs in ``out_dir`` (layout: :mod:`.records`): one record per view in ``views/`` (the run
resumes by skipping finished work: a view's completions, then each grasp method), its meshes and
grasp files, ``rows.csv`` (completion rows), ``grasp_rows.csv`` (one row per executed grasp) and
``tables.md`` / ``tables.csv`` (:mod:`.tables`), and ``settings.json``: the settings that shaped its
entries (:func:`run_settings`). A run resumes a folder only under the same settings; otherwise it is
refused before any work (:class:`SettingsMismatch`), so a folder never mixes entries of two settings.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import multiprocessing as mp
import os
import time
import traceback
from pathlib import Path

import numpy as np

from ..errors import ShapeviewerError
from ..fileio import atomic_write
from ..runtime.backends import BACKENDS, ray_init
from ..runtime.processes import die_with_parent
from ..sim import catalogue

# The grasp stage: what callers of this module have always imported from it.
from .grasping import GRASP_FRAME as GRASP_FRAME
from .grasping import GRASP_METHODS as GRASP_METHODS
from .grasping import ROBUST_METHODS as ROBUST_METHODS
from .grasping import T_WORLD_CAM as T_WORLD_CAM
from .grasping import TABLE_GRASP_FRAME as TABLE_GRASP_FRAME
from .grasping import GraspOptions as GraspOptions
from .grasping import grasp_means as grasp_means
from .grasping import grasp_meshes as grasp_meshes
from .grasping import grasp_view as grasp_view
from .grasping import grasp_world as grasp_world
from .grasping import load_samples as load_samples
from .grasping import pending_grasps as pending_grasps
from .grasping import plan_seed as plan_seed
from .grasping import robust_entries as robust_entries
from .grasping import sample_completions as sample_completions
from .grasping import write_envelope as write_envelope
from .records import (
    GRASP_ROW_FIELDS,
    METHODS,
    METRICS,
    ROW_FIELDS,
    completion_rows,
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
from .viewsets import Views, render_view, sample_views

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


def _init_worker(weights, threads: int, parent: int | None = None) -> None:
    """A worker process's start (``parent``: the run's process id, None in the run's own process):
    it dies with the run, even one killed with SIGKILL, rather than go on writing into the
    results folder (:func:`~shapeviewer.runtime.processes.die_with_parent`)."""
    import torch

    if parent is not None:
        die_with_parent(parent)
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
            # Made by this thread, which outlives the pool: the workers' parent-death signal holds for the run.
            initargs = (weights, threads, os.getpid())
            with mp.get_context("spawn").Pool(workers, initializer=_init_worker, initargs=initargs) as pool:
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
    rows = [r for rec in records for r in completion_rows(rec)]
    atomic_write(out / "rows.csv", csv_text(ROW_FIELDS, (r.to_json() for r in rows)))
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


# ----------------------------------------------------------------------------------------------
# The settings of a results folder

SETTINGS_FILE = "settings.json"
# Each recorded setting: its name on the command line, for messages.
_OPTION_NAMES = {
    "weights": "--weights",
    "seed": "--seed",
    "views": "--views",
    "n_grasps": "--n-grasps",
    "budget_seconds": "--grasp-budget",
    "plan_settings": "the grasp planner's search sizes (GraspOptions.settings)",
    "widen_below": "--widen-below",
}


class SettingsMismatch(ShapeviewerError, ValueError):
    """A results folder made under other settings than the run's: resuming would mix entries of both."""


def weights_identity(weights) -> str:
    """What names a CNN in a folder's settings: the SHA-256 of its weights file (so that a file
    moved or copied is the same CNN), or ``untrained`` when the shipped weights are absent."""
    from ..completion.model import DEFAULT_WEIGHTS

    path = Path(weights) if weights is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        if weights is None:
            return "untrained"
        raise FileNotFoundError(f"weights file not found: {path}")
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return f"{path.name} sha256:{digest.hexdigest()[:16]}"


def run_settings(*, seed: int, weights, views: Views, grasps: GraspOptions | None) -> dict:
    """The settings that shape a run's entries, as ``settings.json`` records them.

    ``completion``: the CNN (:func:`weights_identity`), the seed and the view kind (a view's record
    is found by object and view only). ``grasps`` (a grasp run only): grasps planned per view, the
    planning time limit and the planner's search sizes. ``robust`` (a robust run only): the share
    below which the robust ranking widens its search. The hand and the methods are not among them:
    entries are kept per method and hand, so another of either adds entries.
    """
    settings: dict = {"completion": {"weights": weights_identity(weights), "seed": int(seed), "views": views}}
    if grasps is not None:
        from ..grasp.plan import PlanSettings
        from ..grasp.robust import WIDEN_BELOW

        settings["grasps"] = {
            "n_grasps": int(grasps.n_grasps),
            "budget_seconds": grasps.budget_seconds,
            "plan_settings": dataclasses.asdict(grasps.settings or PlanSettings()),
        }
        if grasps.robust:
            below = WIDEN_BELOW if grasps.widen_below is None else grasps.widen_below
            settings["robust"] = {"widen_below": float(below)}
    return settings


def _shown(key: str, value) -> str:
    if value is None:
        return "none" if key == "budget_seconds" else "the default"
    if isinstance(value, dict):
        return " ".join(f"{k}={v}" for k, v in value.items())
    return str(value)


def check_settings(out_dir: str | Path, settings: dict) -> dict:
    """``settings`` merged into what the results folder recorded, to be saved once the run starts
    (:func:`save_settings`).

    A folder without a record (new, or made before records were kept) takes the run's. A part
    the folder lacks (its first grasp or robust run) is added.

    Raises:
        SettingsMismatch: a setting differs from the folder's; the message names the option, both
            values, and how to resume or start afresh.
    """
    path = Path(out_dir) / SETTINGS_FILE
    try:
        recorded = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError) as e:
        raise SettingsMismatch(
            f"{path}: unreadable ({e}); remove it only if the folder's results are all of this run's settings"
        ) from None
    merged = {**recorded}
    for part, values in settings.items():
        old = recorded.get(part)
        if not isinstance(old, dict):
            merged[part] = values
            continue
        for key, value in values.items():
            if key in old and old[key] != value:
                option = _OPTION_NAMES.get(key, key)
                raise SettingsMismatch(
                    f"{out_dir}: its results were made with {option} {_shown(key, old[key])}, and this run asks for "
                    f"{_shown(key, value)}: resuming would mix the two. Run again with {option} "
                    f"{_shown(key, old[key])} to resume it, or give a new --out folder"
                )
        merged[part] = {**old, **values}
    return merged


def save_settings(out_dir: str | Path, settings: dict) -> None:
    """Write a folder's ``settings.json`` (see :func:`check_settings`)."""
    atomic_write(Path(out_dir) / SETTINGS_FILE, json.dumps(settings, indent=1))


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
    views: Views = "paper",
) -> dict:
    """Run the test set (resumable), then write ``rows.csv``, ``tables.md`` and ``tables.csv``
    (and with ``grasps``, ``grasp_rows.csv`` and Tables IV/V).

    ``views``: ``paper`` (the paper's three view sets) or ``tabletop`` (:mod:`.viewsets`), ``n_per_set``
    of each. ``grasps``: True or a :class:`GraspOptions` adds the grasp stage; finished completions
    are read from ``meshes/``, never recomputed. ``backend`` and ``workers``: see :func:`run_views`.
    Returns ``{"computed", "skipped", "rows", "summary", "grasp_rows", "grasp_summary",
    "tables_md", "seconds"}`` (:func:`write_tables`); ``computed`` counts views with any work done.

    Raises:
        SettingsMismatch: ``out_dir`` holds results made under other settings (:func:`check_settings`).
    """
    options = GraspOptions() if grasps is True else (grasps or None)
    out = Path(out_dir)
    settings = check_settings(out, run_settings(seed=seed, weights=weights, views=views, grasps=options))
    out.mkdir(parents=True, exist_ok=True)
    first = not (out / SETTINGS_FILE).exists()
    save_settings(out, settings)  # before any entry: a run killed midway leaves its entries' settings
    t0 = time.perf_counter()
    sample = sample_views(n_per_set, seed, views)
    upgrade_old_views(out, sample, seed)
    try:
        computed = run_views(
            out, sample, seed=seed, weights=weights, workers=workers, backend=backend, grasps=options, progress=progress
        )
    except BaseException:
        if first and not any((out / "views").glob("*.json")):  # nothing made: the folder stays as it was
            (out / SETTINGS_FILE).unlink(missing_ok=True)
        raise
    return {
        "computed": computed,
        "skipped": len(sample) - computed,
        **write_tables(out, sample, seed, n_per_set),
        "seconds": time.perf_counter() - t0,
    }
