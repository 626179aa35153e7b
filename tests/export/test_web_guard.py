"""The viewer answers only the browser that opened its printed URL: a real viewer, real HTTP and WebSocket
clients (``websockets``), foreign origins and hosts refused."""

from __future__ import annotations

import asyncio
import http.cookiejar
import socket
import urllib.error
import urllib.request

import pytest
import viser
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from nerfpipe.export import web
from nerfpipe.export.web import WebScene
from nerfpipe.export.web_guard import Gate, probe


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def viewer():
    viewer = web.serve(WebScene(frames=[]), port=free_port())
    yield viewer
    viewer.stop()


def websocket(viewer, origin: str | None, cookie: bool = True, host: str | None = None) -> str:
    """"accepted" with the first message viser sends, or "refused STATUS"."""
    port = viewer.server.get_port()
    headers = {} if origin is None else {"Origin": origin}
    if cookie:
        headers["Cookie"] = f"{viewer.gate.cookie}={viewer.gate.token}"
    if host is not None:
        headers["Host"] = host

    async def attempt() -> str:
        try:
            async with connect(f"ws://127.0.0.1:{port}/", additional_headers=headers, open_timeout=10,
                               subprotocols=[f"viser-v{viser.__version__}"]) as client:
                first = await asyncio.wait_for(client.recv(), 10)
                return f"accepted {len(first) > 0}"
        except InvalidStatus as err:
            return f"refused {err.response.status_code}"

    return asyncio.run(attempt())


def test_the_printed_url_opens_the_page_and_its_websocket(viewer) -> None:
    port = viewer.server.get_port()
    assert viewer.url.startswith(f"http://localhost:{port}/?token=") and len(viewer.gate.token) >= 32
    jar = http.cookiejar.CookieJar()
    page = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(jar)).open(viewer.url, timeout=10)
    # the token is traded for a cookie and the address bar loses it
    assert page.status == 200 and page.geturl() == f"http://localhost:{port}/" and b"<html" in page.read().lower()
    assert [c.name for c in jar] == [viewer.gate.cookie]
    assert websocket(viewer, f"http://localhost:{port}") == "accepted True"
    assert websocket(viewer, f"http://127.0.0.1:{port}") == "accepted True"


def test_a_foreign_origin_websocket_is_refused_even_with_the_token(viewer) -> None:
    assert websocket(viewer, "http://evil.example") == "refused 403"
    assert websocket(viewer, f"http://localhost:{viewer.server.get_port() + 1}") == "refused 403"  # another port
    assert websocket(viewer, None) == "refused 403"  # browsers always send one


def test_a_websocket_without_the_token_is_refused(viewer) -> None:
    assert websocket(viewer, f"http://localhost:{viewer.server.get_port()}", cookie=False) == "refused 403"


def test_a_foreign_host_is_refused_dns_rebinding(viewer) -> None:
    port, token = viewer.server.get_port(), viewer.gate.token
    assert probe("127.0.0.1", port, {"Host": "evil.example"}, f"/?token={token}") == 403
    assert probe("127.0.0.1", port, {"Host": f"evil.example:{port}"}, f"/?token={token}") == 403
    assert probe("127.0.0.1", port, {"Host": f"localhost:{port}", "host": "evil.example"}, f"/?token={token}") == 403
    assert probe("127.0.0.1", port, {"Host": f"localhost:{port}"}, f"/?token={token}") == 302
    assert websocket(viewer, f"http://localhost:{port}", host="evil.example") == "refused 403"


def test_no_file_is_served_without_the_token(viewer) -> None:
    port = viewer.server.get_port()
    for path in ("/", "/index.html", "/?token=wrong", "/../../etc/passwd"):
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(f"http://localhost:{port}{path}", timeout=10)
        assert refused.value.code == 403, path


def test_the_share_button_is_hidden_and_its_request_does_nothing(viewer) -> None:
    # viser would open a public tunnel on this message, from a page that shows no button
    assert viewer.server.request_share_url() is None
    assert getattr(viewer.server, "_share_tunnel", None) is None


def test_the_gate_by_hand() -> None:
    gate = Gate(8080, token="t0k")
    ok = {"Host": "localhost:8080", "Cookie": "nerfpipe-viewer-8080=t0k"}
    assert gate.check("/", ok) is None
    assert gate.check("/", {"Host": "[::1]:8080", "Cookie": "nerfpipe-viewer-8080=t0k"}) is None
    assert gate.check("/", {**ok, "Cookie": "nerfpipe-viewer-8080=t0"})[0] == 403  # a prefix of the token
    assert gate.check("/", {**ok, "Host": "localhost:8081"})[0] == 403
    assert gate.check("/", {**ok, "Host": "localhost.evil.example:8080"})[0] == 403
    status, _, headers = gate.check("/a?x=1&token=t0k", {"Host": "127.0.0.1:8080"})
    assert status == 302 and headers["Location"] == "/a?x=1"
    assert headers["Set-Cookie"] == "nerfpipe-viewer-8080=t0k; HttpOnly; SameSite=Strict; Path=/"
    upgrade = {**ok, "Upgrade": "websocket"}
    assert gate.check("/", {**upgrade, "Origin": "http://localhost:8080"}) is None
    assert gate.check("/", {**upgrade, "Origin": "null"})[0] == 403  # a sandboxed frame or a file:// page
    on_network = Gate(8080, token="t0k", hosts=())  # --host 0.0.0.0: any name reaches it, the token still counts
    assert on_network.check("/", {"Host": "box.lan:8080", "Cookie": "nerfpipe-viewer-8080=t0k"}) is None
    assert on_network.check("/", {"Host": "box.lan:8080"})[0] == 403
