"""The results store: the index and read API of a folder written by ``shapeviewer evaluate``.

The folder's files and their formats are :mod:`.records`' (view records in ``views/``, meshes in
the camera optical frame in metres, grasp files); this module adds ``<root>/index.sqlite`` (WAL
mode), an SQLite index of the view files for browsing, and reads meshes and points back.

:meth:`ResultsStore.sync` ingests new and changed view files by (mtime, size), so a store can be
read while an evaluation is still adding views, and extended by later runs. A file that cannot be
read (half written, corrupt) is skipped with a warning and retried when it changes. The index is
a cache of the files: deleting ``index.sqlite`` loses nothing.

The read API returns plain dataclasses and dicts; this module never imports viser.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import sqlite3
import threading
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..sim import catalogue
from . import tables
from .records import (
    GRASP_FIELDS,
    METHODS,
    METRICS,
    ROW_FIELDS,
    ViewFileError,
    load_grasp_rows,
    parse_view_file,
)
from .summaries import CompletionResult, GraspSummary, ObjectSummary, SyncReport, ViewInfo

log = logging.getLogger(__name__)

INDEX_NAME = "index.sqlite"
SCHEMA_VERSION = 3
# The metrics the browser filters and sorts by, and which way is better.
HIGHER_IS_BETTER = {
    "jaccard": True,
    "j80": True,
    "hausdorff_mean_mm": False,
    "hausdorff_max_mm": False,
    "hausdorff_rms_mm": False,
    "geodesic": False,
}
METRIC_TITLES = {
    "jaccard": "Jaccard",
    "j80": "J80 (sampled solids)",
    "hausdorff_mean_mm": "Hausdorff mean (mm)",
    "hausdorff_max_mm": "Hausdorff max (mm)",
    "hausdorff_rms_mm": "Hausdorff RMS (mm)",
    "geodesic": "Geodesic divergence",
}
_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT);
CREATE TABLE IF NOT EXISTS files (path TEXT PRIMARY KEY, mtime_ns INTEGER, size INTEGER, status TEXT,
                                  message TEXT, object TEXT, view INTEGER);
CREATE TABLE IF NOT EXISTS objects (name TEXT PRIMARY KEY, split TEXT, source TEXT,
                                    extent_x REAL, extent_y REAL, extent_z REAL, in_catalogue INTEGER);
CREATE TABLE IF NOT EXISTS views (object TEXT, view INTEGER, view_set TEXT, seed INTEGER, file TEXT,
                                  truth TEXT, points TEXT, PRIMARY KEY (object, view));
CREATE TABLE IF NOT EXISTS completions (object TEXT, view INTEGER, method TEXT, jaccard REAL, j80 REAL,
                                        hausdorff_mean_mm REAL, hausdorff_max_mm REAL, hausdorff_rms_mm REAL,
                                        geodesic REAL, seconds REAL, error TEXT, mesh TEXT, prior TEXT,
                                        PRIMARY KEY (object, view, method));
CREATE TABLE IF NOT EXISTS grasps (object TEXT, view INTEGER, method TEXT, hand TEXT, file TEXT, n INTEGER,
                                   joint_error_deg REAL, pose_error_mm REAL, epsilon_planned REAL,
                                   epsilon_executed REAL, force_closure_planned REAL, lift_success REAL,
                                   seconds_plan REAL, error TEXT, PRIMARY KEY (object, view, method, hand));
CREATE INDEX IF NOT EXISTS completions_by_method ON completions (method, object);
"""
_VIEW_COLUMNS = "object, view, view_set, seed, file, truth, points"  # ViewInfo's fields


# ----------------------------------------------------------------------------------------------
# Values in and out of SQLite


def _as_float(v) -> float:
    """A value read from a view file as float; None, "", or anything unreadable is NaN."""
    try:
        return math.nan if v is None or v == "" else float(v)
    except (TypeError, ValueError):
        return math.nan


def _db(v: float) -> float | None:
    """SQLite stores NaN as NULL; say so explicitly."""
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else v


def _undb(v) -> float:
    return math.nan if v is None else float(v)


# ----------------------------------------------------------------------------------------------
# The store


