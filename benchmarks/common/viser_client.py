"""A headless viser client for the benchmarks: speaks viser's websocket protocol without a browser.

Used by ``benchmarks/pipeline.py`` (:class:`ArrivalClock`: when did a scene node arrive) and
``benchmarks/load.py`` (:class:`ViserClient`: many sessions clicking segments and pressing buttons).

viser's wire format (``viser.infra._infra._message_producer``), server -> client, one websocket frame::

    [8 bytes] size of the msgpack payload, little-endian
    [8 bytes] size of its zstd compression
    [N bytes] zstd(msgpack({"messages": [...], "timestampSec": ..., "binaryBufferLengths": [...]}))
    then each binary buffer (numpy arrays: points, vertices, ...), 8-byte aligned from the frame's start;
    a message refers to one as {"__binary_index": i, "dtype": "<f4"}.

Client -> server: one plain msgpack dict per frame, ``{"type": "<MessageClass>", ...fields}``.

What a browser does and this client does too: it offers the ``viser-v<version>`` subprotocol and
the page's ``Origin``; it reports its camera (``ViewerCameraMessage``) once the connect replay is
done (``ReplayDoneMessage``) and whenever the server moves the camera; viser registers a client
(``server.get_clients()``, connect callbacks, click and GUI events) only after its first camera
report. websockets answers the server's pings. It does not render anything.

The client keeps what the benchmarks need: the scene nodes by name (type, owner, arrival time, pose,
and the points of point clouds and line segments), the GUI components by uuid (type, label,
disabled, visible), the notifications, and the camera the server asked for.
"""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit, urlunsplit

import msgspec
import numpy as np
import viser
import websockets
import zstandard

# viser's default camera before the server sets one (three.js' default: 75 degrees vertical).
DEFAULT_FOV = np.radians(75.0)
CANVAS = (1280, 800)  # the canvas size the client reports (pixels), as tests/helpers.py's browser page


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def decode_frame(frame: bytes) -> list[dict[str, Any]]:
    """The messages of one server -> client frame, binary placeholders replaced by numpy arrays
    (views into ``frame``: copy what you keep)."""
    size = int.from_bytes(frame[:8], "little")
    compressed = int.from_bytes(frame[8:16], "little")
    payload = msgspec.msgpack.decode(
        zstandard.ZstdDecompressor().decompress(frame[16 : 16 + compressed], max_output_size=size)
    )
    buffers: list[memoryview] = []
    offset = 16 + compressed
    view = memoryview(frame)
    for n in payload.get("binaryBufferLengths", ()):
        offset += (8 - offset % 8) % 8
        buffers.append(view[offset : offset + n])
        offset += n
    messages = payload["messages"]
    return [_resolve(m, buffers) for m in messages] if buffers else messages


def _resolve(value: Any, buffers: list[memoryview]) -> Any:
    if isinstance(value, dict):
        if "__binary_index" in value and "dtype" in value:
            return np.frombuffer(buffers[value["__binary_index"]], dtype=np.dtype(value["dtype"]))
        return {k: _resolve(v, buffers) for k, v in value.items()}
    if isinstance(value, list):
        return [_resolve(v, buffers) for v in value]
    return value


def camera_wxyz(position: np.ndarray, look_at: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Orientation (wxyz) of a camera at ``position`` looking at ``look_at``, OpenCV convention
    (+z forward, +y down on screen) as viser's ``ViewerCameraMessage``."""
    forward = look_at - position
    forward = forward / (np.linalg.norm(forward) or 1.0)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking along ``up``
        right = np.cross(forward, [1.0, 0.0, 0.0] if abs(forward[0]) < 0.9 else [0.0, 1.0, 0.0])
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    return viser.transforms.SO3.from_matrix(np.stack([right, down, forward], axis=1)).wxyz


@dataclass
class Node:
    """A scene node as the client knows it."""

    type: str  # the message class, e.g. "MeshMessage"
    owner: str  # "" for the shared (broadcast) scene, else the owning client's id
    arrived: float  # perf_counter seconds when its (last) creation message arrived
    points: np.ndarray | None = None  # (N, 3) points of a point cloud or line segments, in the node's frame
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    wxyz: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))


@dataclass
class Gui:
    """A GUI component as the client knows it."""

    type: str  # e.g. "GuiButtonMessage"
    label: str | None
    disabled: bool = False
    visible: bool = True


@dataclass
class Notification:
    """A notification shown to this client."""

    arrived: float
    uuid: str
    title: str
    body: str
    color: Any  # None, a colour name ("red", ...) or an RGB triple
    loading: bool


# A listener gets (client, message, perf_counter arrival time), after the client's state is updated.
Listener = Callable[["ViserClient", dict[str, Any], float], None]


