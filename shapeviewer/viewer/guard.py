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
"""

from __future__ import annotations

import contextlib
import http
import http.cookies
import ipaddress
import logging
import secrets
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from urllib.parse import parse_qs, urlsplit

import viser
import websockets.asyncio.server as ws_server
from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

log = logging.getLogger(__name__)

TOKEN_PARAM = "token"
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
WILDCARD_HOSTS = frozenset({"", "0.0.0.0", "::"})
_MAX_LOGGED = 100

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
    with _PATCH_LOCK:
        setattr(ws_server, "serve", guarded_serve)  # noqa: B010
        try:
            server = viser.ViserServer(host=host, port=port, verbose=False)
        finally:
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
