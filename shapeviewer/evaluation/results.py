"""The results store: the index and read API of a folder written by ``shapeviewer evaluate``.

The folder's files and their formats are :mod:`.records`' (view records in ``views/``, meshes in
the camera optical frame in metres, grasp files); :mod:`.results_index` keeps ``<root>/index.sqlite``
(WAL mode), an SQLite index of the view files for browsing. This module reads that index, the
tables it sums up (:mod:`.tables`), and meshes and points back.

:meth:`ResultsStore.sync` ingests new and changed view files by (mtime, size), so a store can be
read while an evaluation is still adding views, and extended by later runs. A file that cannot be
read (half written, corrupt) is skipped with a warning and retried when it changes. The index is
a cache of the files: deleting ``index.sqlite`` loses nothing.

The read API returns plain dataclasses and dicts; this module never imports viser.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Literal

import numpy as np

from ..sim import catalogue
from . import tables
from .methods import Method, method_rank
from .records import (
    GRASP_FIELDS,
    HIGHER_IS_BETTER,
    METRIC_TITLES,
    METRICS,
    ROW_FIELDS,
    CompletionRow,
    Metric,
    load_grasp_rows,
)
from .results_index import INDEX_NAME, connect, from_db, open_index, sync_index
from .summaries import CompletionResult, GraspSummary, ObjectSummary, SyncReport, ViewInfo
from .viewsets import Split

log = logging.getLogger(__name__)

__all__ = ["HIGHER_IS_BETTER", "INDEX_NAME", "METRIC_TITLES", "Order", "ResultsStore", "read_mesh", "read_points"]

# How :meth:`ResultsStore.objects` orders the index.
Order = Literal["name", "worst", "best", "views"]
_VIEW_COLUMNS = "object, view, view_set, seed, file, truth, points"  # ViewInfo's fields


# ----------------------------------------------------------------------------------------------
# The store


class ResultsStore:
    """A results folder and its SQLite index (``<root>/index.sqlite``, WAL mode; :mod:`.results_index`).

    Safe to use from several threads and processes: every call opens its own connection, writes
    happen in one transaction per view file, and WAL lets readers go on while a sync writes.

    Args:
        root: the results folder (created when missing).
        sync: ingest the view files now (otherwise call :meth:`sync`).
    """

    def __init__(self, root: str | Path, sync: bool = True) -> None:
        self.root = Path(root).expanduser().resolve()
        self.root.mkdir(parents=True, exist_ok=True)
        self.index_path = self.root / INDEX_NAME
        self._local = threading.local()
        self._sync_lock = threading.Lock()  # one sync at a time per process (SQLite serialises processes)
        self._catalogue_done = False
        open_index(self.index_path)
        if sync:
            self.sync()

    def _read(self, sql: str, args: Iterable = ()) -> list[tuple]:
        # One read connection per thread (sqlite3 connections stay in their thread); in autocommit
        # mode every query is its own WAL read transaction, so it sees the latest committed sync.
        db = getattr(self._local, "db", None)
        if db is None:
            db = self._local.db = connect(self.index_path)
        return db.execute(sql, tuple(args)).fetchall()

    def sync(self) -> SyncReport:
        """Ingest new and changed ``views/*.json`` (by mtime and size) and forget deleted ones
        (:func:`.results_index.sync_index`)."""
        with self._sync_lock:
            db = connect(self.index_path)
            try:
                report = sync_index(db, self.root, with_catalogue=not self._catalogue_done)
                self._catalogue_done = True
            finally:
                db.close()
            if report.changed or report.skipped:
                log.info(
                    "results %s: %d added, %d updated, %d removed, %d skipped",
                    self.root,
                    report.added,
                    report.updated,
                    report.removed,
                    len(report.skipped),
                )
            return report

    def generation(self) -> int:
        """A number that changes whenever any store on this folder (any thread or process) changed the
        views: readers compare it to know when to re-read."""
        rows = self._read("SELECT value FROM meta WHERE key='generation'")
        return int(rows[0][0]) if rows else 0

    # ------------------------------------------------------------------------------------------
    # Reading: objects, views, completions, grasps

    def counts(self) -> dict[str, int]:
        """``{"objects": with results, "views", "completions", "grasps", "skipped": unreadable files}``."""
        ((objects, views),) = self._read("SELECT COUNT(DISTINCT object), COUNT(*) FROM views")
        ((completions,),) = self._read("SELECT COUNT(*) FROM completions")
        ((grasps,),) = self._read("SELECT COUNT(*) FROM grasps")
        ((skipped,),) = self._read("SELECT COUNT(*) FROM files WHERE status='bad'")
        return {"objects": objects, "views": views, "completions": completions, "grasps": grasps, "skipped": skipped}

    def skipped_files(self) -> list[tuple[str, str]]:
        """(path, why) of view files that could not be read at their current version."""
        return [(p, m) for p, m in self._read("SELECT path, message FROM files WHERE status='bad' ORDER BY path")]

    def objects(
        self,
        search: str = "",
        split: Split | None = None,
        with_results: bool = True,
        method: Method = "Ours-fast",
        metric: Metric = "jaccard",
        order: Order = "name",
        metric_range: tuple[float, float] | None = None,
    ) -> list[ObjectSummary]:
        """The object index, filtered and ordered.

        Args:
            search: case-insensitive substring of the name.
            split: ``train`` or ``holdout_model`` (None: both).
            with_results: only objects that have at least one view with results.
            method, metric: the mean that ``order`` and ``metric_range`` use.
            order: ``name``, ``worst`` (worst mean of ``metric`` first: lowest Jaccard, highest
                distances), ``best``, or ``views`` (most views first). Objects without a mean go last.
            metric_range: keep objects whose mean lies in [lo, hi] (objects without one are dropped).
        """
        if metric not in HIGHER_IS_BETTER:
            raise ValueError(f"unknown metric {metric!r}; choose one of {tuple(HIGHER_IS_BETTER)}")
        means: dict[str, dict[str, dict[str, float]]] = {}
        failed: dict[str, dict[str, int]] = {}
        cols = ", ".join(f"AVG(CASE WHEN error='' THEN {k} END)" for k in (*METRICS, "seconds"))
        for name, m, n_failed, *vals in self._read(
            f"SELECT object, method, SUM(error != ''), {cols} FROM completions GROUP BY object, method"
        ):
            means.setdefault(name, {})[m] = dict(zip((*METRICS, "seconds"), map(from_db, vals)))
            failed.setdefault(name, {})[m] = int(n_failed or 0)
        n_views = dict(self._read("SELECT object, COUNT(*) FROM views GROUP BY object"))
        needle = search.strip().lower()
        out = []
        for name, sp, source, ex, ey, ez in self._read(
            "SELECT name, split, source, extent_x, extent_y, extent_z FROM objects ORDER BY name"
        ):
            if needle and needle not in name.lower():
                continue
            if split and sp != split:
                continue
            if with_results and not n_views.get(name):
                continue
            o = ObjectSummary(
                name,
                sp,
                source,
                (from_db(ex), from_db(ey), from_db(ez)),
                int(n_views.get(name, 0)),
                means.get(name, {}),
                failed.get(name, {}),
            )
            if metric_range is not None:
                v = o.mean(method, metric)
                if math.isnan(v) or not metric_range[0] <= v <= metric_range[1]:
                    continue
            out.append(o)
        if order in ("worst", "best"):
            sign = 1.0 if HIGHER_IS_BETTER[metric] == (order == "worst") else -1.0
            out.sort(
                key=lambda o: (
                    math.isnan(o.mean(method, metric)),
                    0.0 if math.isnan(o.mean(method, metric)) else sign * o.mean(method, metric),
                    o.name,
                )
            )
        elif order == "views":
            out.sort(key=lambda o: (-o.views, o.name))
        elif order != "name":
            raise ValueError(f"unknown order {order!r}; use name, worst, best or views")
        return out

    def object(self, name: str) -> ObjectSummary:
        found = [o for o in self.objects(search=name, with_results=False) if o.name == name]
        if not found:
            raise KeyError(f"no object {name!r} in the results store {self.root}")
        return found[0]

    def views(self, name: str) -> list[ViewInfo]:
        """The views of an object that have results, by view number."""
        return [
            ViewInfo(*r) for r in self._read(f"SELECT {_VIEW_COLUMNS} FROM views WHERE object=? ORDER BY view", (name,))
        ]

    def view(self, name: str, view: int) -> ViewInfo:
        rows = self._read(f"SELECT {_VIEW_COLUMNS} FROM views WHERE object=? AND view=?", (name, int(view)))
        if not rows:
            raise KeyError(f"no results for {name!r} view {view} in {self.root}")
        return ViewInfo(*rows[0])

    def completions(self, name: str, view: int) -> list[CompletionResult]:
        """Each method's completion of a view, in :data:`.methods.ALL_METHODS` order."""
        rows = self._read(
            f"SELECT method, {', '.join(METRICS)}, seconds, error, mesh, prior FROM completions"
            " WHERE object=? AND view=?",
            (name, int(view)),
        )
        out = [
            CompletionResult(
                m, **dict(zip((*METRICS, "seconds"), map(from_db, vals))), error=err or "", mesh=mesh, prior=prior or ""
            )
            for m, *vals, err, mesh, prior in rows
        ]
        return sorted(out, key=lambda c: (method_rank(c.method), c.method))

    def grasps(self, name: str, view: int) -> list[GraspSummary]:
        """Grasp summaries of a view (one per method and hand), in :data:`.methods.ALL_METHODS` order."""
        rows = self._read(
            f"SELECT method, hand, file, {', '.join(GRASP_FIELDS)}, error FROM grasps WHERE object=? AND view=?",
            (name, int(view)),
        )
        out = [
            GraspSummary(m, h, f, int(n or 0), **dict(zip(GRASP_FIELDS[1:], map(from_db, vals))), error=err or "")
            for m, h, f, n, *vals, err in rows
        ]
        return sorted(out, key=lambda g: (method_rank(g.method), g.method, g.hand))

    def rows(self, names: Iterable[str] | None = None) -> list[CompletionRow]:
        """The completion rows of the objects ``names`` (None: all), as the evaluation writes them
        (NaN metrics on failure), by object, view and method. ``kind`` is the catalogue's shape kind;
        ``sensor`` is not indexed ("")."""
        sql = (
            f"SELECT c.object, c.view, v.view_set, c.method, {', '.join('c.' + k for k in METRICS)}, c.seconds, "
            "c.error, c.prior FROM completions c JOIN views v ON v.object=c.object AND v.view=c.view"
        )
        wanted = None if names is None else set(names)
        out = []
        for r in self._read(sql + " ORDER BY c.object, c.view"):
            if wanted is not None and r[0] not in wanted:
                continue
            name, view, view_set, method, *vals, error, prior = r
            out.append(
                CompletionRow.from_json(
                    {
                        "object": name,
                        "view": view,
                        "view_set": view_set,
                        "method": method,
                        "kind": catalogue.shape_kind(name),
                        **dict(zip((*METRICS, "seconds"), map(from_db, vals))),
                        "error": error,
                        "prior": prior,
                    }
                )
            )
        out.sort(key=lambda r: (r.object, r.view, method_rank(r.method)))
        return out

    # ------------------------------------------------------------------------------------------
    # Summaries (paper Tables I-V)

    def summary(self) -> dict:
        """Per view set and method means of the completion rows (:func:`tables.summarize`)."""
        return tables.summarize(self.rows())

    def grasp_summary(self) -> dict:
        """``{view_set: {method: {"n": views, "failed": views, <means>}}}`` over views with grasps:
        ``n`` views whose grasp stage ran, ``failed`` views where it failed, and the means over the
        ``n`` views of their per-view means (``GRASP_FIELDS`` but ``n``). Quick (the index only);
        :meth:`grasp_tables_summary` pools the grasps instead, as the evaluation's tables do."""
        out: dict = {}
        means = GRASP_FIELDS[1:]
        cols = ", ".join(f"AVG(CASE WHEN g.error='' THEN g.{k} END)" for k in means)
        for view_set, method, n, failed, *vals in self._read(
            f"SELECT v.view_set, g.method, SUM(g.error=''), SUM(g.error!=''), {cols} FROM grasps g "
            "JOIN views v ON v.object=g.object AND v.view=g.view GROUP BY v.view_set, g.method"
        ):
            out.setdefault(view_set, {})[method] = {
                "n": int(n or 0),
                "failed": int(failed or 0),
                **dict(zip(means, map(from_db, vals))),
            }
        return out

    def grasp_tables_summary(self) -> dict:
        """Tables IV/V cells (:func:`tables.summarize_grasps`) over every grasp in the store, as
        ``shapeviewer evaluate`` computes them: pooled over the grasps, read from the grasp files."""
        return tables.summarize_grasps(*self._grasp_records())

    def _grasp_records(self) -> tuple[list[dict], list[dict]]:
        """Every view with grasp entries, as records with ``object``, ``view``, ``view_set`` and
        ``grasps``, and their grasps (:func:`records.load_grasp_rows`, read from the grasp files)."""
        records: dict[tuple[str, int], dict] = {}
        for name, view, view_set, method, hand, gfile, n, seconds_plan, error in self._read(
            "SELECT g.object, g.view, v.view_set, g.method, g.hand, g.file, g.n, g.seconds_plan, g.error "
            "FROM grasps g JOIN views v ON v.object=g.object AND v.view=g.view ORDER BY g.object, g.view"
        ):
            rec = records.setdefault((name, view), {"object": name, "view": view, "view_set": view_set, "grasps": []})
            rec["grasps"].append(
                {
                    "method": method,
                    "hand": hand,
                    "file": gfile or "",
                    "n": int(n or 0),
                    "seconds_plan": from_db(seconds_plan),
                    "error": error or "",
                }
            )
        found = list(records.values())
        return found, load_grasp_rows(self.root, found)

    def tables_markdown(self) -> str:
        """The evaluation's ``tables.md`` for the whole store: Tables I-III, per shape kind, and
        Tables IV/V (also per shape kind) when grasp results exist, with the paper's figures
        (:mod:`.tables`)."""
        rows = self.rows()
        md = tables.completion_tables_markdown(tables.summarize(rows)) + tables.kind_table_markdown(rows)
        records, grasp_rows = self._grasp_records()
        grasps = tables.summarize_grasps(records, grasp_rows)
        if not grasps:
            return md + "\n_No grasp results in this store (Tables IV and V)._\n"
        return md + tables.grasp_tables_markdown(grasps) + tables.kind_grasp_table_markdown(records, rows, grasp_rows)

    # ------------------------------------------------------------------------------------------
    # Files

    def path(self, rel: str) -> Path:
        """An absolute path inside the store (refuses paths that leave the root)."""
        p = (self.root / rel).resolve()
        if not p.is_relative_to(self.root):
            raise ValueError(f"{rel!r} is outside the results store")
        return p

    def mesh_file(self, name: str, view: int, kind: str) -> Path:
        """The file of ``kind`` (truth, points or a method) of a view. KeyError when there is none."""
        if kind in ("truth", "points"):
            rel = getattr(self.view(name, view), kind)
        else:
            rel = next((c.mesh for c in self.completions(name, view) if c.method == kind), None)
        if not rel:
            raise KeyError(f"{name} view {view} has no {kind} file")
        return self.path(rel)

    def load_mesh(self, name: str, view: int, kind: str):
        """A view's mesh ``kind`` (truth or a method), full resolution, camera optical frame, metres."""
        return read_mesh(self.mesh_file(name, view, kind))

    def load_points(self, name: str, view: int) -> np.ndarray:
        """The partial view (N, 3), camera optical frame, metres."""
        return read_points(self.mesh_file(name, view, "points"))

    def T_cam_obj(self, name: str, view: int) -> np.ndarray:
        """4x4 pose of the object frame (bounding-box centre, catalogue axes) in the camera frame.

        The evaluation renders each view as the training data is (:func:`generate.view_pose` of
        name, view and seed), so the pose follows from those three numbers.
        """
        from ..training.generate import view_pose

        info = self.view(name, view)
        return view_pose(name, view, 0 if info.seed is None else info.seed)

    def capture(self, name: str, view: int):
        """The view as a :class:`~shapeviewer.perception.capture.Capture` the live pipeline can complete.

        ``points_cam`` are the saved partial points (camera optical frame, metres). The world frame
        is the object's frame with its lowest point on z = 0 (the evaluation renders the object
        floating, without a table; this puts a virtual floor under it), and ``objects`` holds the
        ground truth there, so the viewer draws the capture upright with its sensor.
        """
        from ..perception.camera import Intrinsics
        from ..perception.capture import Capture, SceneObject

        points = self.load_points(name, view)
        T_obj_cam = np.linalg.inv(self.T_cam_obj(name, view))
        truth_obj = self.load_mesh(name, view, "truth")
        truth_obj.apply_transform(T_obj_cam)
        T_world_obj = np.eye(4)
        T_world_obj[2, 3] = -float(truth_obj.vertices[:, 2].min())
        return Capture(
            points_cam=points,
            intrinsics=Intrinsics.kinect(),
            T_world_cam=T_world_obj @ T_obj_cam,
            source=str(self.mesh_file(name, view, "points")),
            objects=[SceneObject(name, truth_obj, T_world_obj)],
        )

    def grasp_set(self, name: str, view: int, method: str, hand: str | None = None):
        """The grasps planned on ``method``'s completion (:class:`grasp.export.GraspSet`), or None."""
        from ..grasp.serialize import grasps_from_json

        for g in self.grasps(name, view):
            if g.method == method and (hand is None or g.hand == hand) and g.file:
                return grasps_from_json(self.path(g.file).read_bytes())
        return None

    # ------------------------------------------------------------------------------------------
    # CSV exports (rendered by .tables; kept as methods for shapeviewer.viewer.dataset)

    def view_csv(self, name: str, view: int) -> str:
        return tables.view_csv(self.view(name, view), self.completions(name, view), self.grasps(name, view))

    def objects_csv(self, objects: Iterable[ObjectSummary]) -> str:
        return tables.objects_csv(objects)

    def rows_csv(self, names: Iterable[str] | None = None) -> str:
        return tables.csv_text(ROW_FIELDS, (r.to_json() for r in self.rows(names)))


def read_mesh(path: Path):
    """A triangle mesh from a PLY file, as written (no merging or repair; a few times quicker than
    ``trimesh.load``, which goes through a scene)."""
    import trimesh
    from trimesh.exchange.ply import load_ply

    with open(path, "rb") as f:
        data = load_ply(f)
    if data.get("faces") is None or len(data["faces"]) == 0:
        raise ValueError(f"{path.name}: no triangles")
    return trimesh.Trimesh(vertices=data["vertices"], faces=data["faces"], process=False)


def read_points(path: Path) -> np.ndarray:
    """(N, 3) float64 vertices of a PLY point cloud."""
    from trimesh.exchange.ply import load_ply

    with open(path, "rb") as f:
        return np.asarray(load_ply(f)["vertices"], dtype=np.float64).reshape(-1, 3)
