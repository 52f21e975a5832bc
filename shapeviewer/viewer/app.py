"""The web viewer of the paper's runtime pipeline (Fig. 5, steps 1-5a), served with viser.

:class:`ViewerApp` is the server: it loads what every browser shares once (the CNN, the default
scenes, the sample results store, a bounded pool of worker threads and one of worker processes for
grasp jobs) and gives each browser tab its own :class:`~.session.Session` (its capture, selection,
completions, grasps and Dataset tab, drawn with viser's per-client scene and GUI), closed with the
tab. :meth:`ViewerApp.open_session` opens a session without a browser, drawn server-wide, for
scripts and tests.
"""

from __future__ import annotations

import ctypes
import gc
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import viser
from PIL import Image

from ..completion.model import load_completer, training_curves
from ..evaluation.sample_store import sample_store_complete, sample_store_dir
from ..perception.camera import Intrinsics
from ..perception.capture import Capture, load_capture
from ..runtime.processes import ProcessPool
from . import panel as P
from .audience import Audience
from .context import SessionResources
from .dataset import DEFAULT, SampleBuild
from .guard import Guard, UploadLimit, listen_port, server_url, start_server
from .jobs import WorkerPool
from .session import Session
from .sources import upload_name, upload_problem
from .state import LoadedScene, load_scene

log = logging.getLogger(__name__)

MAX_CACHED_SCENES = 4  # default scenes kept for new sessions and "New scene" (a few MB each)