class ResultsStore:
    """A results folder and its SQLite index (``<root>/index.sqlite``, WAL mode).

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
        with self._connect() as db:
            db.execute("PRAGMA journal_mode=WAL")
            version = None
            try:
                row = db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
                version = row and int(row[0])
            except sqlite3.OperationalError:  # a new index
                pass
            if version not in (None, SCHEMA_VERSION):  # an older index: it is only a cache, rebuild it
                for table in ("meta", "files", "objects", "views", "completions", "grasps"):
                    db.execute(f"DROP TABLE IF EXISTS {table}")
            db.executescript(_SCHEMA)
            db.execute("INSERT OR REPLACE INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))
        if sync:
            self.sync()

    def _connect(self) -> sqlite3.Connection:
        db = sqlite3.connect(self.index_path, timeout=30.0, isolation_level=None)
        db.execute("PRAGMA busy_timeout=30000")
        return db

    def _read(self, sql: str, args: Iterable = ()) -> list[tuple]:
        # One read connection per thread (sqlite3 connections stay in their thread); in autocommit
        # mode every query is its own WAL read transaction, so it sees the latest committed sync.
        db = getattr(self._local, "db", None)
        if db is None:
            db = self._local.db = self._connect()
        return db.execute(sql, tuple(args)).fetchall()

    # ------------------------------------------------------------------------------------------
    # Writing the index

    def sync(self) -> SyncReport:
        """Ingest new and changed ``views/*.json`` (by mtime and size) and forget deleted ones."""
        with self._sync_lock:
            report = SyncReport()
            db = self._connect()
            try:
                if not self._catalogue_done:
                    self._sync_catalogue(db)
                    self._catalogue_done = True
                known = {p: (m, s, st) for p, m, s, st in db.execute("SELECT path, mtime_ns, size, status FROM files")}
                seen = set()
                views_dir = self.root / "views"
                for path in sorted(views_dir.glob("*.json")) if views_dir.is_dir() else []:
                    rel = path.relative_to(self.root).as_posix()
                    seen.add(rel)
                    try:
                        st = path.stat()
                    except FileNotFoundError:  # replaced or deleted while we looked
                        continue
                    old = known.get(rel)
                    if old is not None and old[0] == st.st_mtime_ns and old[1] == st.st_size:
                        continue
                    self._ingest(db, rel, path, st, old, report)
                for rel in set(known) - seen:
                    self._forget(db, rel)
                    report.removed += 1
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

    def _sync_catalogue(self, db: sqlite3.Connection) -> None:
        """Put every catalogue object in the objects table (the index lists objects without results too)."""
        try:
            entries = catalogue.catalogue()
        except Exception as e:  # no catalogue (missing packages): list the objects the results know
            log.warning("object catalogue unavailable (%s); listing only objects with results", e)
            return
        key = hashlib.sha1("\n".join(f"{e.name} {e.split} {e.extents}" for e in entries).encode()).hexdigest()
        row = db.execute("SELECT value FROM meta WHERE key='catalogue'").fetchone()
        if row and row[0] == key:
            return
        db.execute("BEGIN IMMEDIATE")
        try:
            db.executemany(
                "INSERT OR REPLACE INTO objects VALUES (?, ?, ?, ?, ?, ?, 1)",
                [(e.name, e.split, e.source, *map(float, e.extents)) for e in entries],
            )
            db.execute("INSERT OR REPLACE INTO meta VALUES ('catalogue', ?)", (key,))
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise

    def _ingest(
        self, db: sqlite3.Connection, rel: str, path: Path, st: os.stat_result, old, report: SyncReport
    ) -> None:
        try:
            parsed = parse_view_file(path.read_text(), self.root)
        except (OSError, UnicodeDecodeError, ViewFileError) as e:
            why = str(e)
            if old is None or old[2] != "bad":  # warn once per version of the file
                log.warning("results: skipping %s: %s (retried when the file changes)", rel, why)
            report.skipped.append((rel, why))
            # Remember the bad version (so it is not re-read until it changes); rows of an earlier
            # good version stay: a view being rewritten keeps showing its last complete results.
            db.execute(
                "INSERT INTO files (path, mtime_ns, size, status, message) VALUES (?, ?, ?, 'bad', ?) "
                "ON CONFLICT(path) DO UPDATE SET mtime_ns=excluded.mtime_ns, size=excluded.size, "
                "status='bad', message=excluded.message",
                (rel, st.st_mtime_ns, st.st_size, why),
            )
            return
        name, view, files = parsed["object"], parsed["view"], parsed["files"]
        db.execute("BEGIN IMMEDIATE")
        try:
            prev = db.execute("SELECT object, view FROM files WHERE path=?", (rel,)).fetchone()
            had_rows = bool(prev and prev[0] is not None)
            if had_rows and (prev[0], prev[1]) != (name, view):
                self._delete_view(db, prev[0], prev[1])
            self._delete_view(db, name, view)
            db.execute(
                "INSERT OR IGNORE INTO objects VALUES (?, ?, ?, NULL, NULL, NULL, 0)",
                (name, catalogue.model_split(name), name.partition("/")[0] if "/" in name else "unknown"),
            )
            db.execute(
                "INSERT INTO views VALUES (?, ?, ?, ?, ?, ?, ?)",
                (name, view, parsed["view_set"], parsed["seed"], rel, files.get("truth"), files.get("points")),
            )
            completions = {}
            for r in parsed["rows"]:
                m = str(r["method"])
                completions[m] = (
                    name,
                    view,
                    m,
                    *[_db(_as_float(r.get(k))) for k in (*METRICS, "seconds")],
                    str(r.get("error") or ""),
                    files.get(m),
                    str(r.get("prior") or ""),
                )
            slots = ", ".join("?" * (7 + len(METRICS)))
            db.executemany(f"INSERT INTO completions VALUES ({slots})", completions.values())
            grasps = {}
            for g in parsed["grasps"]:
                method, hand = str(g.get("method", "")), str(g.get("hand", ""))
                gfile = g.get("file")
                gfile = gfile if isinstance(gfile, str) and (self.root / gfile).is_file() else None
                n = g.get("n")
                grasps[(method, hand)] = (
                    name,
                    view,
                    method,
                    hand,
                    gfile,
                    int(n) if isinstance(n, (int, float)) else 0,
                    *[_db(_as_float(g.get(k))) for k in GRASP_FIELDS[1:]],
                    str(g.get("error") or ""),
                )
            db.executemany("INSERT INTO grasps VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", grasps.values())
            db.execute(
                "INSERT OR REPLACE INTO files VALUES (?, ?, ?, 'ok', '', ?, ?)",
                (rel, st.st_mtime_ns, st.st_size, name, view),
            )
            self._bump(db)
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        if had_rows:
            report.updated += 1
        else:  # new, or readable for the first time
            report.added += 1

    @staticmethod
    def _bump(db: sqlite3.Connection) -> None:
        db.execute(
            "INSERT INTO meta VALUES ('generation', '1') ON CONFLICT(key) DO UPDATE SET "
            "value = CAST(value AS INTEGER) + 1"
        )

    def generation(self) -> int:
        """A number that changes whenever any store on this folder (any thread or process) changed the
        views: readers compare it to know when to re-read."""
        rows = self._read("SELECT value FROM meta WHERE key='generation'")
        return int(rows[0][0]) if rows else 0

    @staticmethod
    def _delete_view(db: sqlite3.Connection, name: str, view: int) -> None:
        for table in ("views", "completions", "grasps"):
            db.execute(f"DELETE FROM {table} WHERE object=? AND view=?", (name, view))

    def _forget(self, db: sqlite3.Connection, rel: str) -> None:
        db.execute("BEGIN IMMEDIATE")
        try:
            row = db.execute("SELECT object, view FROM files WHERE path=?", (rel,)).fetchone()
            if row and row[0] is not None:
                self._delete_view(db, row[0], row[1])
            db.execute("DELETE FROM files WHERE path=?", (rel,))
            self._bump(db)
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise

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
        split: str | None = None,
        with_results: bool = True,
        method: str = "Ours-fast",
        metric: str = "jaccard",
        order: str = "name",
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
            means.setdefault(name, {})[m] = dict(zip((*METRICS, "seconds"), map(_undb, vals)))
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
                (_undb(ex), _undb(ey), _undb(ez)),
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
        """Each method's completion of a view, in :data:`evaluate.METHODS` order (others after)."""
        rows = self._read(
            f"SELECT method, {', '.join(METRICS)}, seconds, error, mesh, prior FROM completions"
            " WHERE object=? AND view=?",
            (name, int(view)),
        )
        out = [
            CompletionResult(
                m, **dict(zip((*METRICS, "seconds"), map(_undb, vals))), error=err or "", mesh=mesh, prior=prior or ""
            )
            for m, *vals, err, mesh, prior in rows
        ]
        rank = {m: i for i, m in enumerate(METHODS)}
        return sorted(out, key=lambda c: (rank.get(c.method, len(rank)), c.method))

    def grasps(self, name: str, view: int) -> list[GraspSummary]:
        """Grasp summaries of a view (one per method and hand), in :data:`evaluate.METHODS` order."""
        rows = self._read(
            f"SELECT method, hand, file, {', '.join(GRASP_FIELDS)}, error FROM grasps WHERE object=? AND view=?",
            (name, int(view)),
        )
        out = [
            GraspSummary(m, h, f, int(n or 0), **dict(zip(GRASP_FIELDS[1:], map(_undb, vals))), error=err or "")
            for m, h, f, n, *vals, err in rows
        ]
        rank = {m: i for i, m in enumerate(METHODS)}
        return sorted(out, key=lambda g: (rank.get(g.method, len(rank)), g.method, g.hand))

    def rows(self, names: Iterable[str] | None = None) -> list[dict]:
        """Completion rows in the evaluation's format (:data:`evaluate.ROW_FIELDS`, NaN metrics on failure)."""
        sql = (
            f"SELECT c.object, c.view, v.view_set, c.method, {', '.join('c.' + k for k in METRICS)}, c.seconds, "
            "c.error, c.prior FROM completions c JOIN views v ON v.object=c.object AND v.view=c.view"
        )
        wanted = None if names is None else set(names)
        out = []
        for r in self._read(sql + " ORDER BY c.object, c.view"):
            if wanted is not None and r[0] not in wanted:
                continue
            d = dict(zip(("object", "view", "view_set", "method", *METRICS, "seconds", "error", "prior"), r))
            d.update(kind=catalogue.shape_kind(d["object"]), sensor="")
            for k in (*METRICS, "seconds"):
                d[k] = _undb(d[k])
            d["error"], d["prior"] = d["error"] or "", d["prior"] or ""
            out.append(d)
        rank = {m: i for i, m in enumerate(METHODS)}
        out.sort(key=lambda d: (d["object"], d["view"], rank.get(d["method"], len(rank))))
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
                **dict(zip(means, map(_undb, vals))),
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
                    "seconds_plan": _undb(seconds_plan),
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
        return tables.csv_text(ROW_FIELDS, self.rows(names))


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
