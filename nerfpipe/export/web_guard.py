"""The web viewer's gate: only the browser that opened the printed URL reads the run.

Browsers apply no same-origin policy to WebSockets, and a local HTTP server answers any ``Host:`` (DNS
rebinding), so any web page open on this machine could otherwise read the photos the viewer streams. As
Jupyter's and VS Code's servers do, every request must carry a random token: the printed URL has it as
``?token=``, which the gate trades for a cookie (``HttpOnly``, ``SameSite=Strict``) and a redirect to the
same page without it. Every request is also checked for its ``Host`` (loopback names only, unless the
viewer listens on another address) and every WebSocket upgrade for its ``Origin`` (the viewer's own).

viser has no hook for this, so ``install`` wraps the ``process_request`` that viser hands ``websockets``'
``serve``, in viser's server module alone. ``serve`` in ``web.py`` then checks the gate from outside
(``probe``) before it prints the URL, and refuses to serve if the gate is not in place.
"""

from __future__ import annotations

import contextlib
import hmac
import http
import http.client
import io
import secrets
import threading
from dataclasses import dataclass, field
from http.cookies import SimpleCookie
from typing import Any, Callable
from urllib.parse import parse_qsl, urlencode, urlsplit

LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")


@dataclass
class Gate:
    """What a request to the viewer on ``port`` must show: ``token``, a ``Host`` among ``hosts`` (any, when
    ``hosts`` is empty: a viewer on the network, reached by names nerfpipe cannot know), and for a WebSocket
    an ``Origin`` whose host is among them too."""

    port: int
    token: str = field(default_factory=lambda: secrets.token_urlsafe(24))
    hosts: tuple[str, ...] = LOOPBACK_NAMES

    @property
    def cookie(self) -> str:
        return f"nerfpipe-viewer-{self.port}"

    def host_allowed(self, netloc: str | None) -> bool:
        if not netloc:
            return False
        if not self.hosts:
            return True
        parts = urlsplit(f"//{netloc}")
        try:
            port = parts.port
        except ValueError:
            return False
        return (parts.hostname or "") in self.hosts and port in (None, self.port)

    def _token_ok(self, given: str | None) -> bool:
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    def check(self, path: str, headers: Any) -> tuple[int, str, dict[str, str]] | None:
        """``None`` to let the request through, else (status, text, extra headers) to answer it with."""
        hosts, origins = _all(headers, "Host"), _all(headers, "Origin")
        if len(hosts) != 1 or not self.host_allowed(hosts[0]):
            return 403, "nerfpipe viewer: this Host is not the viewer's\n", {}
        upgrade = (headers.get("Upgrade") or "").lower() == "websocket"
        if len(origins) > 1:
            return 403, "nerfpipe viewer: more than one Origin\n", {}
        origin = origins[0] if origins else None
        if upgrade and (origin is None or not self.host_allowed(urlsplit(origin).netloc)):
            return 403, "nerfpipe viewer: a WebSocket from another origin\n", {}
        cookies = SimpleCookie()
        try:
            cookies.load(headers.get("Cookie") or "")
        except Exception:  # a malformed Cookie header is no token
            cookies = SimpleCookie()
        if self.cookie in cookies and self._token_ok(cookies[self.cookie].value):
            return None
        split = urlsplit(path)
        query = parse_qsl(split.query, keep_blank_values=True)
        given = next((v for k, v in query if k == "token"), None)
        if not self._token_ok(given):
            return 403, "nerfpipe viewer: open the URL nerfpipe printed (it carries the token)\n", {}
        if upgrade:
            return None
        rest = urlencode([(k, v) for k, v in query if k != "token"])
        return 302, "", {"Location": split.path + (f"?{rest}" if rest else ""),
                         "Set-Cookie": f"{self.cookie}={self.token}; HttpOnly; SameSite=Strict; Path=/"}

    def wrap(self, inner: Callable | None) -> Callable:
        """A ``process_request`` for ``websockets``: this gate, then ``inner`` (viser's file server)."""
        def process_request(connection: Any, request: Any) -> Any:
            refused = self.check(request.path, request.headers)
            if refused is None:
                return inner(connection, request) if inner is not None else None
            status, text, extra = refused
            response = connection.respond(http.HTTPStatus(status), text)
            for name, value in extra.items():
                response.headers[name] = value
            return response

        return process_request


def _all(headers: Any, name: str) -> list[str]:
    """Every value of header ``name`` (a request may repeat one to slip past a check of the first)."""
    return list(headers.get_all(name)) if hasattr(headers, "get_all") else [v for v in [headers.get(name)] if v]


class _Proxy:
    """``target`` with some attributes replaced: a module as one other module sees it."""

    def __init__(self, target: Any, **replaced: Any) -> None:
        self._target, self._replaced = target, replaced

    def __getattr__(self, name: str) -> Any:
        return self._replaced[name] if name in self._replaced else getattr(self._target, name)


_lock = threading.Lock()
_pending: list[Gate] = []  # the gate of the viser server being constructed (under ``_lock``)
_installed = False


def install() -> None:
    """Route the ``serve`` calls of viser's server module through ``_pending``'s gate (once per process)."""
    global _installed
    if _installed:
        return
    import websockets.asyncio.server
    from viser.infra import _infra

    real_serve = websockets.asyncio.server.serve

    def serve(handler: Any, host: Any, port: Any, *args: Any, process_request: Any = None, **kwargs: Any) -> Any:
        if _pending:
            process_request = _pending[-1].wrap(process_request)
        return real_serve(handler, host, port, *args, process_request=process_request, **kwargs)

    server_module = _Proxy(websockets.asyncio.server, serve=serve)
    _infra.websockets = _Proxy(websockets, asyncio=_Proxy(websockets.asyncio, server=server_module))
    _installed = True


def guarded(gate: Gate, start: Callable[[], Any]) -> Any:
    """``start()`` (which makes a viser server) with ``gate`` in front of the server it makes."""
    install()
    with _lock:
        _pending.append(gate)
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # viser prints its own URLs, which lack the token
                return start()
        finally:
            _pending.pop()


def probe(host: str, port: int, headers: dict[str, str], path: str = "/") -> int:
    """The HTTP status the viewer answers a GET of ``path`` with ``headers``: how ``serve`` checks the gate."""
    connection = http.client.HTTPConnection("::1" if host == "::1" else "127.0.0.1" if host in ("0.0.0.0", "::", "localhost") else host,
                                            port, timeout=5)
    try:
        connection.putrequest("GET", path, skip_host=True)
        for name, value in headers.items():
            connection.putheader(name, value)
        connection.endheaders()
        return connection.getresponse().status
    finally:
        connection.close()
