"""Load: several users on one viewer server at once.

    python benchmarks/load.py [--sessions 5] [--minutes 2] [--planners 1] [--browser] [--json out.json]

Starts the server as a subprocess (``python app.py --port P``, so that its memory can be read from
``/proc``; or ``--url URL [--pid PID]`` for one already running), then runs ``--sessions`` lightweight
sessions: headless viser clients in this process that speak viser's websocket protocol
(benchmarks/common/viser_client.py) and draw nothing. With ``--browser``, one more session is a real
headless Chromium (Playwright) that clicks on its canvas.

Every session, for ``--minutes`` (then no new action; an action under way ends within its timeout):

* clicks a segment: a scene click whose ray goes from the session's camera to a point of the
  segment (its centroid, or another of its points when the centroid is hidden from the camera by
  another segment or a grasp's hand), knowing the segments only from the ``/segments/seg_N``
  point clouds it was sent; then waits for its own ``/fast_mesh/seg_N`` (click -> own fast mesh
  received, the time printed);
* the first ``--planners`` sessions then press "Plan grasps" (the button found by its label in the
  GUI the session was sent) and wait for their ``/grasps/seg_N`` (the time printed) and the
  notification that ends the plan;
* pauses about ``--pause`` seconds, and starts again.

Everything is learnt from what the session's own connection receives, so the benchmark runs the
same against a server whose scene and GUI are shared by every browser and one with a scene and GUI
per browser. (With a shared scene, another session's mesh of the very segment a session waits for
cannot be told from its own: it is counted as its own, so there the wrong-session count is a lower
bound and the latencies are partly other sessions'.) The browser's times are from the mouse click
to its page's websocket receiving the mesh (seen through Playwright), not to the mesh being drawn.

Reported: sessions, actions, errors (timeouts, refusals ("Busy"), red notifications, clicks that
hit no segment), results shown in the WRONG session (a fast mesh or grasps that a session received
for an action it did not do), click -> own fast mesh p50/p95/max, and the server's memory (RSS of
its process and the grasp worker processes it started): at start, the baseline (after warm-up
sessions, as many as the run's, have clicked a few segments and planned once at the same time, and
gone), the peak while the sessions run, and ``--settle`` seconds after they all closed; and whether
Ctrl-C stopped it and every process it started (zombies awaiting init excepted).

Targets (5 sessions x 2 minutes with one planning grasps): 0 errors, 0 results in the
wrong session, click -> own fast mesh p95 <= 0.5 s (lightweight sessions), memory back to the
baseline (taken here as within 10 % or 50 MB of it, whichever is larger).
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import json
import os
import random
import re
import shlex
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import viser

from common.browser import CHROMIUM, CHROMIUM_ARGS
from common.load_report import _plain, markdown, summarize
from common.server_process import MemoryWatch, Server
from common.viser_client import ViserClient, free_port

ROOT = Path(__file__).resolve().parents[1]

# shapeviewer/viewer/rays.py is plain numpy (no viser, no torch): loaded by path, so that this
# process picks segments exactly as the viewer does without importing the viewer (and the model).
_spec = importlib.util.spec_from_file_location("_shapeviewer_rays", ROOT / "shapeviewer" / "viewer" / "rays.py")
assert _spec is not None and _spec.loader is not None
rays = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rays)

# Scene nodes and GUI labels of the viewer (shapeviewer/viewer/drawing.py, grasps/drawing.py, grasps/controls.py).
SEGMENT = re.compile(r"^/segments/seg_(\d+)$")
FAST_MESH = re.compile(r"^/fast_mesh/seg_(\d+)$")
GRASPS = re.compile(r"^/grasps/seg_(\d+)$")  # the frame under which one plan's hands are drawn
HAND_STICKS = re.compile(r"^/grasps/seg_\d+/g\d+/skeleton$")  # a hand's stick figure: clicks pick it
PLAN_BUTTON = "Plan grasps"
WARM_UP_CLICKS = 3  # segment clicks of each warm-up session
HAND_PICK_SPACING = 0.004  # m between the points along a stick figure the viewer picks (grasps/drawing.py)
# Notification titles that end an action (shapeviewer/viewer/app.py, jobs.py, grasps/).
BUSY = "Busy"
MISSED = "No segment there"
EMPTY = "Empty completion"
PLAN_DONE = {"Grasps ready": "ok", "No grasp found": "no grasp"}
PLAN_LOST = ("Planning cancelled", "Grasps dropped")

ERROR_KINDS = ("timeout", "refused", "error", "missed", "not ready")


# ----------------------------------------------------------------------------------------------
# A session


@dataclass
class Pending:
    """The action a session waits for: a click on segment ``segment`` or a grasp plan on it."""

    kind: str  # "click" | "plan"
    segment: int
    t0: float
    future: asyncio.Future
    foreign_seen: bool = False  # another session's result arrived meanwhile
    first_result: float | None = None  # a plan: when its first grasp node arrived (it ends with a notification)


@dataclass
class Stats:
    """What one session did and saw."""

    name: str
    kind: str  # "lightweight" | "browser"
    planner: bool
    clicks: int = 0
    plans: int = 0
    outcomes: Counter = field(default_factory=Counter)  # "click ok", "click timeout", "plan refused", ...
    click_seconds: list[float] = field(default_factory=list)
    plan_seconds: list[float] = field(default_factory=list)
    wrong: list[str] = field(default_factory=list)  # results received for actions this session did not do
    disturbed: int = 0  # actions during which another session's result arrived
    late: int = 0  # own results that arrived after their action had timed out
    red: list[str] = field(default_factory=list)  # red notifications received
    unattributed: Counter = field(default_factory=Counter)  # refusals/errors while no action was pending
    details: list[str] = field(default_factory=list)

    @property
    def errors(self) -> int:
        return sum(n for k, n in self.outcomes.items() if k.split(" ", 1)[1] in ERROR_KINDS) + sum(
            self.unattributed.values()
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": self.kind,
            "planner": self.planner,
            "clicks": self.clicks,
            "plans": self.plans,
            "errors": self.errors,
            "outcomes": dict(self.outcomes),
            "wrong_session_results": len(self.wrong),
            "wrong_session_examples": self.wrong[:10],
            "actions_disturbed": self.disturbed,
            "late_results": self.late,
            "red_notifications": self.red,
            "unattributed": dict(self.unattributed),
            "click_to_own_fast_mesh_s": self.click_seconds,
            "plan_to_own_grasps_s": self.plan_seconds,
            "details": self.details[:50],
        }


class Session:
    """One user: a connection (a lightweight client, or a browser's websocket seen through Playwright)
    and the action it waits for. Subclasses send the clicks."""

    kind = "lightweight"

    def __init__(self, name: str, client: ViserClient, planner: bool, rng: random.Random, args) -> None:
        self.client = client
        self.planner = planner
        self.rng = rng
        self.args = args
        self.stats = Stats(name, self.kind, planner)
        self.pending: Pending | None = None
        self.timed_out: dict[str, set[int]] = {"click": set(), "plan": set()}
        self.empty: set[int] = set()  # segments this session cannot complete
        # The segment whose grasps the session's Grasps folder lists: only its hands take clicks.
        self.listed: int | None = None
        client.listeners.append(self._on_message)

    # -- what arrives

    def _on_message(self, client: ViserClient, m: dict[str, Any], now: float) -> None:
        if not client.replayed:  # the connect replay: the state found, not anyone's action
            return
        name, kind = m.get("name"), m.get("type", "")
        if isinstance(name, str) and "props" in m:
            if match := FAST_MESH.match(name):
                self._result("click", int(match.group(1)), name, now)
            elif match := GRASPS.match(name):
                self._result("plan", int(match.group(1)), name, now)
        elif kind == "NotificationShowMessage":
            p = m.get("props", {})
            if not p.get("loading"):
                self._notification(p.get("title", ""), p.get("body", ""), p.get("color"), now)

    def _resolve(self, outcome: str, now: float, detail: str = "") -> None:
        p = self.pending
        if p is not None and not p.future.done():
            p.future.set_result((outcome, (p.first_result or now) - p.t0, detail))

    def _result(self, kind: str, sid: int, name: str, now: float) -> None:
        p = self.pending
        if p is not None and p.kind == kind == "click" and p.segment == sid:
            self._resolve("ok", now)
        elif p is not None and p.kind == "plan" and kind == "click" and p.segment == sid:
            pass  # planning made the segment's mesh first: part of this session's own plan
        elif p is not None and p.kind == kind == "plan":
            # Timed at the grasps' first node; ended by the notification that follows the last hand
            # (clicking on before the hands have arrived could hit one: the viewer would select it).
            if p.first_result is None:
                p.first_result = now
            if sid != p.segment:  # the plan ran on another segment than this session's selection
                self.stats.wrong.append(f"{name} for a plan on seg_{p.segment}")
                self._resolve("wrong segment", now, name)
        elif sid in self.timed_out[kind]:
            self.timed_out[kind].discard(sid)
            self.stats.late += 1
        else:
            self.stats.wrong.append(name)
            if p is not None:
                p.foreign_seen = True

    def _notification(self, title: str, body: str, color: Any, now: float) -> None:
        red = color == "red"
        if red:
            self.stats.red.append(f"{title}: {body}")
        p = self.pending
        outcome = None
        if title == BUSY:
            outcome = "refused"
        elif red:
            outcome = "error"
        elif p is not None and p.kind == "click" and title == MISSED:
            outcome = "missed"
        elif p is not None and p.kind == "click" and title == EMPTY:
            outcome = "empty"
        elif p is not None and p.kind == "plan" and title in PLAN_DONE:
            outcome = PLAN_DONE[title]
        elif p is not None and p.kind == "plan" and title in PLAN_LOST:
            outcome = "error"
        if outcome is None:
            return
        if p is not None and not p.future.done():
            self._resolve(outcome, now, f"{title}: {body}")
        elif outcome in ERROR_KINDS:
            self.stats.unattributed[outcome] += 1
            self.stats.details.append(f"while idle: {title}: {body}")

    # -- what it does

    def segments(self) -> dict[int, np.ndarray]:
        """The segments this session was sent: id -> world points."""
        out = {}
        for name in list(self.client.nodes):
            match = SEGMENT.match(name)
            if match:
                pts = self.client.world_points(name)
                if pts is not None and len(pts):
                    out[int(match.group(1))] = pts
        return out

    def hands(self) -> dict[str, np.ndarray]:
        """Points along the stick figures of the listed segment's grasp hands (the viewer picks
        those, not the hands of other segments' grasps)."""
        out: dict[str, np.ndarray] = {}
        if self.listed is None:
            return out
        for name in list(self.client.nodes):
            if HAND_STICKS.match(name) and name.startswith(f"/grasps/seg_{self.listed}/"):
                pts = self.client.world_points(name)
                if pts is not None and len(pts):
                    out[name] = rays.sample_segments(pts.reshape(-1, 2, 3), HAND_PICK_SPACING)
        return out

    def camera_position(self) -> np.ndarray | None:
        return self.client.camera_position()

    def aim(self, sid: int, points: np.ndarray, everything: dict, origin: np.ndarray) -> np.ndarray | None:
        """A point of segment ``sid`` that a click from ``origin`` picks (the viewer's own test:
        the segment is the first thing along the ray), or None: the centroid, else other points."""
        candidates = [points.mean(axis=0)]
        candidates += [points[i] for i in self.rng.sample(range(len(points)), min(24, len(points)))]
        for target in candidates:
            o, d = rays.ray_through(origin, target)
            if rays.first_hit(o, d, everything)[0] == ("segment", sid) and self.on_screen(target):
                return target
        return None

    def on_screen(self, target: np.ndarray) -> bool:
        return True

    def choose(self) -> tuple[int, np.ndarray, np.ndarray] | None:
        """``(segment, ray origin, target point)`` of a segment to click, or None."""
        origin = self.camera_position()
        if origin is None:
            return None
        segments = {sid: pts for sid, pts in self.segments().items() if sid not in self.empty}
        everything: dict[Any, np.ndarray] = {("segment", sid): pts for sid, pts in segments.items()}
        everything.update({("hand", name): pts for name, pts in self.hands().items()})
        order = list(segments)
        self.rng.shuffle(order)
        for sid in order:
            target = self.aim(sid, segments[sid], everything, origin)
            if target is not None:
                return sid, origin, target
        return None

    async def ready(self, timeout: float) -> bool:
        """Wait until the session has its camera and segments (and, for a planner, the button)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.client.error is not None or self.client.closed.is_set():
                break
            if (
                self.client.replayed
                and self.camera_position() is not None
                and self.segments()
                and (not self.planner or self.client.find_gui(PLAN_BUTTON) is not None)
            ):
                return True
            await asyncio.sleep(0.1)
        return False

    async def send_click(self, origin: np.ndarray, target: np.ndarray) -> None:
        await self.client.click(*rays.ray_through(origin, target))

    async def press(self, uuid: str) -> None:
        await self.client.press(uuid)

    async def _act(self, kind: str, sid: int, send, timeout: float) -> tuple[str, float, str]:
        loop = asyncio.get_running_loop()
        self.pending = p = Pending(kind, sid, time.perf_counter(), loop.create_future())
        try:
            await send()
            outcome, seconds, detail = await asyncio.wait_for(asyncio.shield(p.future), timeout)
        except TimeoutError:
            outcome, seconds, detail = "timeout", time.perf_counter() - p.t0, f"no result within {timeout:.0f} s"
            self.timed_out[kind].add(sid)
        except ConnectionError as e:
            outcome, seconds, detail = "error", time.perf_counter() - p.t0, str(e)
        finally:
            self.pending = None
        self.stats.outcomes[f"{kind} {outcome}"] += 1
        self.stats.disturbed += p.foreign_seen
        if outcome != "ok":
            self.stats.details.append(f"{kind} seg_{sid}: {outcome} after {seconds:.1f} s {detail}".rstrip())
        return outcome, seconds, detail

    async def click_segment(self) -> int | None:
        """Click a segment and wait for its fast mesh; the segment on success, else None."""
        choice = self.choose()
        if choice is None:
            self.stats.outcomes["click not ready"] += 1
            self.stats.details.append("no segment to click is in view")
            await asyncio.sleep(1.0)
            return None
        sid, origin, target = choice
        self.stats.clicks += 1
        outcome, seconds, _ = await self._act("click", sid, lambda: self.send_click(origin, target), self.args.timeout)
        if outcome == "ok":
            self.stats.click_seconds.append(seconds)
            if f"/grasps/seg_{sid}" in self.client.nodes:  # the viewer lists a segment's grasps when it is picked
                self.listed = sid
            return sid
        if outcome == "empty":
            self.empty.add(sid)
        return None

    async def plan(self, sid: int) -> None:
        """Press "Plan grasps" (once it is enabled) and wait for the grasps of ``sid``."""
        uuid = self.client.find_gui(PLAN_BUTTON)
        deadline = time.monotonic() + self.args.plan_timeout
        while uuid is not None and self.client.gui[uuid].disabled and time.monotonic() < deadline:
            await asyncio.sleep(0.2)
            uuid = self.client.find_gui(PLAN_BUTTON)
        if uuid is None or self.client.gui[uuid].disabled:
            self.stats.outcomes["plan refused"] += 1
            self.stats.details.append(f"plan seg_{sid}: the {PLAN_BUTTON!r} button is missing or stays disabled")
            return
        self.stats.plans += 1
        outcome, seconds, _ = await self._act("plan", sid, lambda: self.press(uuid), self.args.plan_timeout)
        if outcome in ("ok", "no grasp"):
            self.stats.plan_seconds.append(seconds)
        if outcome == "ok":
            self.listed = sid

    async def work(self, deadline: float) -> None:
        """Act until ``deadline`` (perf_counter)."""
        while time.perf_counter() < deadline and not self.client.closed.is_set():
            sid = await self.click_segment()
            if self.planner and sid is not None and time.perf_counter() < deadline:
                await self.plan(sid)
            await asyncio.sleep(self.args.pause * self.rng.uniform(0.5, 1.5))


class BrowserSession(Session):
    """A real headless Chromium: clicks on its canvas where it draws the segment; what its page's
    websocket receives (seen through Playwright) feeds a passive :class:`ViserClient`."""

    kind = "browser"

    def __init__(self, name: str, url: str, rng: random.Random, args) -> None:
        super().__init__(name, ViserClient(url, name, passive=True), False, rng, args)
        self.url = url
        self.page: Any = None
        self.camera: dict[str, Any] | None = None  # the browser's last ViewerCameraMessage
        self.box: dict[str, float] | None = None  # the canvas on the page
        self._xy: tuple[float, float] | None = None

    async def open(self, playwright) -> None:
        self.browser = await playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        self.page = await self.browser.new_page(viewport={"width": 1280, "height": 800})
        self.page.on("websocket", self._on_websocket)
        self.client.connected.set()
        await self.page.goto(self.url)
        await self.page.wait_for_function("!document.body.innerText.includes('Connecting')", timeout=60_000)
        canvas = self.page.locator("canvas").first
        await canvas.wait_for(state="visible", timeout=60_000)
        self.box = await canvas.bounding_box()

    async def close(self) -> None:
        if self.page is not None:
            await self.browser.close()
        self.client.closed.set()

    def _on_websocket(self, ws) -> None:
        import msgspec

        def received(payload) -> None:
            if isinstance(payload, bytes):
                self.client.feed(payload, time.perf_counter())

        def sent(payload) -> None:
            if isinstance(payload, bytes):
                try:
                    m = msgspec.msgpack.decode(payload)
                except msgspec.DecodeError:
                    return
                if isinstance(m, dict) and m.get("type") == "ViewerCameraMessage":
                    self.camera = m

        ws.on("framereceived", received)
        ws.on("framesent", sent)

    def camera_position(self) -> np.ndarray | None:
        return None if self.camera is None else np.asarray(self.camera["position"], dtype=float)

    def on_screen(self, target: np.ndarray) -> bool:
        """Whether ``target`` is drawn inside the canvas (not under the docked panel); remembers the pixel."""
        cam, box = self.camera, self.box
        if cam is None or box is None:
            return False
        R = viser.transforms.SO3(np.asarray(cam["wxyz"])).as_matrix()
        w, h = cam["image_width"], cam["image_height"]
        u, v = rays.project_to_pixels(np.asarray(target)[None], np.asarray(cam["position"]), R, cam["fov"], w, h)[0]
        if not (np.isfinite(u) and np.isfinite(v) and 2 <= u < w - 2 and 2 <= v < h - 2):
            return False
        self._xy = (box["x"] + u * box["width"] / w, box["y"] + v * box["height"] / h)
        return True

    async def send_click(self, origin: np.ndarray, target: np.ndarray) -> None:
        self.on_screen(target)
        assert self._xy is not None
        hit = await self.page.evaluate("([x, y]) => document.elementFromPoint(x, y)?.tagName", list(self._xy))
        if hit != "CANVAS":
            self.stats.details.append(f"the click point is covered by a {hit}")
        await self.page.mouse.click(*self._xy)


# ----------------------------------------------------------------------------------------------
# A run


async def warm_up(url: str, args) -> list[Stats]:
    """As many sessions as the run will have, at once, each clicking a few segments (the first
    planning grasps when sessions will), then leaving: the server's first CNN calls, meshes and
    plans, in every worker thread, allocate what stays allocated (models, hands, each worker's
    thread state and allocator arena), so the memory baseline is taken after them."""

    async def one(i: int) -> Stats:
        client = ViserClient(url, f"warm-up {i + 1}")
        task = asyncio.create_task(client.run())
        session = Session(client.name, client, i < args.planners, random.Random(args.seed - i - 1), args)
        try:
            if await session.ready(args.setup_timeout):
                for _ in range(WARM_UP_CLICKS):
                    sid = await session.click_segment()
                if session.planner and sid is not None:
                    await session.plan(sid)
        finally:
            await client.close()
            await asyncio.wait_for(task, 10)
        return session.stats

    return list(await asyncio.gather(*(one(i) for i in range(args.sessions))))


async def run_sessions(url: str, args) -> tuple[list[Stats], dict[str, Any]]:
    sessions: list[Session] = []
    tasks = []
    for i in range(args.sessions):
        client = ViserClient(url, f"s{i + 1}")
        tasks.append(asyncio.create_task(client.run()))
        sessions.append(Session(client.name, client, i < args.planners, random.Random(args.seed + i + 1), args))
    browser_cm = None
    if args.browser:
        from playwright.async_api import async_playwright

        browser_cm = async_playwright()
        playwright = await browser_cm.__aenter__()
        b = BrowserSession("browser", url, random.Random(args.seed + 1000), args)
        sessions.append(b)
    info: dict[str, Any] = {}
    try:
        if args.browser:
            await b.open(playwright)
        ready = await asyncio.gather(*(s.ready(args.setup_timeout) for s in sessions))
        for s, ok in zip(sessions, ready):
            if not ok:
                s.stats.outcomes["click not ready"] += 1
                error = s.client.error
                why = f": {type(error).__name__}: {error}" if error else ""
                s.stats.details.append(f"not ready within {args.setup_timeout:.0f} s{why}")
        t0 = time.perf_counter()
        deadline = t0 + 60.0 * args.minutes
        info["load_average_start"] = os.getloadavg()[0]
        await asyncio.gather(*(s.work(deadline) for s, ok in zip(sessions, ready) if ok))
        info["seconds"] = time.perf_counter() - t0
        info["load_average_end"] = os.getloadavg()[0]
        info["bytes_received"] = sum(s.client.bytes for s in sessions)
    finally:
        for s in sessions:
            if isinstance(s, BrowserSession):
                await s.close()
            else:
                await s.client.close()
        await asyncio.wait(tasks, timeout=10)
        if browser_cm is not None:
            await browser_cm.__aexit__(None, None, None)
    return [s.stats for s in sessions], info


async def main_async(args) -> dict[str, Any]:
    server = None
    url = args.url
    pid = args.pid
    memory: dict[str, Any] = {}
    info: dict[str, Any] = {}
    try:
        if url is None:
            port = args.port or free_port()
            app = args.app_root.resolve() / "app.py"
            print(f"starting the server: python {app} --port {port} {args.server_args}".rstrip(), file=sys.stderr)
            server = Server(port, shlex.split(args.server_args), args.app_root.resolve())
            url, pid = await asyncio.to_thread(server.wait_ready, args.startup_timeout), server.pid
        watch = MemoryWatch(pid)
        memory["start"] = watch.now()
        if args.warmup:
            print(f"warm-up: {args.sessions} sessions at once ...", file=sys.stderr)
            warm = await warm_up(url, args)
            info["warm_up"] = dict(sum((Counter(w.outcomes) for w in warm), Counter()))
        await asyncio.sleep(args.settle)
        memory["baseline"] = watch.now()
        watch.reset_peak()
        watch.start()
        print(f"{args.sessions} sessions for {args.minutes:g} min on {url} ...", file=sys.stderr)
        stats, run_info = await run_sessions(url, args)
        info.update(run_info)
        await asyncio.sleep(args.settle)
        watch.stop()
        memory["peak"] = watch.peak
        memory["after"] = watch.now()
        if server is not None:
            info["server_tracebacks"] = server.tracebacks()
    finally:
        if server is not None:
            server.stop()  # blocking: also when the run is interrupted
            info["server_stop_seconds"] = server.stop_seconds
            info["server_children_left"] = server.children_left
            print(f"server log: {server.log}", file=sys.stderr)
    return summarize(stats, memory, info, args, url)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sessions", type=int, default=5, help="lightweight sessions")
    ap.add_argument("--minutes", type=float, default=2.0, help="how long the sessions act")
    ap.add_argument("--planners", type=int, default=1, help="how many of the sessions also plan grasps")
    ap.add_argument("--browser", action="store_true", help="one more session: headless Chromium (Playwright)")
    ap.add_argument("--pause", type=float, default=0.5, help="mean pause between a session's actions (s)")
    ap.add_argument("--timeout", type=float, default=30.0, help="wait at most this long for a fast mesh (s)")
    ap.add_argument("--plan-timeout", type=float, default=180.0, help="wait at most this long for grasps (s)")
    ap.add_argument("--setup-timeout", type=float, default=120.0, help="wait this long for a session's scene (s)")
    ap.add_argument("--settle", type=float, default=5.0, help="wait before reading memory at rest (s)")
    ap.add_argument("--no-warmup", dest="warmup", action="store_false", help="no warm-up sessions first")
    ap.add_argument("--seed", type=int, default=0, help="seed of the sessions' choices")
    ap.add_argument("--port", type=int, default=None, help="the server's port (default: a free one)")
    ap.add_argument("--server-args", default="", help="more arguments for app.py, e.g. '--seed 3'")
    ap.add_argument("--app-root", type=Path, default=ROOT, help="checkout whose app.py to serve (default: this)")
    ap.add_argument("--startup-timeout", type=float, default=300.0, help="wait this long for the server (s)")
    ap.add_argument("--url", default=None, help="use this running server instead of starting one")
    ap.add_argument("--pid", type=int, default=None, help="with --url: the server's process id (for its memory)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    if args.sessions < 1 or args.minutes <= 0:
        ap.error("--sessions must be >= 1 and --minutes > 0")

    result = asyncio.run(main_async(args))
    print(markdown(result))
    if args.json is not None:
        args.json.write_text(json.dumps(_plain(result), indent=2))
    return 0 if all(v["ok"] is not False for v in result["targets"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
