"""What the viewer's parts share to run jobs and talk to the browsers: the status line's idle
text, the one-job-at-a-time slot, notifications and downloads.

viser runs plain ``def`` GUI callbacks in a thread pool, so two clicks can start two jobs at once
unless something stops the second.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import viser

if TYPE_CHECKING:
    from viser._gui_api import LiteralColor  # the notification colours viser takes; it does not export the name

log = logging.getLogger(__name__)

READY = "Ready. Click a segment to complete it."
# notify(client, title, body, color=None, auto_close=8.0): tell a browser (None: every browser).
Notify = Callable[..., None]


def notify_clients(
    server: viser.ViserServer,
    client: viser.ClientHandle | None,
    title: str,
    body: str,
    color: LiteralColor | None = None,
    auto_close: float | None = 8.0,
) -> None:
    """Tell ``client`` (every client when None or when it has gone) something; never raises.

    A job can outlive the browser that started it, so its client may have disconnected by the
    time it reports: everyone connected then hears about it (they share the panel anyway).
    """
    log.info("%s: %s", title, body)
    clients = server.get_clients()
    targets = [client] if client is not None and client.client_id in clients else list(clients.values())
    for c in targets:
        try:
            c.add_notification(title, body, color=color, auto_close_seconds=auto_close)
        except Exception:  # the browser went away mid-call
            log.debug("notification to client %s failed", c.client_id, exc_info=True)


def send_download(
    client: viser.ClientHandle | None,
    make: Callable[[], tuple[str, bytes]],
    notify: Notify,
    errors: tuple[type[Exception], ...] = (ValueError,),
) -> None:
    """Send the ``(file name, content)`` that ``make`` returns to ``client``'s browser; when it
    raises one of ``errors`` (a message for the user), show that instead."""
    try:
        name, data = make()
    except errors as e:
        notify(client, "Nothing to export", str(e), "red")
        return
    if client is not None:
        client.send_file_download(name, data, save_immediately=True)


class JobSlot:
    """Runs one job at a time; the buttons that start jobs are disabled while one runs (double
    clicks would queue jobs).

    Args:
        buttons: the job buttons.
        notify: tells a client that it has to wait.
        after: called when a job ends (the app clears its "loading" notifications).
    """

    def __init__(
        self, buttons: tuple[viser.GuiButtonHandle, ...], notify: Notify, after: Callable[[], None] | None = None
    ) -> None:
        self.lock = threading.Lock()  # held by the running job
        self.buttons = buttons
        self.notify = notify
        self.after = after

    @contextlib.contextmanager
    def take(self, client: viser.ClientHandle | None) -> Iterator[bool]:
        """Yields True while holding the slot, or False (after telling the client) when another job runs."""
        if not self.lock.acquire(blocking=False):
            self.notify(client, "Busy", "Another job is still running; try again in a moment.", auto_close=2.0)
            yield False
            return
        for b in self.buttons:
            b.disabled = True
        try:
            yield True
        finally:
            for b in self.buttons:
                b.disabled = False
            if self.after is not None:
                self.after()
            self.lock.release()
