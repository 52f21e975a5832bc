"""The Dataset tab without a browser: the index of a small store, a view's scene nodes in the
common display pose, stepping, grasps, exports, open in pipeline, a store growing while shown."""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
import trimesh

from shapeviewer.evaluation.methods import METHODS
from shapeviewer.evaluation.records import view_stem
from shapeviewer.evaluation.results import ResultsStore
from shapeviewer.grasp.serialize import grasps_from_json
from shapeviewer.perception.camera import transform_points
from shapeviewer.viewer import ViewerApp
from shapeviewer.viewer.dataset import ROOT, layout_view

from helpers import free_port, headless_session, node
from store_factory import VIEWS, jaccard_of, make_store, write_view

PIPELINE = ("/cloud", "/segments", "/fast_mesh")


@pytest.fixture(scope="module")
def store_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    make_store(root)
    return root


@pytest.fixture(scope="module")
def app(store_root):
    # The pipeline shows one of the store's own captures: quicker to build than the default scene.
    capture = ResultsStore(store_root).capture(*VIEWS[0])
    with headless_session(cloud=capture, results=store_root) as app:
        yield app


def test_index_lists_the_store_objects(app):
    d = app.dataset
    # Default order: worst mean Ours-fast Jaccard first.
    names = [o.name for o in d.objects]
    assert sorted(names) == sorted({n for n, _ in VIEWS})
    means = [o.mean("Ours-fast", "jaccard") for o in d.objects]
    assert means == sorted(means)
    for n in names:
        assert n in d.c.index.content
    assert d.c.object.options == ("(choose an object)", *d.c.object_options) and len(d.c.object_options) == len(names)
    d.c.search.value = "mug"
    assert [o.name for o in d.objects] == ["ycb/025_mug"]
    d.c.search.value = ""
    d.c.split.value = "holdout models"
    assert [o.name for o in d.objects] == ["ycb/006_mustard_bottle"]
    d.c.split.value = "all objects"
    assert "Table I" in d.c.summary.content and "Table IV" in d.c.summary.content
    # The per-object bars are drawn in the background for the latest index.
    deadline = time.monotonic() + 20
    while d.bars_drawn != d.bars.key and time.monotonic() < deadline:
        time.sleep(0.1)
    assert d.bars_drawn == d.bars.key and d.c.bars_image is not None and d.c.bars_image.image.shape[1] > 300


def test_select_draws_the_view_side_by_side(app):
    d = app.dataset
    name, view = VIEWS[2]  # Mirror failed on this one
    assert d.select(name, view)
    assert d.active and not node(app, "/cloud").visible and node(app, ROOT).visible
    drawn = d.drawn
    for kind in ("truth", "points", "Partial", "Ours-fast", "Ours-detailed"):
        assert f"{ROOT}/{kind}" in drawn and f"{ROOT}/label_{kind}" in drawn, kind
    assert f"{ROOT}/Mirror" not in drawn and "failed" in drawn[f"{ROOT}/label_Mirror"].text
    j = jaccard_of(name, view, "Ours-fast")
    assert f"J {j:.2f}" in drawn[f"{ROOT}/label_Ours-fast"].text
    assert f"{ROOT}/sensor" in drawn
    # Left to right as in the paper's Fig. 1, in one common pose: every completion is its truth-aligned
    # box moved by the same map as the truth, one column further right.
    xs = [
        np.asarray(drawn[f"{ROOT}/{k}"].vertices if k != "points" else drawn[f"{ROOT}/{k}"].points).mean(0)[0]
        for k in ("truth", "points", "Partial", "Ours-fast", "Ours-detailed")
    ]
    assert xs == sorted(xs)
    L = d.shown.layout
    assert np.allclose(L.T_display_cam["Ours-fast"][:3, :3], L.T_display_cam["truth"][:3, :3])
    truth = np.asarray(drawn[f"{ROOT}/truth"].vertices)
    assert truth[:, 2].min() == pytest.approx(0.0, abs=1e-6)  # standing on the floor
    # The browser camera looks at the side the sensor did not see: sensor and camera on opposite sides.
    assert L.sensor_position[1] > L.columns["points"][1] and L.camera_position[1] < 0
    assert "| Mirror | failed |" in d.c.details.content


def test_layout_faces_the_unseen_side_towards_the_camera():
    # Sensor on the object's +x side, level: the camera must stand on the -x side of the object.
    T_cam_obj = np.eye(4)
    T_cam_obj[:3, :3] = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])  # camera looks along -x
    T_cam_obj[:3, 3] = [0.0, 0.0, 1.0]
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.2))
    truth_cam = transform_points(T_cam_obj, box.vertices)
    L = layout_view(T_cam_obj, truth_cam, {"truth": truth_cam}, ("truth",))
    R_display_obj = (L.T_display_cam["truth"] @ T_cam_obj)[:3, :3]
    sensor_obj = np.linalg.inv(T_cam_obj)[:3, 3]
    assert sensor_obj[0] > 0.9  # the sensor was on +x of the object
    # Where the object's -x (unseen) side goes in the display frame: towards the camera (-y), turned a bit.
    unseen = R_display_obj @ np.array([-1.0, 0.0, 0.0])
    to_camera = (L.camera_position - L.look_at) / np.linalg.norm(L.camera_position - L.look_at)
    assert unseen[1] < -0.7 and unseen @ to_camera > 0.5
    assert R_display_obj @ np.array([0.0, 0.0, 1.0]) == pytest.approx([0.0, 0.0, 1.0])  # still upright


