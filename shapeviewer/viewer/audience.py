"""Who a viewer session draws for: one browser tab, or (headless use, tests) every browser.

viser gives each connected browser its own scene and GUI (``client.scene``, ``client.gui``): nodes
and controls added there exist for that tab only, and go when it closes. A session's parts
(drawing, panel, grasps, Dataset tab) take an :class:`Audience` instead of the server, so the same
code draws per tab in the app and server-wide when a script or test drives a session without a
browser.
"""

from __future__ import annotations

import json
import logging
import threading
from typing import Literal

import numpy as np
import viser
from viser import GuiApi, SceneApi
from viser._messages import (  # viser exports no names for these (end_upload_notice, show_tab)
    FileTransferStartUpload,
    RemoveNotificationMessage,
    RunJavascriptMessage,
)

from .sources import one_line

# The notification colours viser takes (its ``add_notification(color=...)``; viser does not export
# a name for them).
NotificationColor = Literal[
    "dark",
    "gray",
    "red",
    "pink",
    "grape",
    "violet",
    "indigo",
    "blue",
    "cyan",
    "green",
    "lime",
    "yellow",
    "orange",
    "teal",
]

log = logging.getLogger(__name__)

# viser's upload notification is shown by browser code that may run a moment after the app has
# taken it down (a busy page renders late): taken down again this long after (s). It closes by
# itself 4 s after the upload is done.
UPLOAD_NOTICE_AGAIN = (0.5, 1.5, 3.0)

# Activates a tab of the control panel as a keyboard user would (Enter on the tab); viser 1.1 has
# no Python call that chooses a tab group's active tab. Its docked panel draws a tab as
# ``[role=tab][data-dock-tab=<container id>]`` and activates it on Enter; its plain tab groups
# (phones, modals) are Mantine tabs ``[role=tab][id$="-tab-<container id>"]`` activated on click.
_SHOW_TAB_JS = """(() => {
  const id = %s;
  const docked = document.querySelector(`[role="tab"][data-dock-tab="${CSS.escape(id)}"]`);
  if (docked !== null) {
    docked.dispatchEvent(new KeyboardEvent("keydown", {key: "Enter", code: "Enter", bubbles: true}));
    return;
  }
  const plain = document.querySelector(`[role="tab"][id$="-tab-${CSS.escape(id)}"]`);
  if (plain !== null) plain.click();
})();"""


