"""Who may drive the viewer: the user's own browser, not any web page it happens to visit.

viser serves its page and its WebSocket on one port with ``websockets``, whose ``serve`` takes a
``process_request`` hook that sees every HTTP request and WebSocket upgrade before it is answered.
:func:`start_server` installs :class:`Guard`'s check in front of viser's own hook, so that

* a request whose ``Host`` is not this server (``localhost``, ``127.0.0.1``, ``[::1]`` or the
  ``--host`` name, with the port the request came in on; off localhost also this machine's host
  names and any IP address) is refused: a page on another site that re-binds its DNS name to this
  machine still sends that name as ``Host`` (never an IP address);
* a request with an ``Origin`` header (browsers send one with every WebSocket upgrade) that is not
  such an address is refused: a foreign page (``http://evil.example``, or ``null`` from a sandboxed
  frame or a file) cannot open the viewer's WebSocket;
* off localhost (``--host 0.0.0.0`` or any other non-loopback address) every request must also
  carry the server's random token, as Jupyter's do: ``?token=...`` in the URL printed at start, or
  the cookie that the answer to that URL sets (the viser client opens its WebSocket at the page's
  path *without* the query string, so the cookie is what carries the token there). Anyone on the
  network can reach such a server, so the ``Host`` check alone would not do.

Refused requests get ``403 Forbidden`` and a one-line reason; they are logged (once per reason).
``--allow-host NAME`` adds a name (e.g. a DNS alias of the machine) to the accepted ``Host`` names.

Before the server starts, :func:`listen_port` checks that ``--host`` names an address of this machine
and finds a port it can listen on (:class:`ServeError` otherwise: viser would retry in its thread
and wait forever). Once it runs, :class:`UploadLimit` refuses browser uploads over the cap as soon
as their size is announced, and a client whose parts outgrow what it announced while they arrive.
"""

from __future__ import annotations

import contextlib
import errno
import http
import http.cookies
import ipaddress
import logging
import secrets
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qs, urlsplit

import rich
import viser
import websockets.asyncio.server as ws_server
from viser import _messages as viser_messages
from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

from ..errors import ShapeviewerError

log = logging.getLogger(__name__)

TOKEN_PARAM = "token"
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
WILDCARD_HOSTS = frozenset({"", "0.0.0.0", "::"})
_MAX_LOGGED = 100
# Ports tried from --port on when it is in use (viser's own retries happen in its thread, unseen).
PORT_TRIES = 100
# How long resolving --host may take before the name is called unresolvable.
RESOLVE_SECONDS = 5.0

ProcessRequest = Callable[[ServerConnection, Request], "Response | None"]


def cookie_name(port: int) -> str:
    """The token cookie of the server on ``port`` (cookies are per host, not per port)."""
    return f"shapeviewer-token-{port}"


def is_loopback(host: str) -> bool:
    """Whether binding ``host`` serves this machine only (``localhost``, 127.0.0.0/8, ``::1``)."""
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return False


def _split_host(value: str, default_port: int) -> tuple[str, int] | None:
    """``(hostname, port)`` of a ``Host`` header value (``name[:port]``, ``[v6][:port]``); None if malformed."""
    try:
        parts = urlsplit("//" + value)
        name, port = parts.hostname, parts.port
    except ValueError:
        return None
    if not name or parts.username is not None or parts.path or parts.query:
        return None
    return name.lower(), default_port if port is None else port


