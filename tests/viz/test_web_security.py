"""The web viewer against another web page: DNS rebinding, foreign websockets, the secret.

A real ``xray-viz show sphere --web`` server on 127.0.0.1 (a subprocess, as in
``test_web_viewer.py``) is asked with real HTTP requests (``urllib``, ``http.client``) and a real
websocket client (``websocket-client``) speaking wslink's own framing (msgpack in wslink's chunk
header): a ``Host:`` header that is not this machine's loopback name is refused (a page of
another site whose name was rebound to 127.0.0.1 reads nothing), a websocket opened with a
foreign ``Origin`` is refused at the handshake, and the websocket's ``wslink.hello`` only
authenticates with the per-run secret carried by the printed URL - not with trame's public
default ``wslink-secret``.
"""

from __future__ import annotations

import http.client
import urllib.request
from urllib.parse import parse_qs, urlsplit

import pytest

from tests.viz.test_web_viewer import web_server

pytest.importorskip("trame")
websocket = pytest.importorskip("websocket")
msgpack = pytest.importorskip("msgpack")


def _get(url: str, host: str | None = None) -> tuple[int, bytes]:
    """GET ``url`` (with another ``Host:`` header when given): (status, body)."""
    parts = urlsplit(url)
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=30)
    try:
        path = parts.path + (f"?{parts.query}" if parts.query else "")
        conn.putrequest("GET", path, skip_host=host is not None)
        if host is not None:
            conn.putheader("Host", host)
        conn.endheaders()
        response = conn.getresponse()
        return response.status, response.read()
    finally:
        conn.close()


def _hello(url: str, secret: str, origin: str | None = None) -> dict:
    """Open the viewer's websocket (``Origin: origin``) and say wslink's hello with ``secret``;
    the server's answer (``result`` or ``error``)."""
    from wslink.chunking import HEADER_LENGTH, generate_chunks

    parts = urlsplit(url)
    ws = websocket.create_connection(f"ws://{parts.hostname}:{parts.port}/ws", timeout=30,
                                     origin=origin,
                                     suppress_origin=origin is None)
    try:
        message = msgpack.packb({"wslink": "1.0", "id": "system:c0:0", "method": "wslink.hello",
                                 "args": [{"secret": secret}], "kwargs": {}})
        for chunk in generate_chunks(message, 0):
            ws.send_binary(chunk)
        answer = ws.recv()
        return msgpack.unpackb(answer[HEADER_LENGTH:])
    finally:
        ws.close()


@pytest.fixture(scope="module")
def server():
    with web_server("sphere", "--port", "0", "--resolution", "16", "--size", "400",
                    "300") as (proc, url):
        yield url
    out, err = proc.communicate(timeout=60)            # stopped by Ctrl-C: cleanly
    assert proc.returncode == 0 and "Traceback" not in err, err[-2000:]


def test_web_viewer_refuses_foreign_host_headers(server):
    """DNS rebinding: the page and its scripts only for a loopback Host: header."""
    parts = urlsplit(server)
    status, body = _get(server)
    assert status == 200 and b"<html" in body.lower()
    for host in (f"localhost:{parts.port}", f"127.0.0.1:{parts.port}", "127.0.0.1"):
        assert _get(server, host=host)[0] == 200
    for host in ("evil.example", f"evil.example:{parts.port}", f"127.0.0.1.evil.example:{parts.port}",
                 f"rebind.attacker.test:{parts.port}", ""):
        status, body = _get(server, host=host)
        assert status == 403, (host, status)
        assert b"<html" not in body.lower()
        assert b"Host" in body                     # says why


