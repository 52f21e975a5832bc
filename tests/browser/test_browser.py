"""The viewer in a real browser: headless Debian Chromium (Playwright) clicks a segment and a
grasp's hand on the canvas, and the Plan grasps button.

The app runs in this process, so the test reads the browser's camera server-side
(``client.camera``), projects a segment's centroid (world frame) to canvas pixels, clicks there,
and waits for the completion's scene nodes to appear on the server.
"""

from __future__ import annotations

import pytest

from helpers import (
    BROWSER_WAIT,
    browser_page,
    browser_session,
    canvas_point,
    click_until,
    free_port,
    needs_browser,
    node,
    reported_camera,
    visible_segment,
    wait_for_frames,
    wait_until,
)

pytestmark = pytest.mark.browser


@needs_browser
def test_click_segment_completes_it(tmp_path):
    from shapeviewer.viewer import ViewerApp

    # A thin Cloud layer keeps the first software-rendered WebGL frame quick.
    viewer = ViewerApp(port=free_port(), seed=0, max_cloud_points=20_000)
    try:
        with browser_page(viewer) as page:
            app = browser_session(viewer)  # the browser tab's own session
            client = app.audience.client
            cam = wait_until(lambda: reported_camera(client), BROWSER_WAIT, "the browser's camera")
            # Click the largest segment that is in view, not hidden behind another one and
            # not under the control panel.
            order = sorted(app.scene.segments, key=lambda s: -len(app.scene.points_world[s]))
            target = visible_segment(page, client, app, cam, order)
            assert target is not None, "no segment is visible on the canvas"
            sid, xy = target
            # The app records the completion once all its nodes are added.
            click_until(page, xy, lambda: sid in app.completions, f"the completion of segment {sid}")
            for layer in ("fast_mesh", "cnn_input"):
                assert node(app, f"/{layer}/seg_{sid}") is not None
            assert app.selected == sid
            assert app.last_timings["click_to_mesh"] > 0
            wait_for_frames(page)  # the browser has drawn the new nodes before the screenshot
            page.screenshot(path=str(tmp_path / "completed.png"), timeout=120_000)
    finally:
        viewer.stop()


@needs_browser
def test_plan_grasps_button_draws_hands_and_a_click_on_a_hand_selects_it(tmp_path):
    from shapeviewer.grasp.hands import get_hand
    from shapeviewer.perception.camera import transform_points
    from shapeviewer.viewer import ViewerApp
    from shapeviewer.viewer.grasps import hand_skeleton
    from shapeviewer.viewer.rays import ray_through

    viewer = ViewerApp(port=free_port(), seed=0, max_cloud_points=20_000)
    try:
        with browser_page(viewer) as page:
            app = browser_session(viewer)  # the browser tab's own session
            sid = max(app.scene.segments, key=lambda s: len(app.scene.points_world[s]))
            assert app.complete(sid) is not None and app.selected == sid
            app.grasps.panel.count.value = 3  # a quick plan: the test is about the button, not the planner
            button = page.get_by_role("button", name="Plan grasps")
            button.wait_for(state="visible", timeout=BROWSER_WAIT * 1000)
            # A software-rendered WebGL canvas on a busy machine starves the animation frames that
            # Playwright's "stable" check waits for: click without the check (force), and fall back
            # to the same DOM click event if even that cannot get through.
            try:
                button.click(force=True, timeout=30_000)
            except Exception:  # noqa: BLE001
                button.dispatch_event("click")
            job = wait_until(lambda: app.grasps.job, BROWSER_WAIT, "the click to start planning")
            assert job.wait(180), "planning did not finish"
            assert job.error is None and sid in app.grasps.sets
            grasps = app.grasps.sets[sid].grasps
            assert grasps, "no grasp found"
            for k in range(len(grasps)):
                assert node(app, f"/grasps/seg_{sid}/g{k}/hand/palm") is not None
            # The browser shows the best grasp's description.
            page.get_by_text("Grasp #1").first.wait_for(timeout=BROWSER_WAIT * 1000)
            page.screenshot(path=str(tmp_path / "grasps.png"), timeout=120_000)

            # Clicking another grasp's hand on the canvas selects it (and completes nothing).
            client = app.audience.client
            cam = wait_until(lambda: reported_camera(client), BROWSER_WAIT, "the browser's camera")
            hand = get_hand("barrett")
            target = None
            for k, g in enumerate(grasps[1:], start=1):
                sticks = hand_skeleton(hand, [g.joints[n] for n in hand.joint_names]).reshape(-1, 3)
                for point in transform_points(g.T_world_palm, sticks):
                    # A point where this hand, not another or a segment in front of it, takes the click.
                    ray = ray_through(cam.position, point)
                    hit, t_hand = app.grasps.pick(*ray)
                    if hit == k and t_hand <= app.pick_hit(*ray)[1]:
                        xy = canvas_point(page, client, point)
                        if xy is not None:
                            target = (k, xy)
                            break
                if target:
                    break
            assert target is not None, "no other grasp's hand is in view"
            k, xy = target
            completed = set(app.completions)
            # The click handler runs on viser's thread: wait for all of the selection, dropdown included.
            click_until(
                page,
                xy,
                lambda: app.grasps.selected == k and app.grasps.panel.grasp.value.startswith(f"#{k + 1} "),
                f"grasp #{k + 1} being selected",
            )
            assert set(app.completions) == completed
    finally:
        viewer.stop()