def test_grasps_are_drawn_planned_and_executed(app):
    d = app.dataset
    name, view = VIEWS[0]
    d.c.show_grasps.value = True
    assert d.select(name, view)
    drawn = d.drawn
    for m in ("Ours-fast", "Partial"):
        for tag in ("planned", "executed"):
            h = drawn[f"{ROOT}/grasp_{m}_{tag}"]
            centre = np.asarray(h.vertices).mean(0)
            assert abs(centre[0] - d.shown.layout.columns[m][0]) < d.shown.layout.spacing / 2, (m, tag)
        assert "2.9° · 5.0 mm" in drawn[f"{ROOT}/label_{m}"].text
    assert f"{ROOT}/grasp_Mirror_planned" not in drawn
    assert "| Fast | 2 | 2.9 | 5.0 | 50% |" in d.c.details.content
    d.c.show_grasps.value = False
    assert d.select(name, view) and f"{ROOT}/grasp_Partial_planned" not in d.drawn


def test_step_through_views_and_objects(app):
    d = app.dataset
    assert d.select("ycb/025_mug")
    first = d.shown.info.view
    assert d.step("view", 1) and d.shown.info.view != first and d.shown.info.object == "ycb/025_mug"
    assert d.step("view", 1) and d.shown.info.view == first  # wraps around
    order = [o.name for o in d.objects]
    assert d.step("object", 1) and d.shown.info.object == order[(order.index("ycb/025_mug") + 1) % len(order)]
    assert d.step("object", -1) and d.shown.info.object == "ycb/025_mug"
    assert not d.select("ycb/003_cracker_box")  # no results: nothing changes
    assert d.shown.info.object == "ycb/025_mug"


def test_exports(app, store_root):
    d = app.dataset
    name, view = VIEWS[0]
    d.select(name, view)
    stem = view_stem(name, view)
    fname, data = d.export_bytes("mesh", "truth", "ply", "camera")
    assert fname == f"{stem}__truth_camera.ply"
    stored = trimesh.load(store_root / "meshes" / f"{stem}__truth.ply")
    got = trimesh.load(io.BytesIO(data), file_type="ply")
    assert np.allclose(got.vertices, stored.vertices) and len(got.faces) == len(stored.faces)
    fname, data = d.export_bytes("mesh", "Ours-fast", "obj", "object")
    got = trimesh.load(io.BytesIO(data), file_type="obj", force="mesh")
    assert np.allclose(got.bounds.mean(0), 0.0, atol=0.01)  # the object frame: box centred on the origin
    fname, data = d.export_bytes("mesh", "points")
    assert fname.endswith("__points_camera.ply") and len(trimesh.load(io.BytesIO(data), file_type="ply").vertices)
    fname, data = d.export_bytes("grasps", "Partial")
    assert len(grasps_from_json(data).grasps) == 2
    with pytest.raises(ValueError, match="No grasps"):
        d.export_bytes("grasps", "Mirror")
    fname, data = d.export_bytes("view_csv")
    assert fname == f"{stem}_metrics.csv" and data.decode().count("\n") == 1 + len(METHODS)
    _, data = d.export_bytes("index_csv")
    lines = data.decode().splitlines()
    assert len(lines) == 1 + len(d.objects) and lines[0].startswith("object,split,source,extent_x_m")
    assert any(line.startswith("ycb/025_mug,train,ycb,") for line in lines)
    _, data = d.export_bytes("rows_csv")
    assert data.decode().count("\n") == 1 + len(METHODS) * len(VIEWS)
    _, data = d.export_bytes("tables")
    assert b"Table III" in data


def test_open_in_pipeline(app):
    d = app.dataset
    name, view = VIEWS[3]
    d.select(name, view)
    assert d.open_in_pipeline()
    assert not d.active and node(app, ROOT) is None  # taken off the scene
    assert all(node(app, k).visible for k in PIPELINE)
    assert app.scene.capture.source.endswith(f"{view_stem(name, view)}__points.ply")
    assert len(app.scene.segments) == 1  # the lone object, no table
    sid = next(iter(app.scene.segments))
    assert app.complete(sid) is not None


def test_the_index_grows_while_a_run_adds_views(app, store_root):
    d = app.dataset
    before = d.store.counts()["views"]
    write_view(store_root, "ycb/035_power_drill", 2)
    (store_root / "views" / "half.json").write_text('{"object": "ycb/035_power_drill", "view": 9, "ro')
    d.refresh()
    assert d.store.counts()["views"] == before + 1
    assert "ycb/035_power_drill" in [o.name for o in d.objects]
    assert "1 unreadable view file" in d.c.status.content
    assert d.select("ycb/035_power_drill", 2)


def test_back_to_the_pipeline_restores_its_layers(app):
    d = app.dataset
    app.panel.layers["segments"].value = False
    d.select(*VIEWS[0])
    assert not node(app, "/segments").visible and not node(app, "/cloud").visible
    app.panel.layers["cloud"].value = True  # toggled while the dataset is shown: stays hidden
    assert not node(app, "/cloud").visible
    d.leave()
    assert node(app, "/cloud").visible and not node(app, "/segments").visible  # as their checkboxes say
    app.panel.layers["segments"].value = True
    assert node(app, "/segments").visible


def test_bad_results_folder_is_a_clear_error(tmp_path):
    from shapeviewer.perception.capture import Capture

    pts = np.random.default_rng(0).normal([0.0, 0.0, 1.0], 0.02, (500, 3))
    with pytest.raises(FileNotFoundError, match="results folder not found"):
        ViewerApp(port=free_port(), cloud=Capture(pts, source="blob"), results=tmp_path / "missing")


def test_serve_with_a_missing_results_folder_says_so(tmp_path, capsys):
    from shapeviewer.cli import main

    assert main(["serve", "--port", str(free_port()), "--results", str(tmp_path / "missing")]) == 2
    assert "results folder not found" in capsys.readouterr().err
