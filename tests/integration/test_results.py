"""The results store: round trip of an evaluation folder through the SQLite index, both view-file
formats, a half-finished run, incremental sync, reading while another store writes."""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import os
import sqlite3
import threading

import numpy as np
import pytest
import trimesh

from shapeviewer.evaluation import methods
from shapeviewer.evaluation.records import (
    METHODS,
    METRICS,
    ROW_FIELDS,
    CompletionRow,
    ViewFileError,
    completion_rows,
    parse_view_file,
    view_record,
    view_stem,
)
from shapeviewer.evaluation.results import ResultsStore
from shapeviewer.evaluation.run import T_WORLD_CAM
from shapeviewer.evaluation.tables import summarize
from shapeviewer.evaluation.viewsets import VIEW_SETS
from shapeviewer.perception.camera import transform_points

from store_factory import VIEWS, jaccard_of, make_store, truth_cam, write_view


@pytest.fixture()
def folder(tmp_path):
    records = make_store(tmp_path)
    return tmp_path, records


def test_round_trip_of_both_formats(folder):
    root, records = folder
    store = ResultsStore(root)
    assert store.counts() == {"objects": 3, "views": 4, "completions": 4 * len(METHODS), "grasps": 2, "skipped": 0}
    with sqlite3.connect(root / "index.sqlite") as db:
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    # Every completion row comes back as written (the old-format view included), NaN where failed.
    got = {(r.object, r.view, r.method): r for r in store.rows()}
    assert len(got) == 4 * len(METHODS)
    for rec in records.values():
        for row in rec["rows"]:
            back = got[(row["object"], row["view"], row["method"])]
            for k in (*METRICS, "seconds"):
                mine = getattr(back, k)
                assert (math.isnan(mine) and math.isnan(row[k])) or mine == pytest.approx(row[k]), k
            assert back.error == row["error"] and back.view_set == row["view_set"]
    # The tables are the evaluation's own summary of those rows.
    expect = summarize([r for rec in records.values() for r in completion_rows(rec)])
    got_summary = store.summary()
    for s in VIEW_SETS:
        for m in METHODS:
            for k, v in expect[s][m].items():
                assert got_summary[s][m][k] == pytest.approx(v, nan_ok=True), (s, m, k)
    # Mesh files of the old format are found at their fixed paths; a failed method has none.
    name, view = VIEWS[1]
    assert store.view(name, view).seed is None
    assert store.mesh_file(name, view, "Ours-fast").name == f"{view_stem(name, view)}__Ours-fast.ply"
    mustard = {c.method: c for c in store.completions("ycb/006_mustard_bottle", 7)}
    assert not mustard["Mirror"].ok and mustard["Mirror"].mesh is None and math.isnan(mustard["Mirror"].jaccard)
    assert mustard["Ours-fast"].jaccard == pytest.approx(jaccard_of("ycb/006_mustard_bottle", 7, "Ours-fast"))
    with pytest.raises(KeyError):
        store.mesh_file("ycb/006_mustard_bottle", 7, "Mirror")
    # Meshes load in the camera frame, as written.
    truth = store.load_mesh(*VIEWS[0], "truth")
    assert np.allclose(truth.bounds, truth_cam(*VIEWS[0]).bounds, atol=1e-6)


