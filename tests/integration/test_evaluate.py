"""The paper's completion and grasp tables: `shapeviewer.evaluation.run` end to end on one view per set,
through local processes and a Ray instance."""

import csv
import dataclasses
import json
import math
import shutil

import numpy as np
import pytest

from shapeviewer.cli import main
from shapeviewer.evaluation import records as rec
from shapeviewer.evaluation import run as ev
from shapeviewer.evaluation.viewsets import PAPER_SETS, TABLETOP_SETS, TABLETOP_VIEW_OFFSET


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval")
    return out, ev.evaluate(out, n_per_set=1, seed=0, workers=1, progress=False)


def test_sample_views_seeded_and_split():
    a = ev.sample_views(3, seed=0)
    assert a == ev.sample_views(3, seed=0)
    assert a != ev.sample_views(3, seed=1)
    assert [s for *_, s in a] == [s for s in PAPER_SETS for _ in range(3)]
    from shapeviewer.sim.catalogue import view_split

    assert all(view_split(n, v) == s and 0 <= v < 726 for n, v, s in a)
    assert len(set((n, v) for n, v, _ in a)) == len(a)


def test_rows_for_every_view_and_method(run):
    out, r = run
    assert r["computed"] == 3 and r["skipped"] == 0
    rows = list(csv.DictReader(open(out / "rows.csv")))
    assert len(rows) == 3 * len(rec.METHODS)
    assert {(x["view_set"], x["method"]) for x in rows} == {(s, m) for s in PAPER_SETS for m in rec.METHODS}
    for x in rows:
        assert set(rec.ROW_FIELDS) <= set(x)
        if not x["error"]:
            assert 0 <= float(x["jaccard"]) <= 1 and float(x["hausdorff_mean_mm"]) >= 0 and float(x["seconds"]) > 0
    # Ours must succeed on these views; failures elsewhere are recorded, not fatal.
    assert all(not x["error"] for x in rows if x["method"].startswith("Ours"))


def test_meshes_written(run):
    out, r = run
    names = {p.name for p in (out / "meshes").glob("*.ply")}
    for n, v, _ in ev.sample_views(1, 0):
        stem = rec.view_stem(n, v)
        assert f"{stem}__truth.ply" in names and f"{stem}__points.ply" in names
        for m in rec.METHODS:
            if not any(x.error for x in r["rows"] if x.object == n and x.method == m):
                assert f"{stem}__{m}.ply" in names


def test_tables_have_paper_numbers(run):
    out, _ = run
    md = (out / "tables.md").read_text()
    for t in ("Table I:", "Table II:", "Table III:", "completion time"):
        assert t in md
    for paper in ("0.777", "0.749", "0.650", "11.4", "5.9", "0.087", "0.141", "0.494"):
        assert paper in md
    rows = [r for r in csv.DictReader(open(out / "tables.csv")) if r["table"] == "I-III"]
    assert len(rows) == 3 * len(rec.METHODS) and {"paper_jaccard", "jaccard", "seconds"} <= set(rows[0])
    # One paper column per figure: the paper's "Ours" is our detailed mesh; Hull and Ours-fast have none.
    paper = {(r["view_set"], r["method"]): float(r["paper_jaccard"]) for r in rows}
    assert paper[("training_view", "Ours-detailed")] == 0.777 and paper[("holdout_model", "Partial")] == 0.093
    assert all(math.isnan(paper[(s, m)]) for s in PAPER_SETS for m in ("Hull", "Ours-fast"))