class ViewerApp:
    """The viewer server and its sessions.

    Args:
        host, port: where to serve (viser takes the next free port if ``port`` is busy: see ``.port``).
        seed: seed of the generated default scene (used when ``cloud`` is None).
        cloud: a capture file path (.pcd/.ply/.png/.npy), a :class:`Capture`, or None (default
            scene): the scene every new session starts with.
        weights: CNN weights file; None = the shipped model (untrained fallback when absent).
        intrinsics: camera intrinsics for depth images.
        max_cloud_points: draw at most this many points of the Cloud layer (None = what is left of
            :data:`~.drawing.MAX_SENT_POINTS` after the segments); picking and completion use every point.
        announce: called with the URL as soon as the server listens (before the scene is built).
        token: the URL token required off localhost (default: a random one; see :mod:`.guard`).
        allow_hosts: further ``Host`` names to answer to besides localhost and ``host``.
        results: the Dataset tab's results store: a folder written by ``shapeviewer evaluate``,
            :data:`~.dataset.DEFAULT` (a small sample store, built in the background on first use), or
            None (none).
        data_dir: a folder of the server whose capture files browsers may load ("Server file"
            dropdown; nothing outside it). None (default): browsers can only upload their own files.
        workers: jobs of all sessions that compute at once (default: the CPU count, at most 4).
        sessions: True (default): each browser tab gets its own session. False: no session opens
            by itself (a script or test opens one with :meth:`open_session`).
        max_upload_bytes: the largest capture a browser may upload; larger ones are refused when
            the browser announces their size, before any of their bytes is kept (:class:`.guard.UploadLimit`).

    Raises:
        ServeError: ``host`` is not an address of this machine, or no port from ``port`` on can be
            listened on (:func:`.guard.listen_port`).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8080,
        seed: int = 0,
        cloud: str | Path | Capture | None = None,
        weights: str | Path | None = None,
        intrinsics: Intrinsics | None = None,
        max_cloud_points: int | None = None,
        announce: Callable[[str], None] | None = None,
        results: str | Path | None = None,
        token: str | None = None,
        allow_hosts: tuple[str, ...] = (),
        data_dir: str | Path | None = None,
        workers: int | None = None,
        sessions: bool = True,
        max_upload_bytes: int = P.MAX_UPLOAD_MB * 2**20,
    ) -> None:
        data_path = None if data_dir is None else Path(data_dir).expanduser().resolve()
        if data_path is not None and not data_path.is_dir():
            raise NotADirectoryError(f"--data-dir {data_dir}: not a folder")
        results_path = self._results_path(results, weights)
        self.seed = int(seed)
        self.sessions: dict[int, Session] = {}  # viser client id -> the tab's session
        self._headless: list[Session] = []
        self._sessions_lock = threading.Lock()
        self._opening: set[int] = set()  # client ids whose session is being built
        self._scenes: dict[int, LoadedScene] = {}  # seed -> default scene, most recent last
        self._scenes_lock = threading.Lock()
        self._first: LoadedScene | None = None
        self._first_lock = threading.Lock()
        self._cloud = cloud
        self._stopping = False
        self.res: SessionResources | None = None  # set once the model and the first scene are loaded
        self._waiting: dict[int, viser.NotificationHandle] = {}  # client id -> "loading" note, until res
        port = listen_port(host, port)  # a bad --host or --port: one clear error, not a hung thread
        # Only this machine's browser (or, off localhost, holders of the token) may drive the app.
        self.guard = Guard.for_host(host, token, allow_hosts)
        self.server = start_server(host, port, self.guard)
        self.port = self.server.get_port()
        self.host = host
        self.max_upload_bytes = int(max_upload_bytes)
        self.uploads = UploadLimit(self.max_upload_bytes, self._upload_refused)
        try:
            self.uploads.install(self.server.gui)  # headless sessions' upload buttons
        except BaseException:
            self.server.stop()
            raise
        self.server.gui.configure_theme(control_width="medium", show_share_button=False)
        # Docked, the panel takes its own column instead of floating over (and hiding) the scene.
        self.server.gui.main_panel.dock_right()
        self.server.scene.set_up_direction("+z")
        if sessions:
            self.server.on_client_connect(self._connect)
            self.server.on_client_disconnect(self._disconnect)
        if announce is not None:
            announce(self.url)
        try:
            self.first_scene(intrinsics)  # a bad --cloud fails here, before any browser sees a panel
            completer = load_completer(weights)
            curves = training_curves(completer)
            sample_build = None
            if results == DEFAULT and results_path is not None and not sample_store_complete(results_path):
                sample_build = SampleBuild(self.server, self._dataset_tabs)
                # Sharing the app's CNN (inference only) also keeps two threads from loading models
                # at once: TorchScript parses Python source, and CPython 3.11's ``ast.parse`` is not
                # thread-safe.
                sample_build.start(results_path, weights, completer)
            workers = min(os.cpu_count() or 1, 4) if workers is None else workers
            self.res = SessionResources(
                completer=completer,
                model_markdown=P.model_markdown(
                    completer.arch, Path(completer.source).name, completer.trained, completer.meta
                ),
                curves_png=None if curves is None else np.asarray(Image.open(curves).convert("RGB")),
                first_scene=lambda: self.first_scene(intrinsics),
                default_scene=self.default_scene,
                pool=WorkerPool(workers),
                grasp_pool=ProcessPool(max(1, workers // 2), name="viewer-grasp"),
                intrinsics=intrinsics,
                data_dir=data_path,
                max_upload_bytes=self.max_upload_bytes,
                max_cloud_points=max_cloud_points,
                results=results_path,
                sample_build=sample_build,
            )
        except BaseException:  # a bad --cloud/--weights/--results: do not leave the server thread running
            self.server.stop()
            raise
        if sessions:
            for client in list(self.server.get_clients().values()):  # browsers that came while loading
                self._connect(client)

    # ------------------------------------------------------------------------------------------
    # Public API

    @property
    def url(self) -> str:
        """The URL to open (with ``?token=...`` when the server is reachable off this machine)."""
        return server_url(self.host, self.port, self.guard)

    def open_session(self, client: viser.ClientHandle | None = None) -> Session:
        """A session for ``client``'s tab, or (None) one without a browser, drawn server-wide so
        that every browser sees it: for scripts and tests. Closed by :meth:`stop`."""
        if self.res is None:
            raise RuntimeError("the viewer is still loading")
        if client is not None:
            self.uploads.install(client.gui)  # before the tab's upload button exists
        session = Session(Audience(self.server, client), self.res, self.seed)
        with self._sessions_lock:
            if client is None:
                self._headless.append(session)
            else:
                self.sessions[client.client_id] = session
        return session

    def session_of(self, client: viser.ClientHandle | int) -> Session | None:
        """The session of a browser tab (by handle or client id), or None."""
        return self.sessions.get(client if isinstance(client, int) else client.client_id)

    def first_scene(self, intrinsics: Intrinsics | None = None) -> LoadedScene:
        """The scene new sessions start with: ``cloud`` segmented once, or the default scene of ``seed``."""
        with self._first_lock:
            if self._first is None:
                cloud = self._cloud
                if cloud is None:
                    self._first = self.default_scene(self.seed)
                else:
                    capture = (
                        cloud
                        if isinstance(cloud, Capture)
                        else load_capture(Path(cloud).expanduser(), intrinsics=intrinsics)
                    )
                    self._first = load_scene(capture)
            return self._first

    def default_scene(self, seed: int) -> LoadedScene:
        """The generated tabletop scene of ``seed``, segmented; the last few are kept for every session."""
        from ..sim.demo_scene import default_scene  # pybullet and the object catalogue: only when needed

        with self._scenes_lock:
            scene = self._scenes.pop(seed, None)
            if scene is None:
                scene = load_scene(default_scene(int(seed)))
            self._scenes[seed] = scene
            while len(self._scenes) > MAX_CACHED_SCENES:
                self._scenes.pop(next(iter(self._scenes)))
            return scene

    def stop(self) -> None:
        """Close every session, then the server."""
        self._stopping = True
        with self._sessions_lock:
            sessions = [*self.sessions.values(), *self._headless]
            self.sessions.clear()
            self._headless.clear()
        for s in sessions:
            s.close()
        if self.res is not None:
            if self.res.sample_build is not None:
                self.res.sample_build.stop()
            self.res.pool.shutdown()
            self.res.grasp_pool.shutdown()
        self.server.stop()

    # ------------------------------------------------------------------------------------------
    # Browser tabs

    def _connect(self, client: viser.ClientHandle) -> None:
        cid = client.client_id
        with self._sessions_lock:  # viser's hook and __init__'s catch-up may both call this
            if self._stopping or cid in self.sessions or cid in self._opening:
                return
            if self.res is None:  # still loading the model and the first scene: opened once they are
                if cid not in self._waiting:
                    self._waiting[cid] = client.add_notification(
                        "Loading the scene", "Loading the model and the scene...", loading=True, with_close_button=False
                    )
                return
            self._opening.add(cid)
            note = self._waiting.pop(cid, None)
        if note is not None:
            note.remove()
        try:
            self.open_session(client)
        except Exception:  # a tab that closed while its session was being built
            log.warning("opening a session for client %s failed", cid, exc_info=True)
        finally:
            self._opening.discard(cid)
        if cid not in self.server.get_clients():  # it closed meanwhile: free it now
            self._disconnect(client)

    def _disconnect(self, client: viser.ClientHandle) -> None:
        self._waiting.pop(client.client_id, None)
        with self._sessions_lock:
            session = self.sessions.pop(client.client_id, None)
        if session is not None:
            session.close()
            del session
            release_memory()

    def _upload_refused(self, client_id: int, filename: str, size: int, announced: bool) -> None:
        """Tell the browser that sent it why an upload was refused (on viser's event loop: only
        queues messages)."""
        shown = upload_name(filename)  # one line, and short
        problem = upload_problem(shown, size, self.max_upload_bytes) or "more bytes than it announced"
        if not announced:
            problem = f"{problem} (refused while receiving)"
        log.warning("refused an upload from client %s: %s: %s", client_id, shown, problem)
        client = self.server.get_clients().get(client_id)
        if client is not None:
            client.add_notification("Could not load the capture", f"{shown}: {problem}", color="red")

    def _dataset_tabs(self) -> list:
        with self._sessions_lock:
            sessions = [*self.sessions.values(), *self._headless]
        return [s.dataset for s in sessions if s.dataset is not None]

    @staticmethod
    def _results_path(results: str | Path | None, weights: str | Path | None) -> Path | None:
        if results is None:
            return None
        if results == DEFAULT:
            return sample_store_dir(weights)
        root = Path(results).expanduser()
        if not root.is_dir():
            raise FileNotFoundError(f"results folder not found: {root}")
        return root


def release_memory() -> None:
    """Give memory that closed sessions freed back to the system.

    The C allocator keeps freed blocks in per-thread arenas (viser serves each tab's callbacks on
    its thread pool), so without a trim a server's memory would only grow with every tab that came
    and went. glibc only; elsewhere this only collects garbage.
    """
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass


def serve(
    host: str = "127.0.0.1",
    port: int = 8080,
    seed: int = 0,
    cloud: str | Path | None = None,
    weights: str | Path | None = None,
    intrinsics: Intrinsics | None = None,
    block: bool = True,
    results: str | Path | None = None,
    allow_hosts: tuple[str, ...] = (),
    data_dir: str | Path | None = None,
) -> ViewerApp:
    """Start the viewer (``python app.py`` and ``shapeviewer serve``); print its URL; serve until Ctrl-C.

    ``results``: the Dataset tab's results folder; None = the sample store in the user cache (built
    in the background on first run). ``allow_hosts``: more names the server answers to (see
    :mod:`.guard`). ``data_dir``: a folder whose capture files browsers may load (None: uploads only).
    With ``block=False`` returns the running :class:`ViewerApp` instead.
    """
    app = ViewerApp(
        host,
        port,
        seed,
        cloud,
        weights,
        intrinsics,
        announce=lambda url: print(f"shapeviewer: serving on {url} (building the scene...)", flush=True),
        results=DEFAULT if results is None else results,
        allow_hosts=allow_hosts,
        data_dir=data_dir,
    )
    print(f"shapeviewer: ready on {app.url}  (Ctrl-C to stop)", flush=True)
    if not block:
        return app
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
    return app
