"""The Pipeline tab in a real browser (headless Debian Chromium, Playwright): arrow keys on the
Sample control step through the sample completions and leave the camera where it is.

viser's client moves its camera on the arrow keys (and W/A/S/D/Q/E) unless the focus is in a text
field; the test clicks the Sample control as a user would, presses the keys, and reads the camera
the browser reports to the server (``client.camera``).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from helpers import BROWSER_WAIT, browser_page, browser_session, free_port, needs_browser, reported_camera, wait_until

pytestmark = pytest.mark.browser

# Page point (x, y) of the middle of the control that the visible label ``name`` of viser's panel
# labels (its ``for`` attribute), scrolled into view; null when there is none.
CONTROL_MIDDLE = """name => {
  const label = Array.from(document.querySelectorAll("label")).find(
    l => l.innerText.trim() === name && l.offsetParent !== null && l.htmlFor);
  const control = label && document.getElementById(label.htmlFor);
  if (!control) return null;
  control.scrollIntoView({block: "center"});
  const r = control.getBoundingClientRect();
  return [r.x + r.width / 2, r.y + r.height / 2];
}"""
# Whether the focus is in that control (a notification over it would have taken the click).
CONTROL_FOCUSED = """name => {
  const label = Array.from(document.querySelectorAll("label")).find(
    l => l.innerText.trim() === name && l.offsetParent !== null && l.htmlFor);
  const control = label && document.getElementById(label.htmlFor);
  return !!control && control.contains(document.activeElement);
}"""


def camera_pose(client) -> np.ndarray:
    """The camera position and orientation the browser last reported (7 numbers)."""
    cam = client.camera
    return np.concatenate([np.asarray(cam.position, float), np.asarray(cam.wxyz, float)])


@needs_browser
def test_arrow_keys_on_the_sample_control_step_the_samples_not_the_camera():
    from shapeviewer.viewer import ViewerApp

    viewer = ViewerApp(port=free_port(), seed=0, max_cloud_points=20_000)
    try:
        with browser_page(viewer) as page:
            app = browser_session(viewer)  # the browser tab's own session
            client = app.audience.client
            wait_until(lambda: reported_camera(client), BROWSER_WAIT, "the browser's camera")
            sid = max(app.scene.segments, key=lambda s: len(app.scene.points_world[s]))
            assert app.complete(sid) is not None and app.panel.sample.value == 0

            def click_sample() -> bool:
                xy = page.evaluate(CONTROL_MIDDLE, "Sample")
                if xy is not None:
                    page.mouse.click(*xy)
                    time.sleep(0.5)
                return page.evaluate(CONTROL_FOCUSED, "Sample")

            wait_until(click_sample, BROWSER_WAIT, "a click to put the focus on the Sample control", step=1.0)
            time.sleep(1.0)  # the click's own update (a slider jumps to where it is clicked) arrives
            before, shown = camera_pose(client), app.panel.sample.value
            # What a user tries to step with, each held a moment (viser's client turns the camera
            # while an arrow key is held, one frame at a time).
            for key in ("ArrowUp", "ArrowRight", "ArrowUp", "ArrowRight"):
                page.keyboard.down(key)
                time.sleep(0.7)
                page.keyboard.up(key)
                time.sleep(0.5)
            # The keys reached the control: another sample is shown...
            wait_until(lambda: app.panel.sample.value != shown, 60, "the Sample control to step")
            wait_until(
                lambda: f"Sample completion **{app.panel.sample.value}**" in app.panel.status.content,
                60,
                "the sample to be drawn",
            )
            time.sleep(2.0)  # a camera the keys moved would have reported its new pose by now
            # ... and the view stayed where it was.
            moved = np.abs(camera_pose(client) - before).max()
            assert moved < 1e-6, f"the arrow keys on the Sample control moved the camera too ({moved:.3f})"
    finally:
        viewer.stop()
