"""What a new user saw go wrong in the Dataset tab and with uploads, checked in headless Chromium.

One viewer and one page serve the whole module (a software-rendered page is slow to start): the
tests run in file order, each leaving the page in a state the next one can start from.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from shapeviewer.evaluation.results import ResultsStore
from shapeviewer.viewer.dataset.controls import CHOOSE_OBJECT
from shapeviewer.viewer.dataset.summary import TABLE_CLASS

from helpers import (
    BROWSER_WAIT,
    browser_page,
    browser_session,
    choose,
    click,
    dropdown_value,
    free_port,
    needs_browser,
    page_text,
    press,
    wait_for_frames,
    wait_for_text,
    wait_until,
)
from store_factory import VIEWS, make_store

pytestmark = [pytest.mark.browser, needs_browser]

MUG = Path(__file__).resolve().parents[2] / "static_assets" / "captures" / "table_scene_mug_stereo_textured.pcd"
# Upload notifications viser's own upload button shows.
VISER_UPLOAD_DONE = "File uploaded successfully"


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """``(page, session, viewer, screenshot folder)``: one browser tab on a viewer with a small store."""
    from shapeviewer.viewer import ViewerApp

    root = tmp_path_factory.mktemp("results")
    make_store(root)
    shots = tmp_path_factory.mktemp("shots")
    # The Pipeline tab shows one of the store's own captures: small, quick to draw.
    viewer = ViewerApp(port=free_port(), cloud=ResultsStore(root).capture(*VIEWS[0]), results=root)
    try:
        with browser_page(viewer, viewport={"width": 1280, "height": 900}) as page:
            yield page, browser_session(viewer), viewer, shots
    finally:
        viewer.stop()


def tab_selected(page, label: str) -> bool:
    return page.get_by_role("tab", name=label, exact=True).first.get_attribute("aria-selected") == "true"


def notification_texts(page) -> list[str]:
    """The text of every notification on the page."""
    return page.evaluate(
        "() => [...document.querySelectorAll('.mantine-Notification-root')].map(n => n.innerText.trim())"
    )


def upload(page, name: str, content: bytes) -> None:
    """Pick a file called ``name`` holding ``content`` in viser's (hidden) upload input."""
    file_input = page.locator("input[type=file]").first
    file_input.wait_for(state="attached", timeout=BROWSER_WAIT * 1000)
    file_input.set_input_files(files=[{"name": name, "mimeType": "application/octet-stream", "buffer": content}])


def test_a_bad_upload_says_one_thing_only(walk):
    page, app, _viewer, _shots = walk
    before = app.scene
    upload(page, "garbage.pcd", bytes(range(256)) * 40)
    wait_for_text(page, "Could not load the capture")

    def settled() -> bool:
        notes = notification_texts(page)
        return not any("Loading garbage.pcd" in n or "Uploading garbage.pcd" in n for n in notes)

    # viser's own upload notification ("Uploading garbage.pcd" ... "File uploaded successfully.")
    # closes by itself 4 s after the upload; the app takes it down at once (a busy page may draw it
    # a moment late, so it is taken down again shortly after).
    wait_until(settled, 2.5, "the upload and loading notifications to close")
    notes = notification_texts(page)
    assert not any(VISER_UPLOAD_DONE in n for n in notes), notes
    assert sum("garbage.pcd" in n for n in notes) == 1, notes  # the error, and nothing else about the file
    assert app.scene is before


def test_an_upload_name_is_shown_as_text(walk):
    page, app, _viewer, _shots = walk
    before = app.scene
    # (A file name holds no "/": the browser sends the name alone.)
    name = '<img src="x" id="forged"> [site](https:example.com) www.example.com **bold**.pcd'
    upload(page, name, MUG.read_bytes())
    wait_until(lambda: app.scene is not before, BROWSER_WAIT, "the uploaded scene")
    wait_until(lambda: "example" in app.panel.source.content, BROWSER_WAIT, "the Source panel's new text")
    # The Source panel (not a notification, whose text is never markup) shows the name as typed.
    page.wait_for_function(
        """t => [...document.querySelectorAll('p')].some(
             p => !p.closest('.mantine-Notification-root') && p.innerText.replace(/\u2060/g, '').includes(t))""",
        arg="example.com",
        polling=500,
        timeout=BROWSER_WAIT * 1000,
    )
    shown = page.evaluate(
        """() => [...document.querySelectorAll('p')]
             .filter(p => !p.closest('.mantine-Notification-root') && p.innerText.includes('example'))
             .map(p => p.innerText.replace(/\u2060/g, ''))"""
    )
    assert any(name in text for text in shown), shown
    # Nothing of it became markup: no image, no link.
    assert page.locator("#forged").count() == 0 and page.locator("img[src='x']").count() == 0
    assert page.locator("a[href*='example.com']").count() == 0


