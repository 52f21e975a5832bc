"""The whole user path in one real browser: headless Chromium drives the viewer
from upload to the Dataset tab's export, and every file it downloads is parsed.

The steps below run in file order on one server and one page (module fixtures); when a step fails,
the later ones are skipped rather than failing for the same reason. Every action goes through the
page: the file chooser, canvas clicks, buttons, dropdowns, text inputs, the tabs and downloads.
The checks prefer what the browser got (the panel's text, notifications, checkboxes, the files it
saved); where the 3D view is concerned they look at the scene nodes the browser's own session
sent it (:func:`scene_node`). The server state used to aim clicks (where a segment is) comes from
the browser's session (:func:`session_of`).

Order: the app opens on the generated tabletop (seed 0); the user uploads a real capture (no ground
truth), clicks its mug, looks at the CNN grids and fast mesh, makes the detailed mesh and the three
baselines and downloads them; then generates a tabletop again ("New scene", which has true
objects), picks a segment in the dropdown, plans a few grasps, executes them on the true object and
downloads the grasps and the pybullet scene; finally opens the Dataset tab, shows a view and
downloads its mesh, grasps and metrics and the index's CSVs and tables. Screenshots of three steps go
to the test's temporary folder (``e2e*/screenshots``).
"""

from __future__ import annotations

import csv
import io
import json
import re
import time
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pybullet as p
import pytest
import trimesh

from shapeviewer.evaluation.records import KINDS, view_stem
from shapeviewer.grasp.serialize import grasps_from_json

from helpers import (
    BROWSER_WAIT,
    browser_page,
    canvas_point,
    checked,
    choose,
    click,
    click_until,
    dropdown_options,
    dropdown_value,
    free_port,
    load_exported_grasp,
    needs_browser,
    page_shows,
    page_text,
    press,
    reported_camera,
    visible_segment,
    wait_for_frames,
    wait_for_text,
    wait_until,
)
from store_factory import VIEWS, make_store

pytestmark = [pytest.mark.browser, needs_browser]

CAPTURES = Path(__file__).resolve().parents[2] / "static_assets" / "captures"
MUG = CAPTURES / "table_scene_mug_stereo_textured.pcd"  # a real capture shipped in the repository
N_GRASPS = 3  # a short plan: the walk is about the path, not the planner
SEED = 0  # the generated tabletop the app opens on, and "New scene" makes again


# ----------------------------------------------------------------------------------------------
# The two places that know where the server keeps a browser's state.


def session_of(app, client):
    """The session behind browser ``client``: its scene (``.scene.segments``, ``.scene.points_world``),
    ``.segment_centroid_world(sid)`` and ``.pick(origin, direction)``. Used only to aim canvas clicks."""
    return wait_until(lambda: app.session_of(client), BROWSER_WAIT, "the browser's session")


def scene_node(client, name: str):
    """The scene node ``name`` (e.g. ``/fast_mesh/seg_1``) that browser ``client`` was sent, or None:
    its session draws in the tab's own scene."""
    return client.scene.get_handle_by_name(name)


# ----------------------------------------------------------------------------------------------
# The browser


def download(page, button: str, folder: Path) -> Path:
    """Press ``button`` and save the file the browser receives into ``folder``."""
    with page.expect_download(timeout=BROWSER_WAIT * 1000) as info:
        press(page, button)
    path = folder / info.value.suggested_filename
    info.value.save_as(path)
    return path


def settled_camera(client, timeout: float = BROWSER_WAIT):
    """The browser's camera once it has taken the pose the server aimed it at (after a new scene):
    looking at its ``look_at`` point and unchanged for half a second."""
    import viser

    def steady():
        cam = reported_camera(client)
        if cam is None:
            return None
        forward = viser.transforms.SO3(np.asarray(cam.wxyz)).as_matrix()[:, 2]
        to_target = np.asarray(cam.look_at) - np.asarray(cam.position)
        if forward @ to_target < 0.999 * np.linalg.norm(to_target):
            return None
        before = (tuple(cam.position), tuple(cam.wxyz))
        time.sleep(0.5)
        return cam if (tuple(cam.position), tuple(cam.wxyz)) == before else None

    return wait_until(steady, timeout, "the browser's camera to settle on the new scene", step=0.2)