def test_objects_filters_and_orders(folder):
    root, _ = folder
    store = ResultsStore(root)
    names = [o.name for o in store.objects()]
    assert names == sorted(n for n in {v[0] for v in VIEWS})
    assert len(store.objects(with_results=False)) > 1000  # every catalogue object is listed
    mug = store.object("ycb/025_mug")
    assert mug.views == 2 and mug.split == "train" and mug.source == "ycb" and mug.extents[2] > 0.05
    assert mug.mean("Ours-fast", "jaccard") == pytest.approx(
        np.mean([jaccard_of("ycb/025_mug", v, "Ours-fast") for n, v in VIEWS if n == "ycb/025_mug"])
    )
    # Worst Jaccard first, and the reverse for a distance (larger is worse).
    worst = store.objects(order="worst", method="Ours-fast", metric="jaccard")
    js = [o.mean("Ours-fast", "jaccard") for o in worst]
    assert js == sorted(js)
    worst_h = store.objects(order="worst", method="Ours-fast", metric="hausdorff_mean_mm")
    assert [o.name for o in worst_h] == [o.name for o in worst]  # H = 20 (1 - J) here
    assert [o.name for o in store.objects(split="holdout_model")] == ["ycb/006_mustard_bottle"]
    assert [o.name for o in store.objects(search="DUCK")] == ["pybullet/duck"]
    lo = min(js)
    assert [o.name for o in store.objects(metric_range=(0, lo + 1e-9))] == [worst[0].name]
    # A method that failed everywhere has no mean: range filters drop the object.
    assert store.objects(method="Mirror", metric_range=(0, 1), search="mustard") == []


def test_grasps_round_trip(folder):
    root, records = folder
    store = ResultsStore(root)
    name, view = VIEWS[0]
    g = {x.method: x for x in store.grasps(name, view)}
    assert set(g) == {"Ours-fast", "Partial"}
    assert g["Partial"].n == 2 and g["Partial"].joint_error_deg == 2.9 and g["Partial"].lift_success == 0.5
    gs = store.grasp_set(name, view, "Ours-fast")
    assert len(gs.grasps) == 2 and gs.executions[0].lift.success
    assert np.allclose(gs.meta["T_world_cam"], T_WORLD_CAM)
    assert store.grasp_set(name, view, "Mirror") is None
    summary = store.grasp_summary()
    assert summary[records[(name, view)]["view_set"]]["Partial"]["pose_error_mm"] == 5.0
    assert "Table IV" in store.tables_markdown()
    rows = list(csv.DictReader(io.StringIO(store.view_csv(name, view))))
    assert [r["method"] for r in rows] == list(METHODS)
    fast = rows[list(METHODS).index("Ours-fast")]
    assert fast["grasp_hand"] == "barrett" and float(fast["grasp_pose_error_mm"]) == 5.0
    assert rows[1]["grasp_hand"] == ""  # Mirror: no grasps


def test_capture_puts_the_points_back_in_the_view(folder):
    root, _ = folder
    store = ResultsStore(root)
    name, view = VIEWS[0]
    cap = store.capture(name, view)
    pts = store.load_points(name, view)
    assert np.array_equal(cap.points_cam, pts) and cap.source.endswith("__points.ply")
    # World = object frame on a floor: the true object stands on z = 0 and the points lie on it.
    world_truth = cap.objects[0].mesh.copy()
    world_truth.apply_transform(cap.objects[0].T_world_obj)
    assert world_truth.bounds[0][2] == pytest.approx(0.0, abs=1e-9)
    truth = store.load_mesh(name, view, "truth")
    assert np.allclose(transform_points(cap.T_world_cam, truth.vertices), world_truth.vertices, atol=1e-9)
    d = trimesh.proximity.closest_point(world_truth, transform_points(cap.T_world_cam, pts))[1]
    assert d.max() < 1e-6


def test_half_written_file_is_skipped_then_read(folder, caplog):
    root, records = folder
    store = ResultsStore(root)
    name, view = "ycb/035_power_drill", 5
    rec = write_view(root, name, view)
    path = root / "views" / f"{view_stem(name, view)}.json"
    full = path.read_text()
    path.write_text(full[: len(full) // 2])  # a run killed while writing (no atomic rename)
    with caplog.at_level(logging.WARNING, logger="shapeviewer.evaluation.results"):
        report = store.sync()
    assert report.skipped and report.skipped[0][0] == f"views/{path.name}" and "not JSON" in report.skipped[0][1]
    assert "skipping" in caplog.text
    assert store.counts()["views"] == 4 and store.counts()["skipped"] == 1
    assert store.views(name) == []
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="shapeviewer.evaluation.results"):
        assert not store.sync().changed  # unchanged bad file: not re-read, no second warning
    assert "skipping" not in caplog.text
    path.write_text(full)
    os.utime(path, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns + 1_000_000))
    report = store.sync()
    assert report.added == 1 and store.counts() == {**store.counts(), "views": 5, "skipped": 0}
    assert [c.method for c in store.completions(name, view)] == list(METHODS)
    assert len(rec["rows"]) == len(METHODS)
    # Not a view at all, and rows of two views in one file: skipped with the reason.
    (root / "views" / "junk.json").write_text(json.dumps({"hello": 1}))
    bad = [dict(r) for r in rec["rows"]]
    bad[1]["view"] = 99
    (root / "views" / "mixed.json").write_text(json.dumps(bad))
    reasons = dict(store.sync().skipped)
    assert "no 'rows'" in reasons["views/junk.json"] and "different views" in reasons["views/mixed.json"]


