"""Per-browser sessions: two tabs on one server each keep their own capture, completions and
jobs; one tab's long job does not hold up the other's click; a closed tab frees its session."""

from __future__ import annotations

import gc
import threading
import time
import weakref
from pathlib import Path

import pytest

from helpers import CHROMIUM, CHROMIUM_ARGS, free_port, job_running, needs_browser, node, sync_playwright, wait_until

CAPTURES = Path(__file__).resolve().parents[2] / "static_assets" / "captures"
MUG = CAPTURES / "table_scene_mug_stereo_textured.pcd"


def largest(session) -> int:
    return max(session.scene.segments, key=lambda s: len(session.scene.points_world[s]))


@needs_browser
@pytest.mark.browser
def test_two_tabs_keep_their_own_scene_and_jobs(tmp_path):
    from shapeviewer.viewer import ViewerApp

    viewer = ViewerApp(port=free_port(), seed=0, max_cloud_points=20_000, results=None)
    assert sync_playwright is not None
    try:
        with sync_playwright() as p:
            # Two browsers: viser counts a tab as connected once it reports its camera, which a
            # second tab of one headless browser does not do while the first one draws.
            browsers = [p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS) for _ in range(2)]
            try:
                pages, sessions = [], []
                for browser in browsers:
                    known = set(viewer.sessions)
                    page = browser.new_page(viewport={"width": 1100, "height": 760})
                    page.goto(viewer.url)
                    session = wait_until(
                        lambda known=known: next(
                            (s for c, s in viewer.sessions.items() if c not in known and s.scene is not None), None
                        ),
                        60,
                        f"the session of tab {len(pages) + 1}",
                    )
                    pages.append(page)
                    sessions.append(session)
                a, b = sessions
                assert a is not b and a.scene is b.scene  # the default scene is shared, read-only

                # Tab A uploads another capture; tab B keeps the default scene.
                default = b.scene
                file_input = pages[0].locator("input[type=file]")
                file_input.first.wait_for(state="attached", timeout=30_000)
                file_input.first.set_input_files(str(MUG))
                wait_until(lambda: a.scene is not default, 60, "tab A's uploaded scene")
                assert a.scene.capture.source == MUG.name and b.scene is default
                pages[1].get_by_text("default(seed=0)").first.wait_for(timeout=20_000)
                pages[0].get_by_text(MUG.name).first.wait_for(timeout=20_000)
                assert pages[1].get_by_text(MUG.name).count() == 0

                # Both complete at once; each gets its own completion, drawn only in its own tab.
                done: dict[str, object] = {}
                threads = [
                    threading.Thread(target=lambda s=s, k=k: done.__setitem__(k, s.complete(largest(s))))
                    for s, k in ((a, "a"), (b, "b"))
                ]
                for t in threads:
                    t.start()
                for t in threads:
                    t.join(120)
                ca, cb = done["a"], done["b"]
                assert ca is not None and cb is not None
                assert set(a.completions) == {ca.segment_id} and set(b.completions) == {cb.segment_id}
                assert a.selected == ca.segment_id and b.selected == cb.segment_id
                for s, c in ((a, ca), (b, cb)):
                    assert node(s, f"/fast_mesh/seg_{c.segment_id}") is not None
                # The nodes are the tab's own: the server-wide scene has none of them.
                assert viewer.server.scene.get_handle_by_name(f"/fast_mesh/seg_{ca.segment_id}") is None

                # A long job in tab A does not hold up a click in tab B.
                with job_running(a):
                    t0 = time.perf_counter()
                    assert b.complete(largest(b)) is not None
                    assert time.perf_counter() - t0 < 30
                    assert a.jobs.busy  # still running
                time.sleep(1)
                pages[0].screenshot(path=str(tmp_path / "tab_a.png"), timeout=120_000)
                pages[1].screenshot(path=str(tmp_path / "tab_b.png"), timeout=120_000)

                # Closing tab A ends its session and frees it.
                gone = weakref.ref(a)
                cid_a = a.audience.client_id
                # Drop this test's own references to it (the thread lambdas hold it as a default too).
                sessions.clear()
                threads.clear()
                done.clear()
                a = ca = s = None
                pages[0].close()
                wait_until(lambda: cid_a not in viewer.sessions, 30, "tab A's session to close")
                assert b.scene is default and b.audience.client_id in viewer.sessions

                def freed() -> bool:
                    gc.collect()
                    return gone() is None

                wait_until(freed, 30, "tab A's session to be freed")
            finally:
                for browser in browsers:
                    browser.close()
    finally:
        viewer.stop()