def test_the_dataset_tab_opens_with_nothing_chosen_and_choosing_shows_a_view(walk):
    page, app, _viewer, shots = walk
    d = app.dataset
    click(page, page.get_by_role("tab", name="Dataset", exact=True), "the Dataset tab")
    page.get_by_role("combobox", name="Object", exact=True).filter(visible=True).first.wait_for(
        timeout=BROWSER_WAIT * 1000
    )
    # Nothing is chosen, nothing is shown: the Object dropdown does not claim an object.
    assert dropdown_value(page, "Object") == CHOOSE_OBJECT
    assert dropdown_value(page, "View") == "(no view)" and not d.active
    # Choosing the first object of the list (the one the dropdown used to show) shows its first view.
    first = d.objects[0]
    label = next(k for k, v in d.c.object_options.items() if v == first.name)
    choose(page, "Object", label)
    wait_until(lambda: d.active and d.shown_view() is not None, BROWSER_WAIT, "the first object's view")
    assert d.shown_view() == (first.name, d.store.views(first.name)[0].view)
    wait_until(lambda: dropdown_value(page, "View").startswith("view "), BROWSER_WAIT, "the View dropdown")
    assert not app.drawing.visible  # the pipeline's scene is hidden under the dataset
    wait_for_frames(page)
    page.screenshot(path=str(shots / "chosen.png"), timeout=120_000)


def test_tables_have_room_between_their_columns(walk):
    page, app, _viewer, shots = walk
    d = app.dataset
    assert d.select(*VIEWS[0])  # the view with grasps: the details hold both tables
    click(page, page.get_by_text("Summary", exact=True), "the Summary folder")
    wait_for_text(page, "Table IV")
    tables = page.locator(f".{TABLE_CLASS} table").filter(visible=True)
    wait_until(lambda: tables.count() >= 3, BROWSER_WAIT, "the index, view and summary tables")
    # Every two neighbouring cells of a row: their texts stand apart ("1.9 | 100%" never reads "1.9100%").
    gaps = page.evaluate(
        """cls => {
          const textBox = cell => {
            const r = document.createRange();
            r.selectNodeContents(cell);
            const b = r.getBoundingClientRect();
            return b.width > 0 ? b : null;
          };
          const out = [];
          for (const table of document.querySelectorAll(`.${cls} table`)) {
            if (table.offsetParent === null) continue;  // a hidden tab or closed folder
            for (const row of table.rows) {
              const boxes = [...row.cells].map(textBox);
              for (let i = 0; i + 1 < boxes.length; i++)
                if (boxes[i] && boxes[i + 1]) out.push([boxes[i + 1].left - boxes[i].right, row.innerText]);
            }
          }
          return out;
        }""",
        TABLE_CLASS,
    )
    assert gaps and min(g for g, _ in gaps) >= 6, sorted(gaps)[:3]
    # The index's last column header is on screen, inside the panel, not cut off at its edge.
    clipped = page.evaluate(
        """cls => {
          const table = [...document.querySelectorAll(`.${cls} table`)].find(t => t.offsetParent !== null);
          const th = table.rows[0].cells[table.rows[0].cells.length - 1];
          const r = th.getBoundingClientRect(), box = table.parentElement.getBoundingClientRect();
          return [r.right - box.right, th.innerText];
        }""",
        TABLE_CLASS,
    )
    assert clipped[0] <= 0.5, clipped
    wait_for_frames(page)
    page.screenshot(path=str(shots / "tables.png"), full_page=True, timeout=120_000)


def test_open_in_pipeline_brings_the_pipeline_tab_to_the_front(walk):
    page, app, _viewer, shots = walk
    d = app.dataset
    name, view = VIEWS[3]
    assert d.select(name, view)
    assert tab_selected(page, "Dataset")
    press(page, "Open in pipeline")
    wait_until(lambda: tab_selected(page, "Pipeline"), BROWSER_WAIT, "the Pipeline tab to be in front")
    wait_until(lambda: not d.active, BROWSER_WAIT, "the dataset to leave the scene")
    assert app.scene.capture.source.endswith("__points.ply") and app.drawing.visible
    page.get_by_role("button", name="Upload capture").filter(visible=True).first.wait_for(timeout=BROWSER_WAIT * 1000)
    assert "switch to the Pipeline tab" not in page_text(page)
    wait_for_frames(page)
    page.screenshot(path=str(shots / "pipeline.png"), timeout=120_000)