@dataclass
class Guard:
    """The check applied to every request (see the module docstring).

    Attributes:
        bind_host: the address the server listens on (``--host``).
        token: the secret every request must carry, or None (a loopback server needs none).
        extra_hosts: further ``Host`` names to accept (e.g. a DNS name of this machine).
    """

    bind_host: str
    token: str | None = None
    extra_hosts: frozenset[str] = frozenset()
    _names: frozenset[str] = field(init=False, repr=False)
    _logged: set[str] = field(default_factory=set, init=False, repr=False)

    @classmethod
    def for_host(cls, host: str, token: str | None = None, extra_hosts: tuple[str, ...] = ()) -> Guard:
        """The guard of a server bound to ``host``: a fresh random token unless it is loopback-only
        (``token`` overrides, e.g. to keep a link working across restarts)."""
        if token is None and not is_loopback(host):
            token = secrets.token_urlsafe(24)
        return cls(host, token, frozenset(h.lower() for h in extra_hosts))

    def __post_init__(self) -> None:
        names = set(LOOPBACK_NAMES) | set(self.extra_hosts)
        if self.bind_host.lower() not in WILDCARD_HOSTS:
            names.add(self.bind_host.lower().strip("[]"))
        if not is_loopback(self.bind_host):
            # Reachable from the network: the names other machines know this one by. (getfqdn may
            # ask DNS, once, here.) IP literals are accepted below: a re-bound DNS name never is one.
            names |= {socket.gethostname().lower(), socket.getfqdn().lower()}
        self._names = frozenset(names)

    def allowed_host(self, name: str) -> bool:
        """Whether ``name`` (lower case, no brackets) is one of this server's names."""
        if name in self._names:
            return True
        # Off localhost, any IP literal: the browser navigated to that address itself.
        return not is_loopback(self.bind_host) and _is_ip(name)

    def refusal(self, path: str, headers, local_port: int) -> str | None:
        """Why a request (``path`` with its query, ``headers``, arrived on ``local_port``) is refused;
        None if allowed."""
        hosts = headers.get_all("Host")
        if len(hosts) != 1:
            return "missing or repeated Host header"
        host = _split_host(hosts[0], 80)
        if host is None or not self.allowed_host(host[0]) or host[1] != local_port:
            return f"foreign Host {hosts[0]!r}"
        origins = headers.get_all("Origin")
        if len(origins) > 1:
            return "repeated Origin header"
        if origins:
            origin = urlsplit(origins[0]) if origins[0] != "null" else None
            try:
                ok = (
                    origin is not None
                    and origin.scheme in ("http", "https")
                    and origin.hostname is not None
                    and self.allowed_host(origin.hostname.lower())
                    and (origin.port or (443 if origin.scheme == "https" else 80)) == local_port
                )
            except ValueError:  # a port that is not a number
                ok = False
            if not ok:
                return f"foreign Origin {origins[0]!r}"
        if self.token is not None and not self._has_token(path, headers, local_port):
            return "missing or wrong token (open the URL with ?token=... printed at start)"
        return None

    def token_in_query(self, path: str) -> bool:
        if self.token is None:
            return False
        given = parse_qs(urlsplit(path).query).get(TOKEN_PARAM, [])
        return any(secrets.compare_digest(g.encode(), self.token.encode()) for g in given)

    def _has_token(self, path: str, headers, port: int) -> bool:
        assert self.token is not None  # refusal() asks only when a token is required
        if self.token_in_query(path):
            return True
        cookies = http.cookies.SimpleCookie()
        for raw in headers.get_all("Cookie"):
            with contextlib.suppress(http.cookies.CookieError):
                cookies.load(raw)
        morsel = cookies.get(cookie_name(port))
        return morsel is not None and secrets.compare_digest(morsel.value.encode(), self.token.encode())

    def wrap(self, inner: ProcessRequest | None) -> ProcessRequest:
        """A ``process_request`` hook: refuse with 403, else answer as ``inner`` (viser's file server)."""

        def process_request(connection: ServerConnection, request: Request) -> Response | None:
            port = connection.transport.get_extra_info("sockname")[1]
            reason = self.refusal(request.path, request.headers, port)
            if reason is not None:
                # Once per reason (a hostile page may retry forever), and only so many reasons.
                if reason not in self._logged and len(self._logged) < _MAX_LOGGED:
                    self._logged.add(reason)
                    log.warning("refused a request: %s", reason)
                return connection.respond(http.HTTPStatus.FORBIDDEN, f"shapeviewer: refused: {reason}\n")
            response = inner(connection, request) if inner is not None else None
            if response is not None and self.token is not None and self.token_in_query(request.path):
                # The page's WebSocket and assets are requested without the query: a cookie carries
                # the token for them. HttpOnly: page scripts never see it; Strict: never sent by
                # another site's requests.
                response.headers["Set-Cookie"] = f"{cookie_name(port)}={self.token}; Path=/; HttpOnly; SameSite=Strict"
            return response

        return process_request


class ServeError(ShapeviewerError, OSError):
    """The server cannot listen where it was asked to (``--host``, ``--port``); the message says why in one line."""


def _addresses(host: str, port: int) -> list[tuple]:
    """What ``host`` resolves to for listening (as asyncio's ``create_server`` asks), within
    :data:`RESOLVE_SECONDS`; ServeError when it does not resolve."""
    answer: list = []

    def resolve() -> None:
        try:
            answer.append(socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE))
        except OSError as e:
            answer.append(e)

    worker = threading.Thread(target=resolve, name="resolve-host", daemon=True)
    worker.start()
    worker.join(RESOLVE_SECONDS)
    if not answer:
        raise ServeError(f"--host {host}: the name did not resolve within {RESOLVE_SECONDS:.0f} s")
    if isinstance(answer[0], OSError):
        reason = answer[0].strerror or str(answer[0])
        raise ServeError(f"--host {host}: cannot resolve the name ({reason}); give a name or address of this machine")
    return [info for info in answer[0] if info[0] in (socket.AF_INET, socket.AF_INET6)]