class Audience:
    """The browser(s) a session shows its scene, panel and notifications to.

    Args:
        server: the viser server.
        client: the browser tab of the session, or None for every browser (a headless session:
            its nodes and controls are the server's, seen by every tab).
    """

    def __init__(self, server: viser.ViserServer, client: viser.ClientHandle | None = None) -> None:
        self.server = server
        self.client = client
        self.scene: SceneApi = server.scene if client is None else client.scene
        self.gui: GuiApi = server.gui if client is None else client.gui
        # A tab that has not reported its camera yet cannot be aimed: aimed once it does.
        self._pending_aim: tuple[np.ndarray, np.ndarray] | None = None
        # Client id -> its latest upload's transfer id (viser's own upload notification is named after it).
        self._uploads: dict[int, str] = {}
        self._uploads_lock = threading.Lock()
        if client is not None:
            client.camera.on_update(self._aim_when_ready)
            client._websock_connection.register_handler(FileTransferStartUpload, self._upload_started)
        else:
            server._websock_server.register_handler(FileTransferStartUpload, self._upload_started)

    @property
    def client_id(self) -> int | None:
        """The tab's viser client id (None for a headless session)."""
        return None if self.client is None else self.client.client_id

    def get_clients(self) -> dict[int, viser.ClientHandle]:
        """The connected browsers this audience is made of, by client id (empty once the tab closed)."""
        clients = self.server.get_clients()
        if self.client is None:
            return clients
        return {self.client.client_id: self.client} if self.client.client_id in clients else {}

    def flush(self) -> None:
        """Send what is queued for these browsers now (viser otherwise batches for a moment)."""
        if self.client is None:
            self.server.flush()
        elif self.get_clients():
            self.client.flush()

    def notify(
        self,
        client: viser.ClientHandle | None,
        title: str,
        body: str,
        color: NotificationColor | None = None,
        auto_close: float | None = 8.0,
    ) -> None:
        """Show a notification; never raises (the tab may close mid-call).

        A tab's session tells its own tab whatever ``client`` says. A headless session tells
        ``client`` when it is still connected, else every browser: a job can outlive the tab that
        started it, and those left share the panel.
        """
        log.info("%s: %s", one_line(title), one_line(body))  # one log line, whatever a file name holds
        clients = self.get_clients()
        chosen = client if self.client is None else self.client
        targets = [chosen] if chosen is not None and chosen.client_id in clients else list(clients.values())
        for c in targets:
            try:
                c.add_notification(title, body, color=color, auto_close_seconds=auto_close)
            except Exception:  # the browser went away mid-call
                log.debug("notification to client %s failed", c.client_id, exc_info=True)

    def end_upload_notice(self, client: viser.ClientHandle | None) -> None:
        """Take down viser's own notification of ``client``'s latest upload.

        viser's upload button ends that notification with "File uploaded successfully." as soon as
        the bytes have arrived, before the app has read them; the app says what really happened
        (the capture's loading, then why it could not be loaded, if it could not)."""
        if client is None:
            return
        with self._uploads_lock:
            transfer = self._uploads.pop(client.client_id, None)
        if transfer is None:
            return
        # The id viser's browser code gives that notification ("upload-" + the transfer's id).
        message = RemoveNotificationMessage(f"upload-{transfer}")

        def remove() -> None:
            try:
                client._websock_connection.queue_message(message)
                client.flush()
            except Exception:  # the browser went away mid-call
                log.debug("removing the upload notification of client %s failed", client.client_id, exc_info=True)

        remove()
        for seconds in UPLOAD_NOTICE_AGAIN:  # removing a notification that is gone does nothing
            timer = threading.Timer(seconds, remove)
            timer.daemon = True
            timer.start()

    def show_tab(self, tab: viser.GuiTabHandle, client: viser.ClientHandle | None = None) -> None:
        """Bring ``tab`` to the front of its tab group in the browsers (``client``'s alone when it is
        given and still connected, as :meth:`notify`); never raises."""
        clients = self.get_clients()
        chosen = client if self.client is None else self.client
        targets = [chosen] if chosen is not None and chosen.client_id in clients else list(clients.values())
        source = _SHOW_TAB_JS % json.dumps(tab._id)  # the tab's container id (viser keeps it private)
        for c in targets:
            try:
                c._websock_connection.queue_message(RunJavascriptMessage(source=source))
            except Exception:  # the browser went away mid-call
                log.debug("showing a tab in client %s failed", c.client_id, exc_info=True)

    def loading(self, client: viser.ClientHandle | None, body: str) -> list[viser.NotificationHandle]:
        """A "Loading" notification (no close button) in each browser of the audience (only
        ``client``'s in a headless session, when given); the caller removes them."""
        if self.client is None and client is not None:
            clients = [client]
        else:
            clients = list(self.get_clients().values())
        notes = []
        for c in clients:
            try:
                notes.append(c.add_notification("Loading", body, loading=True, with_close_button=False))
            except Exception:  # the browser went away mid-call
                log.debug("notification to client %s failed", c.client_id, exc_info=True)
        return notes

    def point_cameras(self, position: np.ndarray, look_at: np.ndarray) -> None:
        """Aim the browsers' cameras (world metres, z up) from ``position`` at ``look_at``; a
        headless session also sets the camera new browsers start with."""
        if self.client is None:
            cam = self.server.initial_camera
            cam.position, cam.look_at, cam.up = position, look_at, (0.0, 0.0, 1.0)
        for client in self.get_clients().values():
            try:
                with client.atomic():
                    client.camera.up_direction = (0.0, 0.0, 1.0)
                    client.camera.position = position
                    client.camera.look_at = look_at
            except AssertionError:  # the client has not reported its camera yet
                self._pending_aim = (position, look_at)

    def _upload_started(self, client_id: int, message: FileTransferStartUpload) -> None:
        with self._uploads_lock:
            self._uploads[client_id] = message.transfer_uuid

    def _aim_when_ready(self, _camera: viser.CameraHandle) -> None:
        aim, self._pending_aim = self._pending_aim, None
        if aim is not None:
            self.point_cameras(*aim)