class ViserClient:
    """One headless viser session over a websocket; run :meth:`run` as an asyncio task.

    Args:
        url: the page URL printed by the server (``http://host:port[/?token=...]``).
        name: for messages.
        passive: only keep track of frames given to :meth:`feed` (e.g. a real browser's, seen
            through Playwright), never connect or send.
    """

    def __init__(self, url: str, name: str = "client", passive: bool = False) -> None:
        parts = urlsplit(url)
        scheme = "wss" if parts.scheme == "https" else "ws"
        self.ws_url = urlunsplit((scheme, parts.netloc, parts.path or "/", parts.query, ""))
        self.origin = f"{parts.scheme or 'http'}://{parts.netloc}"
        self.name = name
        self.nodes: dict[str, Node] = {}
        self.gui: dict[str, Gui] = {}
        self.notifications: list[Notification] = []
        self.listeners: list[Listener] = []
        self.replayed = False  # the connect replay is over (everything after is live)
        self.camera = {"position": np.array([3.0, 3.0, 3.0]), "look_at": np.zeros(3), "up": np.array([0.0, 0.0, 1.0])}
        self.fov = DEFAULT_FOV
        self.connected = asyncio.Event()
        self.closed = asyncio.Event()
        self.error: BaseException | None = None
        self.frames = 0
        self.bytes = 0
        self.passive = passive
        self._ws: Any = None
        self._camera_reported = False
        self._tasks: set[asyncio.Task] = set()

    # ------------------------------------------------------------------------------------------
    # Connection

    async def run(self, open_timeout: float = 30.0) -> None:
        """Connect and handle messages until :meth:`close` or the server closes the connection."""
        try:
            async with websockets.connect(
                self.ws_url,
                origin=self.origin,  # type: ignore[arg-type]  (a str is what websockets sends)
                subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
                max_size=None,
                compression=None,
                open_timeout=open_timeout,
            ) as ws:
                self._ws = ws
                self.connected.set()
                reporter = asyncio.create_task(self._report_camera_soon())
                try:
                    async for frame in ws:
                        now = time.perf_counter()
                        if isinstance(frame, bytes):
                            self.feed(frame, now)
                finally:
                    reporter.cancel()
        except websockets.exceptions.ConnectionClosedOK:
            pass
        except Exception as e:  # refused, reset, ...: the caller reads ``error``
            self.error = e
        finally:
            self._ws = None
            self.connected.set()  # nobody waits for a connection that failed
            self.closed.set()

    async def close(self) -> None:
        if self._ws is not None:
            await self._ws.close()

    async def send(self, message: dict[str, Any]) -> None:
        """Send one client -> server message (``{"type": ..., **fields}``)."""
        if self._ws is None:
            raise ConnectionError(f"{self.name}: not connected")
        await self._ws.send(msgspec.msgpack.encode(message))

    # ------------------------------------------------------------------------------------------
    # What a user does

    async def report_camera(self) -> None:
        """Tell the server where this client's camera is (as a browser does after each move)."""
        pos, look_at, up = (np.asarray(self.camera[k], dtype=float) for k in ("position", "look_at", "up"))
        width, height = CANVAS
        await self.send(
            {
                "type": "ViewerCameraMessage",
                "wxyz": tuple(float(v) for v in camera_wxyz(pos, look_at, up)),
                "position": tuple(float(v) for v in pos),
                "fov": float(self.fov),
                "near": 0.01,
                "far": 1000.0,
                "image_height": height,
                "image_width": width,
                "look_at": tuple(float(v) for v in look_at),
                "up_direction": tuple(float(v) for v in up),
            }
        )
        self._camera_reported = True

    async def click(self, origin: np.ndarray, direction: np.ndarray) -> None:
        """A click in the 3D view: the world-frame ray through the clicked pixel. (``screen_pos`` is
        the canvas centre: the viewer uses only the ray.)"""
        await self.send(
            {
                "type": "ScenePointerMessage",
                "event_type": "click",
                "ray_origin": tuple(float(v) for v in origin),
                "ray_direction": tuple(float(v) for v in direction),
                "screen_pos": ((0.5, 0.5),),
                "modifier": None,
            }
        )

    async def press(self, uuid: str) -> None:
        """Press a GUI button (what the browser sends on a click)."""
        await self.send({"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"value": True}})

    def find_gui(self, label: str, type_: str = "GuiButtonMessage") -> str | None:
        """The uuid of the (last added) visible component of type ``type_`` labelled ``label``."""
        found = [u for u, g in self.gui.items() if g.type == type_ and g.label == label and g.visible]
        return found[-1] if found else None

    def camera_position(self) -> np.ndarray:
        return np.asarray(self.camera["position"], dtype=float)

    def world_points(self, name: str) -> np.ndarray | None:
        """A point cloud's or line segments' points in the world frame (the node's and its
        ancestors' poses applied), or None when the node is unknown or has no points."""
        node = self.nodes.get(name)
        if node is None or node.points is None:
            return None
        pts = node.points.reshape(-1, 3).astype(np.float64)
        path = name
        while path:
            n = self.nodes.get(path)
            if n is not None:
                R = viser.transforms.SO3(n.wxyz).as_matrix()
                pts = pts @ R.T + n.position
            path = path.rsplit("/", 1)[0]
        return pts

    # ------------------------------------------------------------------------------------------
    # Messages

    def feed(self, frame: bytes, now: float) -> None:
        """Handle one server -> client frame that arrived at ``now`` (perf_counter seconds)."""
        self.frames += 1
        self.bytes += len(frame)
        for m in decode_frame(frame):
            self._handle(m, now)

    def _report_camera_later(self) -> None:
        """Report the camera from a (synchronous) message handler: a task on the running loop."""
        if self.passive or self._ws is None:
            return
        task = asyncio.get_running_loop().create_task(self.report_camera())
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _report_camera_soon(self, fallback: float = 3.0) -> None:
        """Report the camera after the replay (or after ``fallback`` s, for a server that sends no
        end-of-replay marker)."""
        await asyncio.sleep(fallback)
        if not self._camera_reported:
            await self.report_camera()

    def _handle(self, m: dict[str, Any], now: float) -> None:
        kind = m.get("type", "")
        name = m.get("name")
        if kind == "ReplayDoneMessage":
            self.replayed = True
            if not self._camera_reported:
                self._camera_reported = True  # (sent by the task)
                self._report_camera_later()
        elif isinstance(name, str) and "props" in m:  # a scene node is created (or replaced)
            props = m["props"]
            points = props.get("points") if isinstance(props, dict) else None
            old = self.nodes.get(name)
            self.nodes[name] = Node(
                kind,
                str(m.get("owner", "")),
                now,
                None if not isinstance(points, np.ndarray) else points.astype(np.float32).reshape(-1, 3),
            )
            if old is not None:  # viser keeps the pose of a replaced node until told otherwise
                self.nodes[name].position, self.nodes[name].wxyz = old.position, old.wxyz
        elif kind == "RemoveSceneNodeMessage" and isinstance(name, str):
            for key in [k for k in self.nodes if k == name or k.startswith(name + "/")]:
                del self.nodes[key]
        elif kind == "SetPositionMessage" and name in self.nodes:
            self.nodes[name].position = np.asarray(m["position"], dtype=float)
        elif kind == "SetOrientationMessage" and name in self.nodes:
            self.nodes[name].wxyz = np.asarray(m["wxyz"], dtype=float)
        elif "uuid" in m and isinstance(m.get("props"), dict) and kind.startswith("Gui"):
            p = m["props"]
            self.gui[m["uuid"]] = Gui(kind, p.get("label"), bool(p.get("disabled", False)), p.get("visible", True))
        elif kind == "GuiUpdateMessage" and m.get("uuid") in self.gui:
            g, updates = self.gui[m["uuid"]], m.get("updates", {})
            for key in ("label", "disabled", "visible"):
                if key in updates:
                    setattr(g, key, updates[key])
        elif kind == "GuiRemoveMessage":
            self.gui.pop(m.get("uuid", ""), None)
        elif kind in ("NotificationShowMessage", "NotificationUpdateMessage"):
            p = m["props"]
            self.notifications.append(
                Notification(now, m["uuid"], p.get("title", ""), p.get("body", ""), p.get("color"), p.get("loading"))
            )
        elif kind in ("SetCameraPositionMessage", "SetCameraLookAtMessage", "SetCameraUpDirectionMessage"):
            key = {"SetCameraPositionMessage": "position", "SetCameraLookAtMessage": "look_at"}.get(kind, "up")
            value = m.get("look_at") if key == "look_at" else m.get("position")
            if value is not None:
                self.camera[key] = np.asarray(value, dtype=float)
            # A browser moves its camera and reports it; an "initial" camera only applies before the first report.
            if self._camera_reported and not m.get("initial", False):
                self._report_camera_later()
        elif kind == "SetCameraFovMessage" and not self._camera_reported:
            self.fov = float(m["fov"])
        for listener in list(self.listeners):
            listener(self, m, now)


class ArrivalClock:
    """A headless viser client in a background thread: records when each scene node's message
    arrives (perf_counter seconds)."""

    def __init__(self, url: str) -> None:
        self.arrived: dict[str, float] = {}
        self._cv = threading.Condition()
        self._client = ViserClient(url, "arrival-clock")
        self._client.listeners.append(self._on_message)
        self._thread = threading.Thread(target=lambda: asyncio.run(self._client.run()), daemon=True)
        self._thread.start()

    def _on_message(self, _client: ViserClient, m: dict[str, Any], now: float) -> None:
        if isinstance(m.get("name"), str):
            with self._cv:
                self.arrived[m["name"]] = now
                self._cv.notify_all()

    def wait_for(self, name: str, after: float, timeout: float = 30.0) -> float:
        """Arrival time of node ``name`` sent after ``after`` (perf_counter), waiting up to ``timeout`` s."""
        with self._cv:
            ok = self._cv.wait_for(lambda: self.arrived.get(name, -1.0) > after, timeout)
        if not ok:
            raise TimeoutError(f"{name} did not arrive within {timeout} s")
        return self.arrived[name]
