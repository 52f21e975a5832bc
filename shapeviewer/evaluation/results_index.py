"""The SQLite index of a results folder (``<root>/index.sqlite``, WAL mode): its schema, and the
sync that ingests the view files into it.

The index is a cache of the folder's view files (:mod:`.records`): deleting it loses nothing.
:func:`sync_index` ingests new and changed ``views/*.json`` by (mtime, size) and forgets deleted
ones; a file that cannot be read (half written, corrupt) is remembered as bad, with a warning once
per version, and retried when it changes. Every view is written in one transaction, so a reader
(:class:`~.results.ResultsStore`) never sees half a view. NaN is stored as NULL.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import sqlite3
from pathlib import Path

from ..sim import catalogue
from .records import GRASP_FIELDS, METRICS, ViewFileError, completion_rows, parse_view_file
from .summaries import SyncReport

log = logging.getLogger(__name__)

INDEX_NAME = "index.sqlite"
SCHEMA_VERSION = 3
_TABLES = ("meta", "files", "objects", "views", "completions", "grasps")
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


# ----------------------------------------------------------------------------------------------
# Values in and out of SQLite


def as_float(v) -> float:
    """A value read from a view file as float; None, "", or anything unreadable is NaN."""
    try:
        return math.nan if v is None or v == "" else float(v)
    except (TypeError, ValueError):
        return math.nan


def to_db(v: float) -> float | None:
    """SQLite stores NaN as NULL; say so explicitly."""
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else v


def from_db(v) -> float:
    """A REAL column as float (NULL is NaN)."""
    return math.nan if v is None else float(v)


# ----------------------------------------------------------------------------------------------
# Opening and syncing


def connect(path: Path) -> sqlite3.Connection:
    """A connection to the index at ``path`` in autocommit mode, waiting up to 30 s for a lock."""
    db = sqlite3.connect(path, timeout=30.0, isolation_level=None)
    db.execute("PRAGMA busy_timeout=30000")
    return db


def open_index(path: Path) -> None:
    """Create the index at ``path`` (WAL mode), or rebuild one of an older schema (a cache)."""
    with connect(path) as db:
        db.execute("PRAGMA journal_mode=WAL")
        version = None
        try:
            row = db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
            version = row and int(row[0])
        except sqlite3.OperationalError:  # a new index
            pass
        if version not in (None, SCHEMA_VERSION):  # an older index: it is only a cache, rebuild it
            for table in _TABLES:
                db.execute(f"DROP TABLE IF EXISTS {table}")
        db.executescript(_SCHEMA)
        db.execute("INSERT OR REPLACE INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))


def sync_index(db: sqlite3.Connection, root: Path, *, with_catalogue: bool) -> SyncReport:
    """Ingest the new and changed ``root/views/*.json`` (by mtime and size) into the index ``db``
    and forget deleted ones; ``with_catalogue``: also put every catalogue object in it."""
    report = SyncReport()
    if with_catalogue:
        sync_catalogue(db)
    known = {p: (m, s, st) for p, m, s, st in db.execute("SELECT path, mtime_ns, size, status FROM files")}
    seen = set()
    views_dir = root / "views"
    for path in sorted(views_dir.glob("*.json")) if views_dir.is_dir() else []:
        rel = path.relative_to(root).as_posix()
        seen.add(rel)
        try:
            st = path.stat()
        except FileNotFoundError:  # replaced or deleted while we looked
            continue
        old = known.get(rel)
        if old is not None and old[0] == st.st_mtime_ns and old[1] == st.st_size:
            continue
        _ingest(db, root, rel, path, st, old, report)
    for rel in set(known) - seen:
        _forget(db, rel)
        report.removed += 1
    return report


def sync_catalogue(db: sqlite3.Connection) -> None:
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
    db: sqlite3.Connection, root: Path, rel: str, path: Path, st: os.stat_result, old, report: SyncReport
) -> None:
    try:
        parsed = parse_view_file(path.read_text(), root)
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
            _delete_view(db, prev[0], prev[1])
        _delete_view(db, name, view)
        db.execute(
            "INSERT OR IGNORE INTO objects VALUES (?, ?, ?, NULL, NULL, NULL, 0)",
            (name, catalogue.model_split(name), name.partition("/")[0] if "/" in name else "unknown"),
        )
        db.execute(
            "INSERT INTO views VALUES (?, ?, ?, ?, ?, ?, ?)",
            (name, view, parsed["view_set"], parsed["seed"], rel, files.get("truth"), files.get("points")),
        )
        completions = {
            r.method: (
                name,
                view,
                r.method,
                *[to_db(getattr(r, k)) for k in (*METRICS, "seconds")],
                r.error,
                files.get(r.method),
                r.prior,
            )
            for r in completion_rows(parsed)
        }
        slots = ", ".join("?" * (7 + len(METRICS)))
        db.executemany(f"INSERT INTO completions VALUES ({slots})", completions.values())
        grasps = {}
        for g in parsed["grasps"]:
            method, hand = str(g.get("method", "")), str(g.get("hand", ""))
            gfile = g.get("file")
            gfile = gfile if isinstance(gfile, str) and (root / gfile).is_file() else None
            n = g.get("n")
            grasps[(method, hand)] = (
                name,
                view,
                method,
                hand,
                gfile,
                int(n) if isinstance(n, (int, float)) else 0,
                *[to_db(as_float(g.get(k))) for k in GRASP_FIELDS[1:]],
                str(g.get("error") or ""),
            )
        db.executemany("INSERT INTO grasps VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", grasps.values())
        db.execute(
            "INSERT OR REPLACE INTO files VALUES (?, ?, ?, 'ok', '', ?, ?)",
            (rel, st.st_mtime_ns, st.st_size, name, view),
        )
        _bump(db)
        db.execute("COMMIT")
    except BaseException:
        db.execute("ROLLBACK")
        raise
    if had_rows:
        report.updated += 1
    else:  # new, or readable for the first time
        report.added += 1


def _bump(db: sqlite3.Connection) -> None:
    """Change the index's generation number (see :func:`generation`)."""
    db.execute(
        "INSERT INTO meta VALUES ('generation', '1') ON CONFLICT(key) DO UPDATE SET value = CAST(value AS INTEGER) + 1"
    )


def _delete_view(db: sqlite3.Connection, name: str, view: int) -> None:
    for table in ("views", "completions", "grasps"):
        db.execute(f"DELETE FROM {table} WHERE object=? AND view=?", (name, view))


def _forget(db: sqlite3.Connection, rel: str) -> None:
    db.execute("BEGIN IMMEDIATE")
    try:
        row = db.execute("SELECT object, view FROM files WHERE path=?", (rel,)).fetchone()
        if row and row[0] is not None:
            _delete_view(db, row[0], row[1])
        db.execute("DELETE FROM files WHERE path=?", (rel,))
        _bump(db)
        db.execute("COMMIT")
    except BaseException:
        db.execute("ROLLBACK")
        raise
