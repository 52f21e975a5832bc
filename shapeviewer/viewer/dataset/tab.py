"""The Dataset tab: ties the results store to the controls, the 3D scene, the exports and the
background work (see the package docstring for what it shows)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import viser

from ...evaluation.methods import Method
from ...evaluation.records import KINDS, Metric
from ...evaluation.results import ResultsStore
from ...evaluation.summaries import CompletionResult, GraspSummary, ObjectSummary, ViewInfo
from ..audience import Audience
from ..gui import set_value
from ..jobs import send_download
from ..sources import markdown_text, one_line
from .controls import DatasetControls, build_controls
from .drawing import DatasetScene, DisplayMeshes, best_grasp_hands, hand_extents, place_hands
from .exports import export_bytes
from .layout import DATASET_FOV, ViewLayout, layout_view
from .summary import (
    bars_caption,
    column_label,
    index_markdown,
    object_label,
    panel_markdown,
    status_markdown,
    view_label,
    view_markdown,
)
from .work import BarsWorker, SampleBuild, poll_thread

log = logging.getLogger(__name__)

DEFAULT = "default"  # ``results=DEFAULT``: the sample store, built in the background when missing
MAX_OBJECT_OPTIONS = 500  # entries of the Object dropdown: the browser chokes on many thousands


@dataclass
class DatasetHooks:
    """What the tab needs from the app: hide/show the pipeline's nodes, open a capture in the pipeline."""

    set_pipeline_visible: Callable[[bool], None]
    open_capture: Callable[..., bool]  # (capture, client) -> loaded
    notify: Callable[..., None]  # (client, title, body, color=None)


@dataclass
class ShownView:
    """The view on screen: its records and layout (display frame), and how long showing it took (s)."""

    object: ObjectSummary
    info: ViewInfo
    completions: list[CompletionResult]
    grasps: list[GraspSummary]
    layout: ViewLayout
    seconds: float = 0.0