def test_tabletop_views_are_segmented_on_a_table_and_reported_per_kind(tmp_path):
    views = ev.sample_views(2, seed=0, views="tabletop")
    assert [s for *_, s in views] == [s for s in TABLETOP_SETS for _ in range(2)]
    assert all(v >= TABLETOP_VIEW_OFFSET for _, v, _ in views)  # never a view the training data used
    from shapeviewer.sim.catalogue import model_split

    assert [model_split(n) for n, *_ in views] == ["train", "train", "holdout_model", "holdout_model"]
    r = ev.evaluate(tmp_path, n_per_set=1, seed=0, workers=1, progress=False, views="tabletop")
    rows = r["rows"]
    assert {(x.view_set, x.method) for x in rows} == {(s, m) for s in TABLETOP_SETS for m in rec.METHODS}
    assert all(x.kind and x.sensor in ("kinect", "realsense") for x in rows)
    by = {(x.view_set, x.method): x for x in rows}
    for s in TABLETOP_SETS:
        assert by[(s, "Hull")].ok and by[(s, "Ours-detailed")].ok
        # The hull of the visible points is a solid the true object mostly contains, not an empty guess.
        assert 0.1 < by[(s, "Hull")].j80 < 1.0
    md = (tmp_path / "tables.md").read_text()
    assert "Per shape kind" in md and "Tabletop, holdout models" in md and "Training Views" not in md


def test_ours_beats_partial_on_jaccard(run):
    _, r = run

    def mean(m: str) -> float:
        return sum(x.jaccard for x in r["rows"] if x.method == m) / 3

    assert not math.isnan(mean("Ours-fast"))
    assert mean("Ours-fast") > mean("Partial") + 0.1


def test_resume_skips_done_views(run, monkeypatch):
    out, first = run
    calls = []
    monkeypatch.setattr(ev, "evaluate_view", lambda *a, **k: calls.append(a) or [])
    again = ev.evaluate(out, n_per_set=1, seed=0, workers=1, progress=False)
    assert calls == [] and again["computed"] == 0 and again["skipped"] == 3
    assert again["summary"] == first["summary"] or str(again["summary"]) == str(first["summary"])


def test_cli_evaluate(run, capsys):
    out, _ = run
    assert (
        main(
            [
                "evaluate",
                "--out",
                str(out),
                "--views-per-set",
                "1",
                "--workers",
                "1",
                "--no-progress",
                "--backend",
                "process",
            ]
        )
        == 0
    )
    assert "Table III" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["evaluate", "--out", str(out), "--backend", "threads"])


def test_view_files_are_records(run):
    out, _ = run
    for n, v, s in ev.sample_views(1, 0):
        record = json.loads(rec.view_file(out, n, v).read_text())
        assert {"object", "view", "view_set", "seed", "files", "rows", "grasps"} <= set(record)
        assert [record[k] for k in ("object", "view", "view_set", "seed", "grasps")] == [n, v, s, 0, []]
        assert {"truth", "points"} <= set(record["files"]) and all((out / f).exists() for f in record["files"].values())
        assert [r["method"] for r in record["rows"]] == list(rec.METHODS)


def test_old_format_views_load_and_upgrade(run, tmp_path):
    out, _ = run
    n, v, s = ev.sample_views(1, 0)[0]
    stem = rec.view_stem(n, v)
    (tmp_path / "meshes").mkdir()
    for f in (out / "meshes").glob(f"{stem}__*.ply"):
        shutil.copy(f, tmp_path / "meshes" / f.name)
    rows = json.loads(rec.view_file(out, n, v).read_text())["rows"]
    (tmp_path / "views").mkdir()
    rec.view_file(tmp_path, n, v).write_text(json.dumps(rows))  # the first format: a bare list of rows
    record = rec.load_view(tmp_path, n, v, seed=0)
    assert record["rows"] == rows and record["view_set"] == s and record["grasps"] == [] and record["seed"] == 0
    assert record["files"]["truth"] == f"meshes/{stem}__truth.ply" and "Ours-detailed" in record["files"]
    rec.upgrade_old_views(tmp_path, [(n, v, s)], seed=0)
    assert json.loads(rec.view_file(tmp_path, n, v).read_text()) == record


def test_world_frame_is_level_camera():
    R = ev.T_WORLD_CAM[:3, :3]
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R @ [0, 1, 0], [0, 0, -1])  # image down is gravity
    assert np.allclose(R @ [0, 0, 1], [1, 0, 0])  # the optical axis is horizontal