def _bind_error(infos: list[tuple], port: int) -> OSError | None:
    """The error binding every address of ``infos`` on ``port`` raises (None: all bind), tried as
    asyncio's ``create_server`` binds (address reuse, IPv6 sockets IPv6 only)."""
    sockets: list[socket.socket] = []
    try:
        for family, kind, proto, _, address in infos:
            sock = socket.socket(family, kind, proto)
            sockets.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6 and hasattr(socket, "IPPROTO_IPV6"):
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind((address[0], port, *address[2:]))
    except OSError as e:
        return e
    finally:
        for sock in sockets:
            sock.close()
    return None


def listen_port(host: str, port: int, tries: int = PORT_TRIES) -> int:
    """The port the server will listen on: ``port``, or the next free one after it (as viser
    does, at most ``tries`` of them, never past 65535).

    Checked here, before viser starts, because viser retries a failed bind in its own thread on up
    to a thousand ports and then waits forever (and an out-of-range port kills that thread with a
    traceback): a bad ``--host`` or ``--port`` must be one clear line instead.

    Raises:
        ServeError: ``host`` does not resolve or is not an address of this machine, ``port`` needs
            privileges this process lacks, or it and the ports after it are all in use.
    """
    if not 0 <= port <= 65535:
        raise ServeError(f"--port {port}: not a port (0-65535)")
    infos = _addresses(host, port)
    if not infos:
        raise ServeError(f"--host {host}: resolves to no IPv4 or IPv6 address")
    last = min(65535, port + max(1, tries) - 1) if port else 0
    for candidate in range(port, last + 1):
        error = _bind_error(infos, candidate)
        if error is None:
            return candidate
        if error.errno == errno.EADDRINUSE:
            continue
        reason = error.strerror or str(error)
        if error.errno == errno.EADDRNOTAVAIL:
            raise ServeError(f"--host {host}: not an address of this machine ({reason}); use 127.0.0.1 or 0.0.0.0")
        if error.errno in (errno.EACCES, errno.EPERM):
            raise ServeError(
                f"--port {candidate}: cannot listen there ({reason}); ports below 1024 need administrator "
                "rights: use a port from 1024 up"
            )
        raise ServeError(f"cannot listen on {host}:{candidate} ({reason})")
    after = f", and so is every port after it up to {last}" if last > port else ""
    raise ServeError(f"--port {port}: in use on {host}{after}; choose another --port")


_PATCH_LOCK = threading.Lock()


def start_server(host: str, port: int, guard: Guard) -> viser.ViserServer:
    """A running ``viser.ViserServer`` on ``host:port`` (or the next free port) that answers only
    what ``guard`` allows.

    viser builds its ``websockets`` server inside ``ViserServer()`` (on its own thread, which the
    constructor waits for), passing its file server as ``process_request``; no viser option takes a
    hook, so ``websockets.asyncio.server.serve`` is wrapped for the length of the constructor only.

    Raises:
        RuntimeError: viser did not start its server through ``websockets.asyncio.server.serve``
            (a viser version this module does not know): refusing to serve unguarded.
    """
    original = ws_server.serve
    installed: list[bool] = []

    def guarded_serve(*args, **kwargs):
        kwargs["process_request"] = guard.wrap(kwargs.get("process_request"))
        installed.append(True)
        return original(*args, **kwargs)

    # setattr, not an assignment: mypy refuses a function in place of ``serve`` (a class there).
    console = rich.get_console()
    with _PATCH_LOCK:
        setattr(ws_server, "serve", guarded_serve)  # noqa: B010
        # viser prints a box of its URLs whatever ``verbose`` says, without the token: the only
        # URL a user should see is the one the app prints (:func:`server_url`).
        quiet, console.quiet = console.quiet, True
        try:
            server = viser.ViserServer(host=host, port=port, verbose=False)
        finally:
            console.quiet = quiet
            setattr(ws_server, "serve", original)  # noqa: B010
    if not installed:
        server.stop()
        raise RuntimeError(
            f"viser {viser.__version__} did not start its server through websockets' serve(): "
            "the origin/host guard cannot be installed"
        )
    return server


def server_url(host: str, port: int, guard: Guard) -> str:
    """The URL to open: a wildcard bind is reached through 127.0.0.1; with the token when one is needed."""
    name = "127.0.0.1" if host in WILDCARD_HOSTS else host
    if ":" in name:  # an IPv6 literal
        name = f"[{name}]"
    query = f"/?{TOKEN_PARAM}={guard.token}" if guard.token is not None else ""
    return f"http://{name}:{port}{query}"