def test_sync_is_incremental_and_forgets_deleted_views(folder):
    root, records = folder
    store = ResultsStore(root)
    assert not store.sync().changed
    name, view = VIEWS[2]
    path = root / "views" / f"{view_stem(name, view)}.json"
    rec = json.loads(path.read_text())
    rec["rows"][2]["jaccard"] = 0.99
    path.write_text(json.dumps(rec))
    os.utime(path, ns=(path.stat().st_atime_ns, path.stat().st_mtime_ns + 1_000_000))
    report = store.sync()
    assert (report.added, report.updated, report.removed) == (0, 1, 0)
    assert store.completions(name, view)[2].jaccard == 0.99
    path.unlink()
    assert store.sync().removed == 1
    assert store.views(name) == [] and store.counts()["views"] == 3
    # The index is a cache: a new store on the same folder (another process) reads it without syncing,
    # and sees through the generation number when the other one changed it.
    again = ResultsStore(root, sync=False)
    assert again.counts()["views"] == 3
    seen = again.generation()
    write_view(root, "ycb/025_mug", 500)
    assert again.generation() == seen
    store.sync()
    assert again.generation() != seen and again.counts()["views"] == 4


def test_parse_rejects_a_view_file_without_rows(tmp_path):
    for text, why in (
        ("[]", "no rows"),
        ('{"object": "a", "view": 1}', "no 'rows'"),
        ("3", "not a view"),
        ('[{"view": 1, "method": "Partial"}]', "no object name"),
    ):
        with pytest.raises(ViewFileError, match=why):
            parse_view_file(text, tmp_path)


def test_reading_while_another_store_adds_views(tmp_path):
    """A browser reading the index while an evaluation (another connection) adds views and syncs."""
    writer = ResultsStore(tmp_path)
    reader = ResultsStore(tmp_path, sync=False)
    errors: list[BaseException] = []
    seen: list[int] = []
    stop = threading.Event()

    def read() -> None:
        while not stop.is_set():
            try:
                objs = reader.objects()
                seen.append(sum(o.views for o in objs))
                for o in objs:
                    for v in reader.views(o.name):
                        reader.completions(o.name, v.view)
            except BaseException as e:  # noqa: BLE001 - any failure fails the test
                errors.append(e)
                return

    t = threading.Thread(target=read)
    t.start()
    try:
        for view in range(6):
            write_view(tmp_path, "ycb/025_mug", 100 + view)
            writer.sync()
    finally:
        stop.set()
        t.join()
    assert not errors, errors
    assert seen == sorted(seen) and reader.counts()["views"] == 6


