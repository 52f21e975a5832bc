"""Helpers shared by the test modules: a free port, polling, scene nodes, a headless browser and
clicks on its 3D canvas.

Test modules import them as ``from helpers import ...`` (pytest puts ``tests/`` on ``sys.path``, as it
does for ``store_factory``). Nothing here imports shapeviewer's heavy modules (the canvas helpers
import viser and :mod:`shapeviewer.viewer.rays` when called).
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

try:
    from playwright.sync_api import sync_playwright
except ImportError:  # pragma: no cover - depends on the environment
    sync_playwright = None

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]

# The longest a browser test waits for a state it expects (s): a software-rendered page on 2 busy
# cores can take many seconds to draw, and a wait ends as soon as its state is reached anyway.
BROWSER_WAIT = 120.0

needs_browser = pytest.mark.skipif(
    not CHROMIUM.exists() or sync_playwright is None,
    reason="needs Debian chromium at /usr/bin/chromium (apt-get install chromium) and playwright "
    "(pip install playwright)",
)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(predicate: Callable[[], Any], timeout: float, what: str, step: float = 0.1) -> Any:
    """Poll ``predicate`` until it returns something truthy (returned) or fail after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(step)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def node(session, name: str):
    """The scene node called ``name`` (e.g. ``/fast_mesh/seg_0``) of a viewer session, or None."""
    return session.audience.scene.get_handle_by_name(name)


@contextlib.contextmanager
def headless_session(**options) -> Iterator:
    """A viewer (``ViewerApp(**options)`` on a free port, no session per browser) and one session
    without a browser, drawn server-wide; the viewer stops afterwards."""
    from shapeviewer.viewer import ViewerApp

    viewer = ViewerApp(port=free_port(), sessions=False, **options)
    try:
        yield viewer.open_session()
    finally:
        viewer.stop()


@contextlib.contextmanager
def job_running(session, timeout: float = 60.0) -> Iterator[None]:
    """A job of viewer ``session`` that runs, holding its job queue, until the block ends."""
    import threading

    release, running = threading.Event(), threading.Event()
    admitted: list[bool] = []

    def hold() -> None:
        with session.jobs.take(None) as ok:
            admitted.append(ok)
            running.set()
            if ok:
                release.wait(timeout)

    holder = threading.Thread(target=hold)
    holder.start()
    try:
        assert running.wait(10) and admitted == [True], "the job did not start"
        yield
    finally:
        release.set()
        holder.join(timeout)


def browser_session(viewer, timeout: float = BROWSER_WAIT):
    """The session of the (first) browser connected to ``viewer``, once it has its scene."""

    def ready():
        sessions = list(viewer.sessions.values())
        return sessions[0] if sessions and sessions[0].scene is not None else None

    return wait_until(ready, timeout, "the browser's session")


@contextlib.contextmanager
def browser_page(app, **page_options) -> Iterator:
    """A headless Chromium page connected to ``app`` (closed afterwards); ``page_options`` go to
    ``new_page`` (default viewport 1280x800)."""
    page_options.setdefault("viewport", {"width": 1280, "height": 800})
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(**page_options)
            page.goto(app.url)
            page.wait_for_function("!document.body.innerText.includes('Connecting')", timeout=BROWSER_WAIT * 1000)
            yield page
        finally:
            browser.close()


def reported_camera(client):
    """The client's camera once it has reported one (viser asserts before the first report)."""
    try:
        cam = client.camera
        cam.position  # noqa: B018 - raises AssertionError until the browser has sent its camera
        return cam
    except AssertionError:
        return None


def canvas_point(page, client, point_world: np.ndarray) -> tuple[float, float] | None:
    """Page pixel (x, y) where the browser draws ``point_world``, or None when the control panel
    (or anything else) covers it there."""
    import viser

    from shapeviewer.viewer.rays import project_to_pixels

    cam = wait_until(lambda: reported_camera(client), BROWSER_WAIT, "the browser's camera")
    canvas = page.locator("canvas").first
    canvas.wait_for(state="visible", timeout=BROWSER_WAIT * 1000)
    box = canvas.bounding_box()
    R = viser.transforms.SO3(np.asarray(cam.wxyz)).as_matrix()
    u, v = project_to_pixels(
        np.asarray(point_world)[None], cam.position, R, cam.fov, cam.image_width, cam.image_height
    )[0]
    x = box["x"] + u * box["width"] / cam.image_width
    y = box["y"] + v * box["height"] / cam.image_height
    return (x, y) if page.evaluate("([x, y]) => document.elementFromPoint(x, y)?.tagName", [x, y]) == "CANVAS" else None