def test_grasp_means_and_pending():
    rows = [
        {
            "epsilon_planned": 0.1,
            "epsilon_executed": -0.2,
            "joint_error_deg": 2.0,
            "pose_error_mm": 4.0,
            "volume_planned": 1.0,
            "volume_executed": 0.5,
            "start_clear": 1.0,
            "lift_success": 0.0,
        },
        {
            "epsilon_planned": 0.05,
            "epsilon_executed": 0.01,
            "joint_error_deg": 4.0,
            "pose_error_mm": 0.0,
            "volume_planned": 1.0,
            "volume_executed": 0.5,
            "start_clear": 0.0,
            "lift_success": 1.0,
        },
    ]
    m = ev.grasp_means(rows)
    assert m["joint_error_deg"] == 3.0 and m["pose_error_mm"] == 2.0 and m["lift_success"] == 0.5
    assert m["force_closure_planned"] == 1.0 and m["force_closure_executed"] == 0.5
    assert m["lift_success_best"] == 0.0  # rank 0, the grasp a robot would execute, dropped the object
    empty = ev.grasp_means([])
    assert math.isnan(empty["joint_error_deg"]) and empty["lift_success_best"] == 0.0
    opts = ev.GraspOptions(methods=("Partial", "Mirror", "Ours-detailed"))
    record = {
        "grasps": [
            {"method": "Partial", "hand": "barrett", "error": ""},
            {"method": "Mirror", "hand": "barrett", "error": "RuntimeError: crash"},
            {"method": "Ours-detailed", "hand": "panda", "error": ""},
        ]
    }
    assert ev.pending_grasps(record, opts) == ["Mirror", "Ours-detailed"]
    with pytest.raises(ValueError):
        ev.GraspOptions(methods=("Ours",))


def test_grasp_success_per_kind():
    from shapeviewer.evaluation.records import CompletionRow
    from shapeviewer.evaluation.tables import kind_grasp_table_markdown

    def entry(method, n, error=""):
        return {"method": method, "hand": "barrett", "n": n, "error": error}

    records = [
        {"object": "household/mug_001", "view": 1, "grasps": [entry("Hull", 2), entry("Ours-detailed", 2)]},
        # The planner found no grasp on the hull here: a failed lift, as in Table V.
        {"object": "household/mug_001", "view": 2, "grasps": [entry("Hull", 0), entry("Ours-detailed", 1)]},
        # A crashed entry is left out, not counted as a failure.
        {"object": "ycb/025_mug", "view": 3, "grasps": [entry("Hull", 0, "RuntimeError: crash")]},
        {"object": "household/box_004", "view": 4, "grasps": [entry("Hull", 1), entry("Ours-detailed", 1)]},
    ]
    rows = [
        CompletionRow(obj, view, "holdout_model", "Hull", kind=kind)
        for obj, view, kind in (
            ("household/mug_001", 1, "mug"),
            ("ycb/025_mug", 3, "mug"),
            ("household/box_004", 4, "box"),
        )
    ]

    def grasp(obj, view, method, rank, robust_rank, lifted):
        return {"object": obj, "view": view, "method": method, "hand": "barrett", "rank": rank,
                "robust_rank": robust_rank, "lift_success": float(lifted)}  # fmt: skip

    grasp_rows = [
        grasp("household/mug_001", 1, "Hull", 0, math.nan, True),
        grasp("household/mug_001", 1, "Hull", 1, math.nan, False),
        grasp("household/mug_001", 1, "Ours-detailed", 0, 1, False),
        grasp("household/mug_001", 1, "Ours-detailed", 1, 0, True),
        grasp("household/mug_001", 2, "Ours-detailed", 0, 0, True),
        grasp("household/box_004", 4, "Hull", 0, math.nan, False),
        grasp("household/box_004", 4, "Ours-detailed", 0, 0, False),
    ]
    md = kind_grasp_table_markdown(records, rows, grasp_rows)
    assert "| kind | views | Hull | Ours-detailed | Ours-detailed (robust) |" in md
    # mug: Hull lifted on view 1 only; Ours' planner order dropped it on view 1, its robust order lifted both.
    assert "| mug | 2 | 50% | 50% | 100% |" in md
    assert "| box | 1 | 0% | 0% | 0% |" in md
    assert kind_grasp_table_markdown(records, [], grasp_rows) == ""


