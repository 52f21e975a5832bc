"""Only the user's own browser drives the viewer: foreign Origin / Host refused, a token off localhost.

The checks run against real servers on this machine's loopback interface: a bare guarded viser
server (fast) and one full :class:`ViewerApp` bound to 0.0.0.0, which shows that the app is
wired through the guard.
"""

from __future__ import annotations

import asyncio
import http.client
import socket

import numpy as np
import pytest
import viser
import websockets
from websockets.exceptions import InvalidStatus

from shapeviewer.perception.capture import Capture
from shapeviewer.viewer.guard import Guard, cookie_name, server_url, start_server

from helpers import free_port

SUBPROTOCOL = f"viser-v{viser.__version__}"


def http_get(port: int, path: str = "/", host: str | None = None, **headers: str) -> tuple[int, dict, bytes]:
    """GET ``path`` from 127.0.0.1:``port`` with the given ``Host`` (default: the right one) and headers."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.putrequest("GET", path, skip_host=True)
        conn.putheader("Host", host or f"127.0.0.1:{port}")
        for k, v in headers.items():
            conn.putheader(k.replace("_", "-"), v)
        conn.endheaders()
        r = conn.getresponse()
        return r.status, dict(r.getheaders()), r.read()
    finally:
        conn.close()


def ws_connect(
    port: int, origin: str | None = None, path: str = "/", host: str | None = None, cookie: str | None = None
) -> str:
    """Open viser's WebSocket on 127.0.0.1:``port`` (``host`` is only what the Host header says):
    ``"ok"`` once the server sent its first message, else ``"refused <status>"``."""

    async def run() -> str:
        uri = f"ws://{host or f'127.0.0.1:{port}'}{path}"
        headers = {"Cookie": cookie} if cookie else None
        try:
            async with websockets.connect(
                uri,
                origin=origin,
                subprotocols=[SUBPROTOCOL],
                host="127.0.0.1",
                port=port,
                additional_headers=headers,
                open_timeout=10,
            ) as ws:
                await asyncio.wait_for(ws.recv(), 10)
                return "ok"
        except InvalidStatus as e:
            return f"refused {e.response.status_code}"

    return asyncio.run(run())


@pytest.fixture(scope="module")
def local_server():
    guard = Guard.for_host("127.0.0.1")
    server = start_server("127.0.0.1", free_port(), guard)
    yield server.get_port(), guard
    server.stop()


@pytest.fixture(scope="module")
def public_server():
    guard = Guard.for_host("0.0.0.0")
    server = start_server("0.0.0.0", free_port(), guard)
    yield server.get_port(), guard
    server.stop()


def test_loopback_server_needs_no_token(local_server):
    port, guard = local_server
    assert guard.token is None
    assert server_url("127.0.0.1", port, guard) == f"http://127.0.0.1:{port}"
    status, _, body = http_get(port)
    assert status == 200 and b"<html" in body.lower()
    for name in ("localhost", "[::1]"):
        assert http_get(port, host=f"{name}:{port}")[0] == 200


@pytest.mark.parametrize(
    "origin", ["http://evil.example", "null", "http://127.0.0.1:1", "file://", "http://localhost.evil.example"]
)
def test_foreign_origin_websocket_is_refused(local_server, origin):
    port, _ = local_server
    assert ws_connect(port, origin=origin) == "refused 403"


def test_own_origin_websocket_works(local_server):
    port, _ = local_server
    assert ws_connect(port, origin=f"http://127.0.0.1:{port}") == "ok"
    assert ws_connect(port, origin=f"http://localhost:{port}") == "ok"
    assert ws_connect(port) == "ok"  # no Origin: not a browser, e.g. the benchmark's client


@pytest.mark.parametrize(
    "host", ["evil.example:{port}", "127.0.0.1.evil.example:{port}", "127.0.0.1:{other}", "127.0.0.1"]
)
def test_foreign_host_is_refused(local_server, host):
    """DNS rebinding: a foreign name resolved to 127.0.0.1 still sends that name as Host."""
    port, _ = local_server
    host = host.format(port=port, other=port + 1)
    status, _, body = http_get(port, host=host)
    assert status == 403 and b"Host" in body
    assert ws_connect(port, host=host) == "refused 403"


def test_foreign_origin_http_request_is_refused(local_server):
    port, _ = local_server
    assert http_get(port, Origin="http://evil.example")[0] == 403
    assert http_get(port, Origin=f"http://127.0.0.1:{port}")[0] == 200


def test_off_localhost_a_token_is_required(public_server):
    port, guard = public_server
    assert guard.token is not None and len(guard.token) >= 24
    url = server_url("0.0.0.0", port, guard)
    assert url == f"http://127.0.0.1:{port}/?token={guard.token}"
    # Without the token, or with a wrong one: refused, page and WebSocket alike.
    assert http_get(port)[0] == 403
    assert http_get(port, "/?token=wrong")[0] == 403
    assert ws_connect(port, origin=f"http://127.0.0.1:{port}") == "refused 403"
    assert ws_connect(port, origin=f"http://127.0.0.1:{port}", cookie=f"{cookie_name(port)}=wrong") == "refused 403"
    # The URL printed at start opens the page and sets the cookie its WebSocket then carries.
    status, headers, _ = http_get(port, f"/?token={guard.token}")
    assert status == 200
    cookie = headers["Set-Cookie"].split(";")[0]
    assert cookie == f"{cookie_name(port)}={guard.token}" and "HttpOnly" in headers["Set-Cookie"]
    assert ws_connect(port, origin=f"http://127.0.0.1:{port}", cookie=cookie) == "ok"
    assert ws_connect(port, path=f"/?token={guard.token}") == "ok"
    # The token does not excuse a foreign page or name.
    assert ws_connect(port, origin="http://evil.example", cookie=cookie) == "refused 403"
    assert http_get(port, f"/?token={guard.token}", host=f"evil.example:{port}")[0] == 403


def test_off_localhost_accepts_the_machines_addresses(public_server):
    port, guard = public_server
    assert http_get(port, f"/?token={guard.token}", host=f"192.0.2.7:{port}")[0] == 200  # an IP literal
    assert http_get(port, f"/?token={guard.token}", host=f"{socket.gethostname()}:{port}")[0] == 200


def _blob_capture() -> Capture:
    """A small table with a box on it (camera frame, metres), enough for a scene."""
    rng = np.random.default_rng(0)
    table = np.column_stack([rng.uniform(-0.4, 0.4, 4000), np.full(4000, 0.3), rng.uniform(0.6, 1.2, 4000)])
    box = np.column_stack([rng.uniform(-0.05, 0.05, 1500), rng.uniform(0.2, 0.3, 1500), rng.uniform(0.85, 0.95, 1500)])
    return Capture(np.concatenate([table, box]), source="blob")


def test_viewer_app_is_guarded():
    from shapeviewer.viewer import ViewerApp

    app = ViewerApp(host="0.0.0.0", port=free_port(), cloud=_blob_capture(), results=None)
    try:
        port, token = app.port, app.guard.token
        assert token and app.url == f"http://127.0.0.1:{port}/?token={token}"
        assert http_get(port)[0] == 403
        assert ws_connect(port, path=f"/?token={token}", origin="http://evil.example") == "refused 403"
        assert ws_connect(port, path=f"/?token={token}", origin=f"http://127.0.0.1:{port}") == "ok"
    finally:
        app.stop()