def wait_for_frames(page, frames: int = 3, timeout: float = BROWSER_WAIT) -> None:
    """Wait until ``page`` has drawn ``frames`` more animation frames, so that what it had received
    before the call is on its canvas (for a screenshot)."""
    page.evaluate(
        """n => {
          window.__framesToDraw = n;
          const tick = () => { if (--window.__framesToDraw > 0) requestAnimationFrame(tick); };
          requestAnimationFrame(tick);
        }""",
        frames,
    )
    page.wait_for_function("() => window.__framesToDraw <= 0", polling=100, timeout=int(timeout * 1000))


def visible_segment(page, client, session, cam, order) -> tuple[int, tuple[float, float]] | None:
    """The first segment of ``order`` that a click at its centroid on ``page``'s canvas picks (in
    view, in front of the others, not under the panel): ``(segment id, page xy)``, or None.
    ``session`` is the browser's viewer session, ``client`` its viser client and ``cam`` the
    camera it reported."""
    from shapeviewer.viewer.rays import ray_through

    for sid in order:
        centroid = session.segment_centroid_world(sid)
        if session.pick(*ray_through(cam.position, centroid)) == sid:
            xy = canvas_point(page, client, centroid)
            if xy is not None:
                return sid, xy
    return None


def load_exported_grasp(folder: Path, hand_urdf: Path, physics_client: int, index: int = 0) -> tuple[int, int]:
    """Load an extracted pybullet scene export (``object.urdf``, ``grasps.json``) into pybullet
    ``physics_client`` with grasp ``index``'s hand (``hand_urdf``) at its pose and its joints set:
    ``(object body, hand body)``."""
    import json

    import pybullet as p

    g = json.loads((folder / "grasps.json").read_text())["grasps"][index]
    obj = p.loadURDF(str(folder / "object.urdf"), useFixedBase=True, physicsClientId=physics_client)
    hand = p.loadURDF(
        str(hand_urdf), g["position"], g["quaternion_xyzw"], useFixedBase=True, physicsClientId=physics_client
    )
    joints = {
        p.getJointInfo(hand, i, physicsClientId=physics_client)[1].decode(): i
        for i in range(p.getNumJoints(hand, physicsClientId=physics_client))
    }
    for name, q in zip(g["joint_names"], g["joint_values"]):
        p.resetJointState(hand, joints[name], q, physicsClientId=physics_client)
    return obj, hand


def click_until(page, xy: tuple[float, float], done, what: str, timeout: float = BROWSER_WAIT) -> None:
    """Click at ``xy`` until ``done()``: the canvas may not handle pointer events before its
    first frame."""
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        page.mouse.click(*xy)
        try:
            wait_until(done, 8, what)
        except AssertionError:
            pass
    assert done(), f"clicking at ({xy[0]:.0f}, {xy[1]:.0f}) did not lead to {what}"


# ----------------------------------------------------------------------------------------------
# Reading and driving viser's panel in a page


def page_text(page) -> str:
    """The text the page shows (hidden tabs and closed folders excluded)."""
    return page.evaluate("() => document.body.innerText")


def wait_for_text(page, text: str, timeout: float = BROWSER_WAIT) -> None:
    """Wait until the page shows ``text`` (a notification, the panel's markdown, ...)."""
    page.wait_for_function(
        "t => document.body.innerText.includes(t)", arg=text, polling=500, timeout=int(timeout * 1000)
    )


def page_shows(page, text: str, not_: str | None = None) -> bool:
    """Whether the page shows ``text`` (and not ``not_``)."""
    shown = page_text(page)
    return text in shown and (not_ is None or not_ not in shown)