class DatasetTab:
    """The Dataset tab's state and actions; the GUI callbacks call the same methods.

    Args:
        audience: the session's browser tab (its scene is shared with the pipeline tab).
        tab: the tab to put the controls in; ``pipeline_tab`` gets a "back to the pipeline" button
            shown while the dataset is on screen.
        results: a results folder (it may still be empty while ``build`` fills it), or None (no
            store: the tab says how to open one).
        hooks: see :class:`DatasetHooks`.
        build: the server's background build of the sample store into ``results``, or None.
    """

    def __init__(
        self,
        audience: Audience,
        tab: viser.GuiTabHandle,
        pipeline_tab: viser.GuiTabHandle,
        results: Path | None,
        hooks: DatasetHooks,
        build: SampleBuild | None = None,
    ) -> None:
        self.audience = audience
        self.pipeline_tab = pipeline_tab
        self.hooks = hooks
        self.build = build
        self.store: ResultsStore | None = None
        self.active = False
        self.shown: ShownView | None = None
        self.objects: list[ObjectSummary] = []  # the filtered index
        self.total_objects = 0
        self.last_error: str | None = None
        self._lock = threading.RLock()  # GUI callbacks run in a thread pool
        self._closed = threading.Event()  # set by shutdown(): background threads stop touching the GUI
        self._generation = -1  # the store generation the index shows
        self.scene = DatasetScene(audience)
        self.meshes = DisplayMeshes()
        self.c: DatasetControls = build_controls(audience.gui, tab, pipeline_tab)
        self.bars = BarsWorker(self._show_bars, self._closed)
        self.c.wire(audience.gui, self, hooks.notify)
        self.c.progress.visible = self.building
        self._open(results)
        # Started once the store is open (a bad --results folder raises above and leaves no thread).
        self._threads = [self.bars.thread]
        if self.store is not None:
            self._threads.append(poll_thread(self.refresh, self._closed))
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------------------------------
    # Public API

    @property
    def building(self) -> bool:
        """Whether the sample store is being built."""
        return self.build is not None and self.build.running

    @property
    def bars_drawn(self) -> tuple | None:
        """The ``(method, metric, objects)`` key of the per-object chart on screen."""
        return self.bars.drawn

    @property
    def drawn(self) -> dict[str, viser.SceneNodeHandle]:
        """The dataset's scene nodes now drawn for the session, by name."""
        return self.scene.handles()

    def shown_view(self) -> tuple[str, int] | None:
        """``(object, view)`` on screen, or None."""
        shown = self.shown
        return None if shown is None else (shown.info.object, shown.info.view)

    def select(self, name: str, view: int | None = None, client: viser.ClientHandle | None = None) -> bool:
        """Show object ``name``'s view ``view`` (default: its first) in 3D. False when there is none."""
        with self._lock:
            if self.store is None:
                self.hooks.notify(client, "No results store", "Open one with --results DIR.", "yellow")
                return False
            views = self.store.views(name)
            info = next((v for v in views if v.view == view), None) if view is not None else next(iter(views), None)
            if info is None:
                what = f"{name} has no view with results." if not views else f"{name} has no results for view {view}."
                self.hooks.notify(client, "No results" if not views else "No such view", what, "yellow")
                self._sync_selectors()  # the dropdowns show what is on screen, not the refused choice
                return False
            try:
                self._show(info, client)
            except Exception as e:  # a missing or broken mesh file: say so, keep the app alive
                log.warning("showing %s view %d failed: %s", one_line(name), info.view, one_line(str(e)), exc_info=True)
                self.last_error = f"{name} view {info.view}: {e}"
                self.hooks.notify(client, "Cannot show the view", self.last_error, "red")
                self._sync_selectors()
                return False
            self._sync_selectors()
            return True

    def step(self, what: str, delta: int, client: viser.ClientHandle | None = None) -> bool:
        """Go to the next (``delta`` = 1) or previous (-1) ``view`` of the object, or ``object`` of the index."""
        with self._lock:
            if self.store is None or not self.objects:
                return False
            if self.shown is None:
                return self.select(self.objects[0].name, None, client)
            name, view = self.shown.info.object, self.shown.info.view
            if what == "view":
                views = [v.view for v in self.store.views(name)]
                i = views.index(view) if view in views else 0
                return self.select(name, views[(i + delta) % len(views)], client)
            names = [o.name for o in self.objects if o.views]
            if not names:
                return False
            i = names.index(name) if name in names else (-1 if delta > 0 else 0)
            return self.select(names[(i + delta) % len(names)], None, client)

    def show(self, client: viser.ClientHandle | None = None) -> None:
        """Put the dataset on screen (hides the pipeline's nodes); shows the first object if none is chosen."""
        with self._lock:
            if self.shown is None:
                first = next((o.name for o in self.objects if o.views), None)
                if first is None:
                    self.hooks.notify(
                        client, "Nothing to show", "No object in the index has a view with results.", "yellow"
                    )
                    return
                self.select(first, None, client)
                return
            self._show(self.shown.info, client)  # drawn anew: leaving took it off the scene

    def leave(self, client: viser.ClientHandle | None = None) -> None:
        """Back to the pipeline: hide the dataset, show the pipeline's nodes and the cameras as they were."""
        with self._lock:
            if not self.active:
                return
            self.active = False
            self.scene.remove_root()
            self.hooks.set_pipeline_visible(True)
            self.scene.restore_cameras()
            self.c.set_shown(False)

    def open_in_pipeline(self, client: viser.ClientHandle | None = None) -> bool:
        """Send the shown view's capture (its saved partial points) to the Pipeline tab, and bring
        that tab to the front once the capture is loaded.

        The dataset stays on screen while the capture loads (loading it leaves the dataset, as any
        new scene does): the pipeline's scene is never drawn under the Dataset tab, and a capture
        that cannot be loaded leaves the view where it was."""
        with self._lock:
            if self.shown is None:
                self.hooks.notify(client, "No view", "Choose a view first.", "yellow")
                return False
            info = self.shown.info
            assert self.store is not None  # a view is shown only from a store
            try:
                capture = self.store.capture(info.object, info.view)
            except Exception as e:
                self.hooks.notify(client, "Cannot open the view", f"{info.object} view {info.view}: {e}", "red")
                return False
        ok = self.hooks.open_capture(capture, client)
        if ok:
            self.leave(client)  # done by loading the scene already; nothing when so
            self.audience.show_tab(self.pipeline_tab, client)
            self.hooks.notify(
                client,
                "Opened in the Pipeline tab",
                f"{info.object} view {info.view}: click the segment to complete it.",
                "green",
            )
        return ok

    def export_bytes(
        self, what: str, kind: str | None = None, mesh_format: str = "ply", frame: str = "camera"
    ) -> tuple[str, bytes]:
        """``(file name, content)`` of an export of the store, the index or the shown view (full
        resolution); see :func:`~.exports.export_bytes`. Raises ValueError for the user."""
        shown = self.shown
        return export_bytes(
            self.store,
            self.objects,
            None if shown is None else shown.info,
            [] if shown is None else shown.grasps,
            what,
            kind,
            mesh_format,
            frame,
        )

    def download(self, client: viser.ClientHandle | None, what: str) -> None:
        """Send export ``what`` (with the Export folder's choices) to ``client``'s browser."""
        c = self.c
        send_download(
            client,
            lambda: self.export_bytes(
                what, c.choice(c.export_kind), c.choice(c.export_format), c.choice(c.export_frame)
            ),
            self.hooks.notify,
            (ValueError, OSError),
        )

    def refresh(self) -> None:
        """Re-read the store (new views of a running evaluation) and redraw the index if it changed."""
        with self._lock:
            if self.store is None:
                return
            report = self.store.sync()
            if self._closed.is_set():  # the server stopped meanwhile: no GUI to update
                return
            generation = self.store.generation()  # also changed by other stores on the folder
            if generation != self._generation:
                self.refresh_index()
            elif report.skipped:
                self.c.status.content = self._status_text()

    def refresh_index(self) -> None:
        """Apply the filters: the index table, status, dropdowns, summary tables and chart."""
        with self._lock:
            if self.store is None:
                return
            f = self.c.filters()
            self._generation = self.store.generation()
            self.objects = self.store.objects(**f)
            self.total_objects = len(self.store.objects(with_results=f["with_results"]))
            selected = self.shown.info.object if self.shown else None
            self.c.index.content = index_markdown(self.objects, f["method"], f["metric"], selected, self.total_objects)
            self.c.status.content = self._status_text()
            self._sync_selectors()
            self.c.summary.content = panel_markdown(self.store.summary(), self.store.grasp_summary())
            self.bars.request(self.objects, f["method"], f["metric"])

    def build_progress(self, percent: float, text: str | None) -> None:
        """The sample build's progress (``text`` None: it is over; the status says what the store holds)."""
        if self._closed.is_set():
            return
        set_value(self.c.progress, percent)
        self.c.progress.visible = text is not None
        self.c.status.content = self._status_text() if text is None else text

    def shutdown(self) -> None:
        """Stop the background work before the server goes away (waits for a chart or index update
        in progress; the sample build stops at its next step)."""
        self._closed.set()
        self.bars.wake()
        for t in self._threads:
            t.join(timeout=10.0)

    # ------------------------------------------------------------------------------------------
    # Helpers

    def _open(self, results: Path | None) -> None:
        if results is None:
            self.c.status.content = (
                "_No results store._ Start the viewer with `--results DIR` (a folder written by "
                "`shapeviewer evaluate`)."
            )
            return
        # The app has checked the folder; the sample store's may not exist yet (its build writes it).
        self.store = ResultsStore(results)
        self.refresh_index()

    def _status_text(self) -> str:
        assert self.store is not None  # called by refresh(), refresh_index() and the sample build: all with a store
        return status_markdown(self.store.counts(), str(self.store.root), self.building)

    def build_failed(self, message: str) -> None:
        """The sample build failed with ``message``: say so in the tab."""
        self.last_error = message
        if not self._closed.is_set():
            self.c.progress.visible = False
            self.c.status.content = f"**Building the sample store failed:** {markdown_text(message)}"

    def _show_bars(self, png: bytes | None, method: Method, metric: Metric) -> None:
        self.c.show_bars(self.audience.gui, png, bars_caption(method, metric))

    def _sync_selectors(self) -> None:
        """Fill the object and view dropdowns from the index and the shown view (no callbacks act)."""
        f = self.c.filters()
        method, metric = f["method"], f["metric"]
        objects = self.objects[:MAX_OBJECT_OPTIONS]
        shown = self.shown
        if shown is not None and all(o.name != shown.info.object for o in objects):
            # Keep the shown object choosable even when the filters hide it.
            objects = [next((o for o in self.objects if o.name == shown.info.object), shown.object), *objects]
        if shown is not None:
            assert self.store is not None  # a view is shown only from a store
            views = self.store.views(shown.info.object)
        else:
            views = []
        self.c.sync_selectors(
            {object_label(o, method, metric): o.name for o in objects},
            None if shown is None else shown.info.object,
            {view_label(v): v.view for v in views},
            None if shown is None else shown.info.view,
        )

    def _show(self, info: ViewInfo, client: viser.ClientHandle | None) -> None:
        """Read view ``info``'s records and files, lay them out and draw them; aim the cameras."""
        t0 = time.perf_counter()
        store = self.store
        assert store is not None  # select() checked
        name = info.object
        o = next((x for x in self.objects if x.name == name), None) or store.object(name)
        completions = store.completions(name, info.view)
        grasps = store.grasps(name, info.view)
        by_method = {c.method: c for c in completions}
        files = {"truth": info.truth, "points": info.points, **{m: c.mesh for m, c in by_method.items()}}
        items = {
            kind: self.meshes.get(store.path(file), kind == "points") for kind in KINDS if (file := files.get(kind))
        }
        if "truth" not in items:
            raise ValueError("the view has no ground-truth mesh file")
        kinds = tuple(k for k in KINDS if k in items or k in by_method)
        column_hands = best_grasp_hands(store, info, grasps, kinds) if self.c.show_grasps.value else []
        layout = layout_view(
            store.T_cam_obj(name, info.view),
            items["truth"][0],
            {k: v[0] for k, v in items.items()},
            kinds,
            self.scene.aspect(client),
            extras_cam=hand_extents(column_hands),
        )
        labels = {k: column_label(k, len(items[k][0]) if k in items else 0, by_method.get(k), grasps) for k in kinds}
        hands = place_hands(column_hands, layout)
        self._activate(None)  # the root first: the view is drawn under it
        self.scene.draw(layout, kinds, items, labels, hands)
        self.shown = ShownView(o, info, completions, grasps, layout)
        self.c.details.content = view_markdown(o, info, completions, grasps)
        self._activate(layout)
        self.audience.flush()
        self.shown.seconds = time.perf_counter() - t0
        f = self.c.filters()
        self.c.index.content = index_markdown(self.objects, f["method"], f["metric"], name, self.total_objects)

    def _activate(self, layout: ViewLayout | None) -> None:
        """Show the dataset root (hiding the pipeline) and point every browser camera at ``layout``'s row."""
        if not self.active:
            self.active = True
            self.hooks.set_pipeline_visible(False)
            self.scene.show_root()
            self.c.set_shown(True)
        if layout is not None:
            self.scene.aim_cameras(layout, DATASET_FOV)