def test_files_are_written_atomically(tmp_path, monkeypatch):
    """One helper writes every results file: the whole file or, when writing fails, the old one;
    never a temp file left behind that a ``views/*.json`` glob could pick up."""
    from shapeviewer import fileio

    path = fileio.atomic_write(tmp_path / "views" / "a.json", "{}")
    assert path.read_text() == "{}" and [p.name for p in path.parent.iterdir()] == ["a.json"]
    fileio.atomic_write(path, b"[1]")
    assert path.read_bytes() == b"[1]"

    def fail(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(fileio.os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        fileio.atomic_write(path, "[2]")
    assert path.read_bytes() == b"[1]" and [p.name for p in path.parent.iterdir()] == ["a.json"]


def test_completion_rows_round_trip(tmp_path):
    """A row as the evaluation writes it today reads back identically (NaN included), through the
    record and the JSON text of a view file; a first-format row gets the defaults of what it lacks."""
    nan = math.nan
    written = [
        {"object": "ycb/025_mug", "view": 3, "view_set": "training_view", "kind": "mug", "sensor": "kinect",
         "method": "Ours-fast", "jaccard": 0.71, "j80": 0.69, "hausdorff_mean_mm": 3.2, "hausdorff_max_mm": 11.0,
         "hausdorff_rms_mm": 4.1, "geodesic": 0.08, "seconds": 0.42, "error": "", "prior": "revolution",
         "support_plane": [0.0, -1.0, 0.0, 0.5]},
        {"object": "ycb/025_mug", "view": 3, "view_set": "training_view", "kind": "mug", "sensor": "kinect",
         "method": "Mirror", "jaccard": nan, "j80": nan, "hausdorff_mean_mm": nan, "hausdorff_max_mm": nan,
         "hausdorff_rms_mm": nan, "geodesic": nan, "seconds": nan, "error": "ValueError: too few points",
         "prior": ""},
    ]  # fmt: skip
    expect = [{k: v for k, v in r.items() if k != "support_plane"} for r in written]
    record = view_record(tmp_path, "ycb/025_mug", 3, "training_view", 0, [dict(r) for r in written])
    assert record["support_plane"] == [0.0, -1.0, 0.0, 0.5]
    assert json.dumps(record["rows"]) == json.dumps(expect)  # every key, in ROW_FIELDS order
    assert [list(r) for r in record["rows"]] == [list(ROW_FIELDS)] * 2
    parsed = parse_view_file(json.dumps(record), tmp_path)
    rows = completion_rows(parsed)
    assert [r.method for r in rows] == ["Ours-fast", "Mirror"] and rows[0].prior == "revolution"
    assert not rows[1].ok and math.isnan(rows[1].jaccard)
    assert json.dumps([r.to_json() for r in rows]) == json.dumps(expect)
    assert all(CompletionRow.from_json(r.to_json()) == r for r in rows[:1])  # frozen, comparable (no NaN)
    with pytest.raises(AttributeError):
        rows[0].jaccard = 1.0  # type: ignore[misc]
    # The first format: no kind, sensor or prior; the view set comes from the record when missing.
    old = {k: written[0][k] for k in ("object", "view", "method", *METRICS, "seconds", "error")}
    first = completion_rows(parse_view_file(json.dumps([old]), tmp_path))[0]
    assert (first.kind, first.sensor, first.prior, first.view_set) == ("", "", "", "training_view")
    assert first.jaccard == 0.71
    # A row of a method no evaluation ever wrote makes the file unreadable, with the reason.
    with pytest.raises(ViewFileError, match="unknown method"):
        parse_view_file(json.dumps([{**old, "method": "Ours"}]), tmp_path)


def test_one_method_vocabulary():
    """Results files keep their method names; the viewer's keys, titles and short labels map to them."""
    assert methods.METHODS == ("Partial", "Mirror", "Hull", "Ours-fast", "Ours-detailed")
    assert methods.ENVELOPE == "Ours-envelope" and methods.ALL_METHODS == (*methods.METHODS, methods.ENVELOPE)
    assert methods.CNN_METHODS == ("Ours-fast", "Ours-detailed", "Ours-envelope")
    assert set(methods.MESH_KINDS) == {info.key for info in methods.METHOD_INFO.values()}
    for m in methods.ALL_METHODS:
        assert methods.method_of(methods.key_of(m)) == m
    assert methods.method_of("fast") == "Ours-fast" and methods.key_of("Hull") == "hull"
    assert methods.method_rank("Ours-envelope") == 5 and methods.method_rank("something else") == 6