# Where a user's click on element ``e`` lands (its centre, scrolled into view), and whether ``e``
# is what is there (not a folder that is still opening over it, a notification, ...).
HIT_POINT = """e => {
  e.scrollIntoView({block: "nearest"});
  const r = e.getBoundingClientRect(), x = r.x + r.width / 2, y = r.y + r.height / 2;
  const there = document.elementFromPoint(x, y);
  return [x, y, there !== null && (there === e || e.contains(there))];
}"""


def click(page, locator, what: str) -> None:
    """Click the first visible match of ``locator`` with the mouse, once it is what a click at its
    centre would hit and it stands still there.

    (Playwright's own actionability checks wait for animation frames, which a software-rendered
    WebGL canvas on a busy machine starves; these checks poll the page instead.)"""
    target = locator.filter(visible=True).first
    target.wait_for(state="visible", timeout=BROWSER_WAIT * 1000)

    def hit() -> tuple[float, float] | None:
        x, y, ok = target.evaluate(HIT_POINT)
        time.sleep(0.15)
        return (x, y) if ok and target.evaluate(HIT_POINT)[:2] == [x, y] else None

    page.mouse.click(*wait_until(hit, BROWSER_WAIT, f"{what} to be clickable", step=0.2))


def press(page, name: str) -> None:
    """Click the button called exactly ``name`` once it is enabled (no job running)."""
    button = page.get_by_role("button", name=name, exact=True).filter(visible=True).first
    button.wait_for(state="visible", timeout=BROWSER_WAIT * 1000)
    wait_until(button.is_enabled, BROWSER_WAIT, f"the {name!r} button to be enabled (no job running)")
    click(page, button, f"the {name!r} button")


def choose(page, dropdown: str, option: str) -> None:
    """Pick ``option`` (its full text) in the visible dropdown labelled ``dropdown``."""
    click(page, page.get_by_role("combobox", name=dropdown, exact=True), f"the {dropdown!r} dropdown")
    click(page, page.get_by_role("option", name=option, exact=True), f"the {option!r} entry")
    wait_until(lambda: dropdown_value(page, dropdown) == option, BROWSER_WAIT, f"{dropdown!r} to show {option!r}")


def dropdown_value(page, dropdown: str) -> str:
    return page.get_by_role("combobox", name=dropdown, exact=True).filter(visible=True).first.input_value()


def dropdown_options(page, dropdown: str) -> list[str]:
    """The entries of the visible dropdown ``dropdown`` (opened and closed again)."""
    click(page, page.get_by_role("combobox", name=dropdown, exact=True), f"the {dropdown!r} dropdown")
    options = page.get_by_role("option")
    options.first.wait_for(timeout=BROWSER_WAIT * 1000)
    texts = [t.strip() for t in options.all_inner_texts()]
    page.keyboard.press("Escape")
    return texts


def checked(page, label: str) -> bool:
    return page.get_by_role("checkbox", name=label, exact=True).filter(visible=True).first.is_checked()


def table_camera() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(R_cam_world, t_cam_world, plane_cam)``: a camera 0.6 m out and 0.5 m up looking at the
    table's origin (optical frame: z forward, y down), and the table z = 0 in its frame."""
    eye = np.array([0.0, -0.6, 0.5])
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])  # rows: the camera's axes in world coordinates
    t = -R @ eye
    normal = R @ np.array([0.0, 0.0, 1.0])
    return R, t, np.r_[normal, -normal @ t]


def seen_by(
    points_world: np.ndarray, normals_world: np.ndarray, R: np.ndarray, t: np.ndarray, *, noise: float = 0.0
) -> np.ndarray:
    """The points facing the camera ``(R, t)`` (:func:`table_camera`), in its frame (metres), with
    seeded Gaussian depth noise of ``noise`` metres."""
    facing = np.einsum("ij,ij->i", normals_world, -R.T @ t - points_world) > 0
    cam = points_world[facing] @ R.T + t
    return cam + np.random.default_rng(2).normal(0.0, noise, cam.shape) if noise else cam