# ----------------------------------------------------------------------------------------------
# Uploads

# (client id, the browser's file name, bytes announced or received, whether the size was announced)
UploadRefused = Callable[[int, str, int, bool], None]


class UploadLimit:
    """Refuses browser uploads of more than ``max_bytes``, before their bytes are kept.

    viser's upload button sends a start message announcing the file's name and size, then the file
    in parts of 512 KB, and keeps every part in memory until the last one has come; only then does
    the app's ``on_upload`` see the file. Its size check there came after the whole file was in
    memory (and the file stayed referenced as the button's value). viser offers no public hook on
    the transfer, so :meth:`install` hooks its message handling, on each GUI that has upload buttons:

    * the GUI's table of transfers in progress (``GuiApi._current_file_upload_states``) becomes
      one that never stores a transfer announced over the cap, so every part of it is dropped as
      it arrives; and it counts each stored transfer's bytes as its parts arrive, dropping the
      transfer (and every part it kept) once they exceed the cap or what was announced;
    * a handler of the start message, run after viser's own, tells ``refused`` and answers the
      browser that the transfer is over, so that its upload button works again.

    ``refused`` is called on viser's event loop thread: it must only queue messages.
    """

    def __init__(self, max_bytes: int, refused: UploadRefused) -> None:
        self.max_bytes = int(max_bytes)
        self.refused = refused

    def install(self, gui: viser.GuiApi) -> None:
        """Hook ``gui`` (``server.gui`` or a tab's ``client.gui``; once is enough, again is a no-op).

        Raises:
            RuntimeError: a viser whose upload handling this does not know: refusing to serve
                uploads uncapped.
        """
        current = getattr(gui, "_current_file_upload_states", None)
        interface = getattr(gui, "_websock_interface", None)
        if isinstance(current, _Transfers):
            return
        if not isinstance(current, dict) or not hasattr(interface, "register_handler"):
            raise RuntimeError(
                f"viser {viser.__version__} keeps uploads in a way this app does not know: "
                "the upload size cap cannot be installed"
            )
        gui._current_file_upload_states = _Transfers(self, current)  # type: ignore[attr-defined]
        assert interface is not None
        handler = self._handler(gui, interface)
        interface.register_handler(viser_messages.FileTransferStartUpload, handler)

    def _handler(self, gui: viser.GuiApi, interface: Any) -> Callable[[int, Any], None]:
        def started(client_id: int, message: Any) -> None:
            inputs = getattr(gui, "_gui_input_handle_from_uuid", {})
            if message.source_component_uuid not in inputs or message.size_bytes <= self.max_bytes:
                return
            # Nothing of it is kept (see _Transfers): say so, and end the browser's transfer.
            interface.queue_message(
                viser_messages.FileTransferPartAck(
                    source_component_uuid=message.source_component_uuid,
                    transfer_uuid=message.transfer_uuid,
                    transferred_bytes=message.size_bytes,
                    total_bytes=message.size_bytes,
                )
            )
            self.refused(client_id, message.filename, message.size_bytes, True)

        return started


class _Transfers(dict):
    """viser's table of uploads in progress (transfer id -> state), capped (see :class:`UploadLimit`)."""

    def __init__(self, limit: UploadLimit, current: dict) -> None:
        super().__init__(current)
        self.limit = limit

    def __setitem__(self, transfer_uuid: str, state: Any) -> None:
        if int(state["total_bytes"]) > self.limit.max_bytes:
            return  # never stored: viser drops each of its parts on arrival (an unknown transfer)
        state["parts"] = _Parts(self, transfer_uuid, state)
        super().__setitem__(transfer_uuid, state)


class _Parts(dict):
    """The parts of one upload kept so far (index -> bytes), counted as they arrive."""

    def __init__(self, transfers: _Transfers, transfer_uuid: str, state: Any) -> None:
        super().__init__()
        self.transfers = transfers
        self.transfer_uuid = transfer_uuid
        self.state = state
        self.received = 0

    def __setitem__(self, index: int, content: bytes) -> None:
        self.received += len(content)
        limit = self.transfers.limit
        if self.received <= min(limit.max_bytes, int(self.state["total_bytes"])):
            super().__setitem__(index, content)
            return
        # More than the cap, or than the client announced: drop the transfer and all it kept.
        self.clear()
        self.transfers.pop(self.transfer_uuid, None)
        limit.refused(int(self.state["client_id"]), str(self.state["filename"]), self.received, False)