def segment_counts(page) -> dict[int, int]:
    """Segment id -> number of points, read from the Segment dropdown's entries
    (``segment 1 (15215 pts, 13 cm)``)."""
    out = {}
    for text in dropdown_options(page, "Segment"):
        m = re.match(r"segment (\d+) \((\d+) pts", text)
        if m:
            out[int(m.group(1))] = int(m.group(2))
    return out


def shown_segments(page) -> int:
    """The number of segments the Source folder reports."""
    m = re.search(r"·\s*(\d+)\s+segments", page_text(page))
    assert m, "the Source folder shows no segment count"
    return int(m.group(1))


def shot(walk, name: str) -> Path:
    wait_for_frames(walk.page)  # the software renderer has drawn the last nodes
    path = walk.shots / f"{name}.png"
    walk.page.screenshot(path=str(path), timeout=120_000)
    return path


def unlabelled(walk, names: list[str]) -> list[str]:
    """Of the label nodes ``names``, those with no text just above their anchor in a screenshot of
    the page (labels are dark text over the light sky, anchored bottom-centre). Text is counted as
    pixels much darker than the sky around them: software WebGL draws the same label anywhere from
    near-black to mid-grey (luminance 12-98 at its darkest in two runs), the sky is 255."""
    from PIL import Image

    image = np.asarray(Image.open(io.BytesIO(walk.page.screenshot(timeout=120_000))).convert("L"))
    missing = []
    for name in names:
        xy = canvas_point(walk.page, walk.client, np.asarray(scene_node(walk.client, name).position))
        if xy is None:
            continue  # under the panel
        x, y = int(xy[0]), int(xy[1])
        box = image[max(0, y - 60) : y + 5, max(0, x - 60) : x + 60].astype(int)
        if (box < np.median(box) - 80).sum() < 40:
            missing.append(name)
    return missing


# ----------------------------------------------------------------------------------------------
# One server, one page, in order


@pytest.fixture(scope="module")
def walk(tmp_path_factory, request):
    from shapeviewer.viewer import ViewerApp

    root = tmp_path_factory.mktemp("e2e")
    make_store(root / "results")
    # A thin Cloud layer and a small window keep the software-rendered frames quick.
    app = ViewerApp(port=free_port(), seed=SEED, results=root / "results", max_cloud_points=20_000)
    try:
        with browser_page(app, viewport={"width": 1000, "height": 700}, accept_downloads=True) as page:
            client = wait_until(
                lambda: next(iter(app.server.get_clients().values()), None), BROWSER_WAIT, "the browser to connect"
            )
            wait_for_text(page, f"default(seed={SEED})")
            folders = {k: root / k for k in ("downloads", "screenshots")}
            for f in folders.values():
                f.mkdir()
            yield SimpleNamespace(
                app=app,
                page=page,
                client=client,
                downloads=folders["downloads"],
                shots=folders["screenshots"],
                failed_before=request.session.testsfailed,
            )
    finally:
        app.stop()


@pytest.fixture(autouse=True)
def _after_the_previous_step(walk, request):
    """Each step starts where the previous one left the page: skip the rest once one failed."""
    if request.session.testsfailed > walk.failed_before:
        pytest.skip("an earlier step of the walk failed")


# ----------------------------------------------------------------------------------------------
# Pipeline tab: a real capture


def test_upload_a_capture_shows_its_segments(walk):
    page = walk.page
    before = shown_segments(page)
    with page.expect_file_chooser(timeout=BROWSER_WAIT * 1000) as chooser:
        press(page, "Upload capture")
    chooser.value.set_files(str(MUG))
    # The Source folder names the uploaded file instead of the generated scene.
    wait_until(lambda: page_shows(page, MUG.name, not_=f"default(seed={SEED})"), BROWSER_WAIT, "the uploaded scene")
    wait_until(lambda: not page_shows(page, f"Loading {MUG.name}"), BROWSER_WAIT, "the loading notification to close")
    n = shown_segments(page)
    assert n >= 1, (before, n)
    counts = segment_counts(page)
    assert len(counts) == n, counts
    for sid in counts:
        assert scene_node(walk.client, f"/segments/seg_{sid}") is not None, sid
    walk.capture_counts = counts