GRASP_METHODS = ("Partial", "Ours-detailed")


@pytest.fixture(scope="module")
def grasp_run(run, tmp_path_factory):
    """The completion run's folder, copied, rerun with grasps: the completions must be reused."""
    from shapeviewer.grasp.plan import PlanSettings

    out = tmp_path_factory.mktemp("eval_grasps") / "out"
    shutil.copytree(run[0], out)
    options = ev.GraspOptions(
        methods=GRASP_METHODS, n_grasps=2, settings=PlanSettings(samples=256, chains=16, steps=10, simulate=8)
    )

    def no_completion(*a, **k):
        raise AssertionError("completions were recomputed")

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(ev, "evaluate_view", no_completion)
        r = ev.evaluate(out, n_per_set=1, seed=0, workers=1, progress=False, grasps=options)
    return out, options, r


@pytest.mark.slow
def test_grasp_stage_records(grasp_run):
    from shapeviewer.grasp.serialize import grasps_from_json

    out, options, r = grasp_run
    assert r["computed"] == 3
    for n, v, _ in ev.sample_views(1, 0):
        record = json.loads(rec.view_file(out, n, v).read_text())
        assert [g["method"] for g in record["grasps"]] == list(GRASP_METHODS)
        for g in record["grasps"]:
            assert g["error"] == "" and g["hand"] == "barrett" and 1 <= g["n"] <= 2
            assert g["file"] == f"grasps/{rec.view_stem(n, v)}__{g['method']}.json"
            for k in ("joint_error_deg", "pose_error_mm", "epsilon_planned", "epsilon_executed"):
                assert math.isfinite(g[k])
            assert g["joint_error_deg"] >= 0 and g["pose_error_mm"] >= 0 and g["seconds_plan"] > 0
            assert 0 <= g["force_closure_planned"] <= 1 and 0 <= g["lift_success"] <= 1
            gs = grasps_from_json((out / g["file"]).read_text())
            assert len(gs.grasps) == g["n"] and all(e is not None and e.lift is not None for e in gs.executions)
            assert gs.meta["T_world_cam"] == ev.T_WORLD_CAM.tolist() and gs.meta["view"] == v
            # The entry's means are those of the saved grasps.
            assert g["pose_error_mm"] == pytest.approx(np.mean([e.pose_error for e in gs.executions]))
    rows = list(csv.DictReader(open(out / "grasp_rows.csv")))
    assert (
        len(rows)
        == len(r["grasp_rows"])
        == sum(g["n"] for n, v, _ in ev.sample_views(1, 0) for g in rec.load_view(out, n, v)["grasps"])
    )
    assert set(rec.GRASP_ROW_FIELDS) <= set(rows[0])


@pytest.mark.slow
def test_grasp_tables(grasp_run):
    out, _, r = grasp_run
    md = (out / "tables.md").read_text()
    assert "Table I:" in md and "Table IV: joint error" in md and "Table V analogue" in md
    assert "Per shape kind: best grasp's lift success, barrett hand" in md
    for paper in ("6.09", "4.56", "16.0", "13.2", "71.4%", "93.3%"):
        assert paper in md
    cells = [x for x in csv.DictReader(open(out / "tables.csv")) if x["table"] == "IV-V"]
    assert {(x["view_set"], x["method"]) for x in cells} == {
        (s, m) for s in (*PAPER_SETS, "all") for m in GRASP_METHODS
    }
    for x in cells:
        for k in ("joint_error_deg", "pose_error_mm", "joint_error_deg_median", "pose_error_mm_median"):
            assert math.isfinite(float(x[k])) and float(x[k]) >= 0
    allp = next(x for x in cells if x["view_set"] == "all" and x["method"] == "Partial")
    assert int(allp["n"]) == 3 and float(allp["paper_lift_success"]) == 0.714


