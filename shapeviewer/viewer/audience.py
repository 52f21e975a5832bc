"""Who a viewer session draws for: one browser tab, or (headless use, tests) every browser.

viser gives each connected browser its own scene and GUI (``client.scene``, ``client.gui``): nodes
and controls added there exist for that tab only, and go when it closes. A session's parts
(drawing, panel, grasps, Dataset tab) take an :class:`Audience` instead of the server, so the same
code draws per tab in the app and server-wide when a script or test drives a session without a
browser.
"""

from __future__ import annotations

import logging
from typing import Literal

import numpy as np
import viser
from viser import GuiApi, SceneApi

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
        if client is not None:
            client.camera.on_update(self._aim_when_ready)

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
        log.info("%s: %s", title, body)
        clients = self.get_clients()
        chosen = client if self.client is None else self.client
        targets = [chosen] if chosen is not None and chosen.client_id in clients else list(clients.values())
        for c in targets:
            try:
                c.add_notification(title, body, color=color, auto_close_seconds=auto_close)
            except Exception:  # the browser went away mid-call
                log.debug("notification to client %s failed", c.client_id, exc_info=True)

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

    def _aim_when_ready(self, _camera: viser.CameraHandle) -> None:
        aim, self._pending_aim = self._pending_aim, None
        if aim is not None:
            self.point_cameras(*aim)