def test_click_a_segment_shows_cnn_grids_and_fast_mesh(walk):
    page, client = walk.page, walk.client
    session = session_of(walk.app, client)
    cam = settled_camera(client)
    # The largest segment (the mug) that is in view, in front of the others and not under the panel.
    order = sorted(walk.capture_counts, key=lambda s: -walk.capture_counts[s])
    target = visible_segment(page, client, session, cam, order)
    assert target is not None, "no segment of the capture is visible on the canvas"
    sid, xy = target

    def fast_mesh_shown() -> bool:
        return f"Segment {sid}" in page_text(page) and "click → mesh" in page_text(page)

    click_until(page, xy, fast_mesh_shown, f"the timings of segment {sid}'s completion")
    assert dropdown_value(page, "Segment").startswith(f"segment {sid} (")
    for layer in ("cnn_input", "fast_mesh"):
        assert scene_node(client, f"/{layer}/seg_{sid}") is not None, layer
    # The CNN output is off by default: the user ticks it to see the completed grid (drawn then).
    assert checked(page, "CNN input") and checked(page, "Fast mesh") and not checked(page, "CNN output")
    click(page, page.get_by_role("checkbox", name="CNN output", exact=True), "the 'CNN output' checkbox")
    wait_until(lambda: scene_node(client, "/cnn_output").visible, BROWSER_WAIT, "the CNN output layer")
    wait_until(lambda: scene_node(client, f"/cnn_output/seg_{sid}"), BROWSER_WAIT, "the CNN output's cubes")
    walk.capture_segment = sid


def test_detailed_mesh_and_baselines(walk):
    page, sid = walk.page, walk.capture_segment
    click(page, page.get_by_role("checkbox", name="CNN output", exact=True), "the 'CNN output' checkbox")  # the meshes
    for button, title, layer in (
        ("Detailed mesh", "Detailed mesh", "detailed_mesh"),
        ("Partial", "Partial baseline", "partial_mesh"),
        ("Mirror", "Mirror baseline", "mirror_mesh"),
        ("Hull", "Hull baseline", "hull_mesh"),
    ):
        press(page, button)
        wait_for_text(page, f"{title} ready")
        assert re.search(rf"Segment {sid}: [\d,]+ triangles", page_text(page)), title
        # The user asked to see it: its layer's checkbox is ticked in the browser.
        wait_until(lambda title=title: checked(page, title), BROWSER_WAIT, f"the {title!r} checkbox")
        assert scene_node(walk.client, f"/{layer}/seg_{sid}") is not None, layer
        if button == "Detailed mesh":
            assert "Algorithm 1" in page_text(page)
            shot(walk, "1_capture_detailed_mesh")


def test_capture_exports_download_and_parse(walk):
    page, sid, folder = walk.page, walk.capture_segment, walk.downloads
    stem = f"{MUG.stem}_seg{sid}"
    click(page, page.get_by_text("Export", exact=True), "the Export folder")  # it starts closed
    page.get_by_role("button", name="Segment points (PLY)").wait_for(timeout=BROWSER_WAIT * 1000)

    points = download(page, "Segment points (PLY)", folder)
    assert points.name == f"{stem}_points_world.ply"
    cloud = trimesh.load(points)
    assert isinstance(cloud, trimesh.PointCloud) and len(cloud.vertices) == walk.capture_counts[sid]

    grids = download(page, "CNN grids (NPZ)", folder)
    assert grids.name == f"{stem}_grids.npz"
    with np.load(grids) as z:
        assert z["grid_in"].shape == (40, 40, 40) and z["grid_in"].dtype == bool and z["grid_in"].any()
        probabilities = z["probabilities"]
        assert probabilities.shape == (40, 40, 40) and 0.0 <= probabilities.min() <= probabilities.max() <= 1.0
        assert (probabilities > 0.5).sum() >= z["grid_in"].sum() // 2  # the completion fills the seen voxels
        assert z["grid_out"].dtype == bool and (z["grid_out"] >= (probabilities > 0.5)).all()
        assert z["grid_to_camera"].shape == (4, 4) and json.loads(str(z["frame_json"]))

    # Every mesh, in three of the formats (the format is kept between downloads, as a user would).
    for kind, fmt in (("fast", "ply"), ("partial", "ply"), ("hull", "ply"), ("mirror", "stl"), ("detailed", "obj")):
        if dropdown_value(page, "Mesh format") != fmt:
            choose(page, "Mesh format", fmt)
        if dropdown_value(page, "Mesh") != kind:
            choose(page, "Mesh", kind)
        path = download(page, "Mesh", folder)
        assert path.name == f"{stem}_{kind}_world.{fmt}", path.name
        mesh = trimesh.load(path, force="mesh")
        if fmt == "stl":
            mesh.merge_vertices()  # STL stores every triangle's own corners
        assert len(mesh.faces) > 0 and mesh.is_watertight, (kind, fmt)
        assert 0.03 < max(mesh.extents) < 0.5, (kind, mesh.extents)  # a tabletop object, in metres