@pytest.mark.slow
def test_grasp_resume_skips_done(grasp_run, monkeypatch, capsys):
    out, options, first = grasp_run
    calls = []
    monkeypatch.setattr(ev, "evaluate_view", lambda *a, **k: calls.append(a) or [])
    monkeypatch.setattr(ev, "grasp_view", lambda *a, **k: calls.append(a) or {})
    again = ev.evaluate(out, n_per_set=1, seed=0, workers=1, progress=False, grasps=options)
    assert calls == [] and again["computed"] == 0 and again["skipped"] == 3
    assert again["grasp_rows"] == first["grasp_rows"]
    # The command line with the same hand and methods, but the planner's default search sizes (the
    # folder's grasps were planned with smaller ones): refused before any work, naming the setting.
    assert (
        main(
            [
                "evaluate",
                "--out",
                str(out),
                "--views-per-set",
                "1",
                "--workers",
                "1",
                "--no-progress",
                "--grasps",
                "--n-grasps",
                "2",
                "--grasp-methods",
                *GRASP_METHODS,
            ]
        )
        == 2
    )
    assert calls == [] and "search sizes" in capsys.readouterr().err
    assert main(["evaluate", "--out", str(out), "--views-per-set", "1", "--grasps", "--grasp-methods", "Ours"]) == 2


@pytest.mark.slow
def test_ray_backend_gives_the_same_records(grasp_run, tmp_path):
    """Two of the views through a local Ray instance on one CPU, completions and Partial's grasps:
    the records are those the process backend wrote (times aside)."""
    ray = pytest.importorskip("ray")
    out, options, _ = grasp_run
    views = ev.sample_views(1, 0)[:2]
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:
        assert (
            ev.run_views(
                tmp_path,
                views,
                seed=0,
                backend="ray",
                progress=False,
                grasps=dataclasses.replace(options, methods=("Partial",)),
            )
            == 2
        )
    finally:
        ray.shutdown()

    def same(d: dict) -> str:  # JSON text: NaN metrics of a failed method compare equal
        return json.dumps(
            {k: v for k, v in d.items() if k not in ("seconds", "seconds_plan", "seconds_execute")}, sort_keys=True
        )

    for n, v, _ in views:
        a, b = rec.load_view(out, n, v), rec.load_view(tmp_path, n, v)
        assert (b["files"], b["support_plane"], b["seed"]) == (a["files"], a["support_plane"], a["seed"])
        assert [same(r) for r in b["rows"]] == [same(r) for r in a["rows"]]
        assert [same(g) for g in b["grasps"]] == [same(g) for g in a["grasps"] if g["method"] == "Partial"]
    with pytest.raises(ValueError, match="unknown backend"):
        ev.run_views(tmp_path, views, backend="threads")


def test_tabletop_grasps_happen_on_the_found_table_in_its_frame():
    plane = np.array([0.0, -0.8, -0.6, 0.7])  # camera 0.7 m above a table seen from 37 degrees
    T, table = ev.grasp_world({"support_plane": plane.tolist()})
    assert table
    # The world's z is the table normal, and points on the table sit at z = 0.
    assert np.allclose(T[:3, :3] @ plane[:3], [0, 0, 1], atol=1e-9)
    on_table = -plane[3] * plane[:3]  # the camera's foot on the plane
    assert abs((T[:3, :3] @ on_table + T[:3, 3])[2]) < 1e-9
    assert ev.grasp_world({"support_plane": None}) == (ev.T_WORLD_CAM, False)
