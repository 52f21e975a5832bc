"""Completion uncertainty in a real browser: headless Debian Chromium (Playwright) ticks
the Confidence layer and presses "Rank by robustness", and reads what the panel then shows.

The app runs in this process: the test completes a segment and plans its grasps server-side (the
clicks that do those are tested in ``test_browser.py``) and checks the scene and grasps there.
"""

from __future__ import annotations

import pytest

from helpers import (
    BROWSER_WAIT,
    browser_page,
    browser_session,
    checked,
    click,
    dropdown_value,
    free_port,
    needs_browser,
    node,
    page_text,
    press,
    wait_for_text,
    wait_until,
)

pytestmark = pytest.mark.browser


@needs_browser
def test_confidence_checkbox_and_rank_by_robustness_button():
    from shapeviewer.grasp.robust import rank_robust
    from shapeviewer.viewer import ViewerApp

    # A thin Cloud layer keeps the first software-rendered WebGL frame quick.
    viewer = ViewerApp(port=free_port(), seed=0, max_cloud_points=20_000)
    try:
        with browser_page(viewer) as page:
            app = browser_session(viewer)  # the browser tab's own session
            sid = max(app.scene.segments, key=lambda s: len(app.scene.points_world[s]))
            assert app.complete(sid) is not None

            # Ticking Confidence shades the completion and puts its figures in the stage panel.
            click(page, page.get_by_role("checkbox", name="Confidence", exact=True), "the 'Confidence' checkbox")
            wait_for_text(page, "confidence of the completion")
            text = page_text(page)
            assert "unseen side" in text and "are a guess" in text
            assert checked(page, "Confidence") and node(app, f"/confidence/seg_{sid}") is not None

            job = app.plan_grasps(sid, "barrett", "fast", 3, seed=0)
            assert job is not None and job.error is None and job.result is not None and job.result.grasps
            lifts = [g.lift for g in job.result.grasps]
            # The planner lifted its grasps on the fast mesh; the browser says how the selected one did.
            assert all(lift is not None for lift in lifts)
            wait_for_text(page, "Lift check on the fast mesh:")
            press(page, "Rank by robustness")  # waits until the button is enabled: there are grasps
            job = wait_until(
                lambda: app.grasps.job if app.grasps.job.kind == "rank" else None,
                BROWSER_WAIT,
                "the click to start ranking",
            )
            assert job.wait(600), "ranking did not finish"
            assert job.error is None and job.result is not None
            # Ranked with those of the wider search when no grasp held up on the samples.
            best = rank_robust(job.result, [g.lift for g in app.grasps.sets[sid].grasps])[0]
            holds = f"holds {round(8 * job.result[best].fraction)}/8"
            # The browser lists the most robust grasp first and describes it.
            wait_for_text(page, f"Robustness: rank 1 of {len(job.result)} · {holds} sample completions")
            assert "Ranked by robustness" in page_text(page)
            shown = dropdown_value(page, "Grasp")
            # The most robust grasp is among those lifted on the samples, and says so.
            tests = 8 * job.result[best].lift_rounds  # one lift per sample and round
            assert job.result[best].lift_tests == tests
            lifted = f"lifted {round(tests * job.result[best].lifted)}/{tests}"
            assert shown.startswith(f"#{best + 1} ") and shown.endswith(f"{holds} · {lifted}")
    finally:
        viewer.stop()
