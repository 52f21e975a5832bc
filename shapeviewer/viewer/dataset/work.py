"""The Dataset tab's background work: the per-object chart, polling the store, building the sample store.

Each runs in a daemon thread and stops once the tab's ``closed`` event is set (the viewer is
stopping): from then on none of them touches the GUI.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Protocol

import viser

from ...errors import Cancelled
from ...evaluation.methods import Method
from ...evaluation.records import Metric
from ...evaluation.sample_store import build_sample_store
from ...evaluation.summaries import ObjectSummary
from .summary import bars_png, path_markdown, styled, worst_first

log = logging.getLogger(__name__)

POLL_SECONDS = 5.0  # how often the tab looks for new view files


class BuildListener(Protocol):
    """What the sample build tells a Dataset tab (:class:`~.tab.DatasetTab` is one)."""

    def build_progress(self, percent: float, text: str | None) -> None: ...

    def build_failed(self, message: str) -> None: ...

    def refresh(self) -> None: ...


class BarsWorker:
    """Draws the per-object chart for the latest request.

    Drawing takes most of a second, so it runs in its own thread and skips requests that a newer
    one replaced: typing in the search box stays quick.

    Args:
        show: called (in the worker thread) with the PNG (None: nothing to plot), method and metric.
        closed: set when the tab shuts down.
    """

    def __init__(self, show: Callable[[bytes | None, Method, Metric], None], closed: threading.Event) -> None:
        self.key: tuple | None = None  # the latest requested chart
        self.drawn: tuple | None = None  # the key of the chart on screen
        self._show = show
        self._closed = closed
        self._request: tuple[tuple, list[ObjectSummary], Method, Metric] | None = None  # (key, objects, method, metric)
        self._wanted = threading.Event()
        self.thread = threading.Thread(target=self._run, name="dataset-bars", daemon=True)

    def request(self, objects: list[ObjectSummary], method: Method, metric: Metric) -> None:
        """Ask for the chart of ``method``'s ``metric`` over ``objects`` (nothing when it is the latest)."""
        key = (method, metric, tuple((o.name, o.views) for o in objects))
        if key != self.key:
            self.key = key
            self._request = (key, objects, method, metric)
            self._wanted.set()

    def wake(self) -> None:
        """Let the thread see that the tab has closed."""
        self._wanted.set()

    def _run(self) -> None:
        while not self._closed.is_set():
            self._wanted.wait()
            self._wanted.clear()
            if self._closed.is_set():
                return
            assert self._request is not None  # set before _wanted (wake() sets it only when closing)
            key, objects, method, metric = self._request
            try:
                png = bars_png(worst_first(objects, method, metric), metric)
            except Exception:  # a chart must never take the tab down
                log.exception("drawing the per-object bars failed")
                continue
            if self._wanted.is_set() or self._closed.is_set():  # a newer request came in, or closing
                continue
            self._show(png, method, metric)
            self.drawn = key


def poll_thread(refresh: Callable[[], None], closed: threading.Event) -> threading.Thread:
    """A (not yet started) thread that calls ``refresh`` every :data:`POLL_SECONDS` until ``closed``,
    to pick up the views that a running evaluation (or the sample build) adds."""

    def run() -> None:
        while not closed.wait(POLL_SECONDS):
            try:
                refresh()
            except Exception:  # an unreadable folder for a moment: try again next time
                log.warning("refreshing the results store failed", exc_info=True)

    return threading.Thread(target=run, name="dataset-poll", daemon=True)


# Raised in the sample build's progress callback when the viewer stops.


class SampleBuild:
    """Evaluates the sample views into the sample results store in the background, once per
    server; the index of every session's Dataset tab fills in as views finish. Every browser
    (also those connecting later) sees a progress notification until it is done.

    Args:
        server: for the notifications.
        tabs: the open sessions' Dataset tabs (asked at each step: sessions come and go).
    """

    def __init__(self, server: viser.ViserServer, tabs: Callable[[], Sequence[BuildListener]]) -> None:
        self.server = server
        self.tabs = tabs
        self.running = False
        self._stopped = threading.Event()
        self._notes: dict[int, viser.NotificationHandle] = {}  # client id -> progress notification
        self._step = ""
        server.on_client_connect(self._add_note)

        @server.on_client_disconnect
        def _(client: viser.ClientHandle) -> None:
            self._notes.pop(client.client_id, None)

    def start(self, root: Path, weights, completer) -> None:
        """Build the sample store in ``root`` with ``completer`` (a
        :class:`~shapeviewer.completion.model.Completer`) loaded from ``weights``, in a daemon thread."""
        self.running = True
        threading.Thread(target=self._run, args=(root, weights, completer), name="sample-store", daemon=True).start()

    def stop(self) -> None:
        """Stop at the next step (the server is stopping)."""
        self._stopped.set()

    def _run(self, root: Path, weights, completer) -> None:
        self._step = "starting"

        def progress(done: int, total: int, what: str) -> None:
            if self._stopped.is_set():
                raise Cancelled
            if what == "done":
                return
            self._step = f"step {done + 1} of {total}: {what}"
            text = styled([f"_Building the sample results store ({self._step})..._  \n" + path_markdown(str(root))])
            for tab in self.tabs():
                tab.build_progress(100.0 * done / max(total, 1), text)
                if done:
                    tab.refresh()
            for note in list(self._notes.values()):
                note.body = self._note_body()

        for client in self.server.get_clients().values():
            self._add_note(client)
        try:
            build_sample_store(root, weights=weights, progress=progress, completer=completer)
        except Cancelled:
            return
        except Exception as e:  # keep the viewer alive; say why in the tabs
            log.exception("building the sample store failed")
            for tab in self.tabs():
                tab.build_failed(f"sample store: {e}")
            return
        finally:
            self.running = False
            if not self._stopped.is_set():
                for note in list(self._notes.values()):
                    note.remove()
            self._notes.clear()
        for tab in self.tabs():
            tab.refresh()
            tab.build_progress(100.0, None)

    def _note_body(self) -> str:
        return (
            f"The Dataset tab is evaluating a few sample views in the background (first run only): "
            f"{self._step}. Views appear in the tab as they finish."
        )

    def _add_note(self, client: viser.ClientHandle) -> None:
        if self.running and client.client_id not in self._notes:
            self._notes[client.client_id] = client.add_notification(
                "Dataset tab: building sample results", self._note_body(), loading=True, with_close_button=True
            )
