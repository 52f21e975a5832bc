"""The Dataset tab in a real browser: headless Chromium walks from the index to a view and
downloads a mesh."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from shapeviewer.evaluation.records import view_stem
from shapeviewer.evaluation.results import ResultsStore

from helpers import BROWSER_WAIT, browser_page, browser_session, free_port, needs_browser, wait_for_frames, wait_until
from store_factory import VIEWS, make_store

pytestmark = pytest.mark.browser


@needs_browser
def test_index_to_view_to_mesh_download(tmp_path):
    from shapeviewer.viewer import ViewerApp

    root = tmp_path / "results"
    make_store(root)
    name, view = VIEWS[0]
    # The pipeline tab shows one of the store's own captures: small, quick to draw.
    viewer = ViewerApp(port=free_port(), cloud=ResultsStore(root).capture(name, view), results=root)
    try:
        with browser_page(viewer, viewport={"width": 1100, "height": 760}, accept_downloads=True) as page:
            app = browser_session(viewer)  # the browser tab's own session

            page.get_by_role("tab", name="Dataset").click()
            # The index lists the store's objects; pick the mug in the Object dropdown.
            page.get_by_text(name, exact=True).first.wait_for(timeout=BROWSER_WAIT * 1000)
            page.get_by_role("combobox", name="Object").click()
            page.get_by_role("option", name=f"{name} ·").first.click()
            wait_until(
                lambda: app.dataset.shown is not None and app.dataset.shown.info.object == name,
                BROWSER_WAIT,
                "the view to be shown",
            )
            assert app.dataset.active and app.dataset.shown.info.view == view
            assert "/dataset/truth" in app.dataset.drawn

            # Export the ground truth (full resolution, camera frame) through a browser download.
            # (The Pipeline tab has a Mesh dropdown too, hidden in its tab.)
            page.get_by_role("combobox", name="Mesh").filter(visible=True).click()
            page.get_by_role("option", name="truth", exact=True).click()
            wait_until(lambda: app.dataset.c.export_kind.value == "truth", BROWSER_WAIT, "the mesh choice")
            with page.expect_download(timeout=BROWSER_WAIT * 1000) as info:
                page.get_by_role("button", name="Mesh (full resolution)").click()
            download = info.value
            stem = view_stem(name, view)
            assert download.suggested_filename == f"{stem}__truth_camera.ply"
            path = tmp_path / download.suggested_filename
            download.save_as(path)
            got = trimesh.load(path)
            stored = trimesh.load(root / "meshes" / f"{stem}__truth.ply")
            assert len(got.faces) == len(stored.faces) and np.allclose(got.vertices, stored.vertices)
            wait_for_frames(page)  # the view is drawn before the screenshot
            page.screenshot(path=str(tmp_path / "dataset.png"), timeout=120_000)
    finally:
        viewer.stop()