def test_web_viewer_websocket_refuses_a_foreign_origin(server):
    """Another site's page may open a websocket to 127.0.0.1: refused at the handshake."""
    secret = parse_qs(urlsplit(server).query)["secret"][0]
    port = urlsplit(server).port
    for origin in ("http://evil.example", f"http://evil.example:{port}", "null",
                   f"http://127.0.0.1.evil.example:{port}"):
        with pytest.raises(websocket.WebSocketBadStatusException) as refused:
            _hello(server, secret, origin=origin)
        assert refused.value.status_code == 403
    # the page's own origin (as the browser sends it), or none (a script): the secret works
    assert "result" in _hello(server, secret, origin=f"http://127.0.0.1:{port}")
    assert "result" in _hello(server, secret, origin=f"http://localhost:{port}")
    assert "result" in _hello(server, secret)


def test_web_viewer_secret_is_random_per_run(server):
    """trame's public default secret does not authenticate; the URL's does."""
    query = parse_qs(urlsplit(server).query)
    secret = query["secret"][0]
    assert len(secret) >= 32 and secret != "wslink-secret"
    answer = _hello(server, "wslink-secret")
    assert "error" in answer and "result" not in answer
    answer = _hello(server, secret[:-1])
    assert "error" in answer
    assert "clientID" in _hello(server, secret)["result"]
    with urllib.request.urlopen(server, timeout=30) as page:   # the page itself, as printed
        assert page.status == 200


def test_non_loopback_bind_is_announced_loudly(monkeypatch):
    """``--host 0.0.0.0`` (or any non-loopback interface): a warning on stderr and the URL a
    remote browser would use, not a 127.0.0.1 one (the server is not started here: nothing is
    bound to other interfaces by the test suite)."""
    import socket

    from xray_viz.viz import web

    lines, warnings = [], []

    class Fake(web.WebViewer):
        secret = "s" * 43

        class server:
            port = 8123

        def __init__(self):
            pass

        def close(self):
            pass

        def start(self, *, host, port, on_ready):
            on_ready(self)

    monkeypatch.setattr(web, "_warn", warnings.append)
    for host in ("0.0.0.0", "::", "192.0.2.7"):
        lines.clear()
        warnings.clear()
        web.serve(Fake(), host=host, port=8123, announce=lines.append)
        assert warnings and "every" in warnings[0] or "192.0.2.7" in warnings[0]
        assert "not only this machine" in warnings[0]
        url = lines[0].split("serving the viewer at ")[1].split()[0]
        shown = urlsplit(url).hostname
        assert shown not in ("127.0.0.1", "localhost", "::1"), lines[0]
        if host == "192.0.2.7":
            assert shown == "192.0.2.7"
        else:
            assert shown == socket.gethostname().lower() or shown == socket.gethostname()
        assert "secret=" + "s" * 43 in url
    for host in ("127.0.0.1", "localhost", "::1", "127.0.0.2"):
        lines.clear()
        warnings.clear()
        web.serve(Fake(), host=host, port=8123, announce=lines.append)
        assert not warnings, (host, warnings)


@pytest.mark.parametrize("proxied", [False, True])
def test_guard_through_jupyter_server_proxy(proxied):
    """jupyter-server-proxy passes the browser's Host and Origin on (the notebook server's
    site, e.g. a JupyterHub's name): refused when serving directly, answered when the viewer
    is proxied (the proxy checked them; the websocket's secret is the lock). Directly, the
    page's own address is still answered."""
    import asyncio

    from aiohttp import web as aiohttp_web
    from aiohttp.test_utils import make_mocked_request

    from xray_viz.viz.web import _request_guard

    guard = _request_guard("127.0.0.1", proxied=proxied)

    async def handler(request):
        return aiohttp_web.Response(text="page")

    def status(headers):
        request = make_mocked_request("GET", "/ws", headers=headers)
        return asyncio.run(guard(request, handler)).status

    hub = {"Host": "hub.example.org", "Origin": "https://hub.example.org",
           "Upgrade": "websocket", "Connection": "Upgrade"}
    assert status(hub) == (200 if proxied else 403)
    assert status({"Host": "127.0.0.1:8888", "Origin": "http://127.0.0.1:8888"}) \
        == (200 if proxied else 403)                   # the notebook's port, not the viewer's
    assert status({"Host": "127.0.0.1:8888"}) == 200