# ----------------------------------------------------------------------------------------------
# Pipeline tab: a generated tabletop with true objects


def test_plan_grasps_on_a_generated_tabletop(walk):
    page, client = walk.page, walk.client
    page.get_by_role("textbox", name="Seed", exact=True).fill(str(SEED))
    press(page, "New scene")
    wait_until(lambda: page_shows(page, f"default(seed={SEED})", not_=MUG.name), BROWSER_WAIT, "the generated scene")
    counts = segment_counts(page)
    assert len(counts) == shown_segments(page)
    # Pick the largest segment in the dropdown (the other way to choose one): it is completed.
    sid = max(counts, key=counts.get)
    option = next(o for o in dropdown_options(page, "Segment") if o.startswith(f"segment {sid} ("))
    choose(page, "Segment", option)
    wait_until(lambda: f"Segment {sid}" in page_text(page), BROWSER_WAIT, f"segment {sid}'s completion")
    assert scene_node(client, f"/fast_mesh/seg_{sid}") is not None

    grasps = page.get_by_role("textbox", name="Grasps", exact=True)
    grasps.fill(str(N_GRASPS))
    grasps.press("Enter")
    count = session_of(walk.app, client).grasps.panel.count
    wait_until(lambda: count.value == N_GRASPS, BROWSER_WAIT, "the server to have the new grasp count")
    press(page, "Plan grasps")
    wait_for_text(page, "Grasps ready", timeout=120)
    wait_for_text(page, f"Segment {sid}: {N_GRASPS} barrett grasps")
    assert dropdown_value(page, "Grasp").startswith("#1 ")
    assert len(dropdown_options(page, "Grasp")) == N_GRASPS
    assert "Grasp #1" in page_text(page)
    for k in range(N_GRASPS):
        assert scene_node(client, f"/grasps/seg_{sid}/g{k}/hand/palm") is not None, k
    walk.grasp_segment = sid


def test_execute_grasps_on_the_true_object(walk):
    page, sid = walk.page, walk.grasp_segment
    press(page, "Execute all")
    wait_for_text(page, "Executed")
    text = page_text(page)
    assert re.search(rf"Segment {sid} on .+: joint error [\d.]+°, pose error [\d.]+ mm, lifted \d/{N_GRASPS}", text)
    assert "On the ground truth" in text  # the selected grasp's execution, in the Grasps folder
    # The completion's mesh and CNN input layers are switched off to show the true object.
    assert not checked(page, "Fast mesh") and not checked(page, "CNN input")
    shot(walk, "2_tabletop_grasps_executed")


def test_grasp_exports_download_and_parse(walk, tmp_path):
    page, sid, folder = walk.page, walk.grasp_segment, walk.downloads
    stem = f"default_seed{SEED}_seg{sid}_fast_barrett"

    path = download(page, "Grasps (JSON)", folder)
    assert path.name == f"{stem}_grasps.json"
    doc = grasps_from_json(path.read_bytes())  # raises on anything but a shapeviewer.grasps v1 file
    assert len(doc.grasps) == N_GRASPS and all(g.hand == "barrett" for g in doc.grasps)
    assert all(e is not None and e.lift is not None for e in doc.executions), "executions missing"
    assert doc.meta["segment"] == sid and doc.meta["source"] == f"default(seed={SEED})"
    assert doc.meta["ground_truth"]
    for g in doc.grasps:
        T = np.asarray(g.T_world_palm)
        assert T.shape == (4, 4) and np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6)

    path = download(page, "pybullet scene (zip)", folder)
    assert path.name == f"{stem}_pybullet.zip"
    with zipfile.ZipFile(path) as z:
        assert {"object.obj", "object_collision.obj", "object.urdf", "grasps.json"} <= set(z.namelist())
        z.extractall(tmp_path)
    urdf = next((tmp_path / "hands").glob("*.urdf"))
    c = p.connect(p.DIRECT)
    try:
        obj, hand = load_exported_grasp(tmp_path, urdf, c)
        assert obj >= 0 and hand >= 0 and p.getNumJoints(hand, physicsClientId=c) > 0
        # The exported grasp touches the exported object, as planned.
        rows = p.getClosestPoints(hand, obj, 0.005, physicsClientId=c)
        assert rows, "the exported hand is nowhere near the exported object"
    finally:
        p.disconnect(physicsClientId=c)


