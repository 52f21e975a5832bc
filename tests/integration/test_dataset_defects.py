"""What a new user tripped over in the Dataset tab and with uploads, driven without a browser:
forged dropdown values, the tab's first state, hands in their columns, open in pipeline while
busy, names from uploads in markdown and in the log, "no ground truth" as information."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh
import viser

from shapeviewer.evaluation.methods import METHODS
from shapeviewer.evaluation.records import view_stem
from shapeviewer.evaluation.results import ResultsStore
from shapeviewer.viewer.dataset import ROOT
from shapeviewer.viewer.dataset.controls import CHOOSE_OBJECT, NO_VIEW
from shapeviewer.viewer.sources import markdown_text, one_line, upload_name

from helpers import headless_session, node
from store_factory import VIEWS, make_store, write_view

CAPTURES = Path(__file__).resolve().parents[2] / "static_assets" / "captures"
MILK = CAPTURES / "milk_cartoon_all_small_clorox.pcd"
MUG = CAPTURES / "table_scene_mug_stereo_textured.pcd"
# A die (1.8 cm) with the best grasp of every method: Barrett hands far wider than the object.
SMALL = ("ycb/062_dice", 5)
# A view whose saved partial view is a few points: the pipeline finds no segment in it.
SPARSE = ("pybullet/lego", 2)


@pytest.fixture(scope="module")
def store_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    make_store(root)
    write_view(root, *SMALL, grasp_methods=METHODS)
    write_view(root, *SPARSE)
    points = np.array([[0.0, 0.0, 0.8], [0.01, 0.0, 0.8], [0.0, 0.01, 0.8]])
    trimesh.PointCloud(points).export(root / "meshes" / f"{view_stem(*SPARSE)}__points.ply")
    return root


@pytest.fixture(scope="module")
def app(store_root):
    capture = ResultsStore(store_root).capture(*VIEWS[0])
    with headless_session(cloud=capture, results=store_root) as app:
        yield app


def forge(handle, value) -> None:
    """What viser does when a browser sends ``value`` for ``handle`` (it takes any value): set it,
    then call the handle's callbacks. A callback's exception reaches the test."""
    handle._impl.value = value
    for cb in list(handle._impl.update_cb):
        cb(viser.GuiEvent(None, 0, handle))


# ----------------------------------------------------------------------------------------------
# A fresh tab


def test_the_tab_opens_with_nothing_chosen(store_root):
    capture = ResultsStore(store_root).capture(*VIEWS[0])
    with headless_session(cloud=capture, results=store_root) as app:
        d = app.dataset
        # No view on screen: the Object dropdown chooses nothing (it used to show the first object
        # next to "(no view)", and choosing that object again did nothing).
        assert d.shown is None and not d.active
        assert d.c.object.value == CHOOSE_OBJECT and d.c.view.value == NO_VIEW
        assert set(d.c.object.options[1:]) == set(d.c.object_options)
        assert node(app, "/cloud").visible  # the pipeline's scene, as the dataset is not shown
        first = d.objects[0].name
        assert d.select(first)
        label = next(k for k, v in d.c.object_options.items() if v == first)
        assert d.c.object.value == label and CHOOSE_OBJECT not in d.c.object.options
        assert d.c.view.value.startswith(f"view {d.store.views(first)[0].view} ")
        assert d.active and not node(app, "/cloud").visible
        # A view the store does not have: refused, the dropdowns still show what is on screen.
        assert not d.select(first, 999)
        assert d.c.object.value == label and d.shown_view() == (first, d.store.views(first)[0].view)


# ----------------------------------------------------------------------------------------------
# Forged values


def test_forged_dropdown_values_are_refused_and_the_index_keeps_working(app):
    d = app.dataset
    d.leave()
    c = d.c
    d.refresh_index()
    names = [o.name for o in d.objects]
    dropdowns = (c.split, c.method, c.metric, c.order, c.object, c.view, c.export_kind, c.export_format, c.export_frame)
    for handle in dropdowns:
        label, before = handle.label, handle.value
        app.last_error = None
        forge(handle, "'; DROP TABLE views; --")  # raised KeyError in the callbacks, once
        assert handle.value == before, label
        assert app.last_error is not None and app.last_error.startswith("Unknown choice: " + label), app.last_error
        assert "is not one of its entries" in app.last_error
        d.refresh_index()
        assert [o.name for o in d.objects] == names, label
    # The step buttons, and a range that is no range of the slider.
    app.last_error = None
    forge(c.step, "◀ nowhere")
    assert app.last_error.startswith("Unknown choice: Step")
    before = c.range.value
    forge(c.range, (5.0, -3.0))
    assert c.range.value == before and app.last_error.startswith("Unknown choice: Range")
    # A forged Split that the callbacks have not answered yet: the index filters by the last valid one.
    c.split._impl.value = "nonsense"
    try:
        d.refresh_index()
        assert [o.name for o in d.objects] == names
    finally:
        forge(c.split, "nonsense")
    assert c.split.value == "all objects"
    # Valid choices still act.
    c.split.value = "holdout models"
    assert [o.name for o in d.objects] == ["ycb/006_mustard_bottle"]
    c.split.value = "all objects"
    c.metric.value = "hausdorff_mean_mm"
    assert c.range.max == 100.0 and "H mm" in c.index.content
    c.metric.value = "jaccard"


# ----------------------------------------------------------------------------------------------
# The 3D row


def test_hands_stay_in_their_columns(app):
    d = app.dataset
    d.c.show_grasps.value = True
    try:
        assert d.select(*SMALL)
        drawn, L = d.drawn, d.shown.layout
        kinds = [k for k in L.columns if f"{ROOT}/{k}" in drawn or f"{ROOT}/grasp_{k}_planned" in drawn]
        assert all(f"{ROOT}/grasp_{m}_planned" in drawn for m in METHODS)

        def xs(kind: str) -> np.ndarray:
            parts = []
            for name, h in drawn.items():
                if name == f"{ROOT}/{kind}" or name.startswith(f"{ROOT}/grasp_{kind}_"):
                    parts.append(np.asarray(h.points if kind == "points" else h.vertices)[:, 0])
            return np.concatenate(parts)

        # Left to right, whatever stands in one column (an item and its hands) ends before the next begins.
        for a, b in zip(kinds, kinds[1:]):
            assert xs(a).max() < xs(b).min(), (a, b)
        # The labels stand above the hands.
        hands_top = max(np.asarray(h.vertices)[:, 2].max() for n, h in drawn.items() if "/grasp_" in n)
        for m in METHODS:
            assert drawn[f"{ROOT}/label_{m}"].position[2] > hands_top
    finally:
        d.c.show_grasps.value = False


# ----------------------------------------------------------------------------------------------
# Open in pipeline


def test_a_view_the_pipeline_cannot_load_keeps_the_dataset_on_screen(app):
    d = app.dataset
    assert d.select(*SPARSE)
    before = app.scene
    app.last_error = None
    assert not d.open_in_pipeline()  # three points: no segment to complete
    assert app.last_error is not None and app.last_error.startswith("Could not load the capture")
    # The Dataset tab still shows its view, the pipeline's scene still hidden under it.
    assert d.active and d.shown_view() == SPARSE and node(app, ROOT) is not None
    assert not node(app, "/cloud").visible and app.scene is before


# ----------------------------------------------------------------------------------------------
# Names from uploads


def test_names_are_one_line_and_literal_markdown():
    assert upload_name("C:\\Users\\me\\a\nb.pcd") == "a\\nb.pcd"
    assert upload_name("evil\x1b[31m\u202e.pcd") == "evil\\x1b[31m\\u202e.pcd"
    assert len(upload_name("x" * 5000 + ".pcd")) <= 120 and upload_name("x" * 5000 + ".pcd").endswith(".pcd")
    assert one_line("plain name.pcd") == "plain name.pcd" and one_line(one_line("a\nb")) == "a\\nb"
    markdown_it = pytest.importorskip("markdown_it")
    md = markdown_it.MarkdownIt("commonmark").enable("table")
    for name in (
        '<img src="x" onerror="alert(1)">.pcd',
        "[site](https:example.com).pcd",
        "see https://example.com and www.example.com or me@example.com.pcd",
        "**bold** _it_ `code` <b>.pcd",
        "| a | b |.pcd",
        "&lt;img&gt;.pcd",
    ):
        html = md.renderInline(markdown_text(name))
        assert "<img" not in html and "<a " not in html and "<b>" not in html and "<strong>" not in html, html
        assert "<em>" not in html and "<code>" not in html, html
        # GitHub-flavoured markdown links these in the text itself: an invisible joiner splits them.
        assert not re.search(r"www\.|https?://|\w@\w", html), html
        text = html.replace("&lt;", "<").replace("&gt;", ">").replace("&quot;", '"').replace("&amp;", "&")
        assert text.replace("\u2060", "") == name, (name, html)
    # Catalogue names read the same in the markdown source.
    assert markdown_text("ycb/025_mug") == "ycb/025_mug"


def test_an_upload_name_is_text_in_the_source_panel_and_one_log_line(caplog):
    markdown_it = pytest.importorskip("markdown_it")
    with headless_session(cloud=MILK, results=None) as app:
        forged = "mug\n2026-01-01 CRITICAL forged line <img src=x>[link](https:example.com).pcd"
        assert app.load_upload(forged, MUG.read_bytes())
        source = app.scene.capture.source
        assert (
            "\n" not in source
            and source == "mug\\n2026-01-01 CRITICAL forged line <img src=x>[link](https:example.com).pcd"
        )
        html = markdown_it.MarkdownIt("commonmark").render(app.panel.source.content)
        assert "<img" not in html and "<a " not in html, html
        assert "[link](https:example.com).pcd" in html.replace("\u2060", "")
        # A bad upload is logged (and notified) by its name on one line: no forged log line.
        caplog.clear()
        with caplog.at_level(logging.DEBUG, logger="shapeviewer"):
            assert not app.load_upload("bad\nCRITICAL forged.pcd", b"not a cloud" * 50)
        messages = [r.getMessage() for r in caplog.records]
        assert any("bad\\nCRITICAL forged.pcd" in m for m in messages), messages
        assert not any("\n" in m for m in messages), messages


# ----------------------------------------------------------------------------------------------
# No ground truth


def test_no_ground_truth_on_a_real_capture_is_information(monkeypatch):
    with headless_session(cloud=MILK, results=None) as app:
        told: list[tuple[str, str | None]] = []
        notify = app.audience.notify

        def record(client, title, body, color=None, auto_close=8.0):
            told.append((title, color))
            notify(client, title, body, color, auto_close)

        monkeypatch.setattr(app.audience, "notify", record)
        sid = next(iter(app.scene.segments))
        app.last_error = None
        assert app.grasps.execute(sid, None) is None
        assert told and told[-1][0] == "No ground truth"
        assert told[-1][1] not in ("red", "orange", "yellow")  # nothing failed
        assert app.last_error is None