# ----------------------------------------------------------------------------------------------
# Dataset tab


def test_dataset_tab_shows_a_view_and_exports_it(walk):
    page, folder = walk.page, walk.downloads
    name, view = VIEWS[0]  # the store's first view: all five methods, grasps on Ours-fast
    click(page, page.get_by_role("tab", name="Dataset"), "the Dataset tab")
    wait_for_text(page, name)
    option = next(o for o in dropdown_options(page, "Object") if o.startswith(f"{name} ·"))
    choose(page, "Object", option)
    wait_for_text(page, f"{name} · view {view}")
    assert dropdown_value(page, "View").startswith(f"view {view} ")
    assert scene_node(walk.client, "/dataset/truth") is not None
    shot(walk, "3_dataset_view")
    # Every column's label (method, metrics) is drawn without the user moving the camera.
    labels = [f"/dataset/label_{k}" for k in KINDS if scene_node(walk.client, f"/dataset/label_{k}") is not None]
    assert len(labels) >= 6, labels
    # (Most, not all: a column's label may sit behind another column's hand or frustum.)
    # Software WebGL on a loaded machine can take a while to draw them; a failure names the missing.
    missing: list[str] = []

    def drawn() -> bool:
        missing[:] = unlabelled(walk, labels)
        return len(missing) <= len(labels) // 2

    try:
        wait_until(drawn, BROWSER_WAIT, "the labels drawn")
    except AssertionError as e:
        raise AssertionError(f"{e}; without text above their anchors: {missing}") from None

    stem = view_stem(name, view)
    path = download(page, "Mesh (full resolution)", folder)  # Ours-fast, PLY, camera frame by default
    assert path.name == f"{stem}__Ours-fast_camera.ply", path.name
    mesh = trimesh.load(path)
    assert len(mesh.faces) > 0 and mesh.is_watertight

    path = download(page, "Grasps of this method (JSON)", folder)
    assert path.name == f"{stem}__Ours-fast_grasps.json", path.name
    assert len(grasps_from_json(path.read_bytes()).grasps) >= 1

    path = download(page, "View metrics (CSV)", folder)
    assert path.name == f"{stem}_metrics.csv", path.name
    rows = list(csv.DictReader(io.StringIO(path.read_text())))
    methods = {r.get("method") for r in rows}
    assert {"Partial", "Mirror", "Hull", "Ours-fast", "Ours-detailed"} <= methods, methods
    # The Jaccard the page shows for Ours-fast is the one in the downloaded metrics.
    ours = next(r for r in rows if r.get("method") == "Ours-fast")
    assert f"{float(ours['jaccard']):.3f}" in page_text(page)

    # The index's exports: its objects, their views' rows, the paper's tables.
    path = download(page, "Index (CSV)", folder)
    index = list(csv.DictReader(io.StringIO(path.read_text())))
    assert path.name == "results_index.csv" and name in {r["object"] for r in index}
    assert len(index) == len({n for n, _ in VIEWS}), index
    path = download(page, "Metrics of the index's views (CSV)", folder)
    assert path.name == "results_rows.csv"
    assert len(list(csv.DictReader(io.StringIO(path.read_text())))) == 5 * len(VIEWS)  # five methods a view
    path = download(page, "Tables I-IV (markdown)", folder)
    assert path.name == "results_tables.md"
    assert "## Table I" in path.read_text() and "## Table IV" in path.read_text()
