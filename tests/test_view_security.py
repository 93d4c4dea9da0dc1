"""``photorecon view``'s server answers only the viewer's own page: a request whose ``Origin`` is another site
(a web page open in the same browser) or whose ``Host`` is not this machine (DNS rebinding) is refused with
403 before any byte of the scene is sent; the viewer's own origin (127.0.0.1 or localhost) gets the scene.
Loopback only, every wait bounded.
"""
from __future__ import annotations

import socket
import time

import numpy as np
import pytest
import trimesh

from photorecon.cameras import Intrinsics, View, look_at, ring_positions


def handshake(port: int, host: str, origin: str | None, websocket: bool = True, timeout: float = 10.0) -> int:
    """The HTTP status of a request to 127.0.0.1:``port`` sent with these ``Host`` and ``Origin`` headers
    (a WebSocket upgrade, or a plain GET of the page)."""
    import viser

    lines = ["GET / HTTP/1.1", f"Host: {host}"]
    if websocket:
        lines += ["Upgrade: websocket", "Connection: Upgrade", "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
                  "Sec-WebSocket-Version: 13", f"Sec-WebSocket-Protocol: viser-v{viser.__version__}"]
    if origin is not None:
        lines.append(f"Origin: {origin}")
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        data = b""
        while b"\r\n" not in data:
            chunk = s.recv(4096)
            if not chunk:
                break
            data += chunk
    return int(data.split(b" ", 2)[1])


def receives_scene(port: int, origin: str, timeout: float = 10.0) -> int:
    """Bytes of scene messages a WebSocket client with this ``Origin`` receives within ``timeout`` s."""
    import viser
    from websockets.sync.client import connect

    got = 0
    with connect(f"ws://127.0.0.1:{port}", origin=origin, subprotocols=[f"viser-v{viser.__version__}"],
                 open_timeout=timeout, max_size=None) as ws:
        deadline = time.time() + timeout
        while got < 10_000 and time.time() < deadline:
            try:
                msg = ws.recv(timeout=max(0.1, deadline - time.time()))
            except TimeoutError:
                break
            got += len(msg)
    return got


@pytest.fixture(scope="module")
def server():
    from photorecon.report import start_viewer_server, stop_viewer_server

    mesh = trimesh.creation.icosphere(2)
    cams = [View(f"v{i}", Intrinsics.from_fov(64, 48, 50), look_at(p, [0, 0, 0]))
            for i, p in enumerate(ring_positions(3, 4.0, 20))]
    srv = start_viewer_server(mesh, cams, {}, "127.0.0.1", 0, lighting="plain")
    yield srv.get_port()
    stop_viewer_server(srv)


def test_foreign_origin_is_refused(server):
    """A page of another site opening a WebSocket to the viewer (the browser sends its Origin): 403."""
    port = server
    assert handshake(port, f"127.0.0.1:{port}", "http://evil.example") == 403
    assert handshake(port, f"127.0.0.1:{port}", f"http://127.0.0.1:{port + 1}") == 403  # another local port
    assert handshake(port, f"127.0.0.1:{port}", "null") == 403  # a file:// page or a sandboxed frame
    from websockets.exceptions import InvalidStatus
    with pytest.raises(InvalidStatus) as e:
        receives_scene(port, "http://evil.example")
    assert e.value.response.status_code == 403


def test_foreign_host_is_refused(server):
    """DNS rebinding: evil.example resolved to 127.0.0.1, so Host and Origin agree but name another site."""
    port = server
    assert handshake(port, f"evil.example:{port}", f"http://evil.example:{port}") == 403
    assert handshake(port, f"evil.example:{port}", None) == 403
    assert handshake(port, f"evil.example:{port}", None, websocket=False) == 403  # the page itself too


def test_own_origin_gets_the_scene(server):
    """The viewer's page at http://127.0.0.1:PORT or http://localhost:PORT connects and receives the scene;
    the page itself is served."""
    port = server
    assert handshake(port, f"localhost:{port}", f"http://localhost:{port}") == 101
    assert handshake(port, f"127.0.0.1:{port}", f"http://127.0.0.1:{port}") == 101
    assert handshake(port, f"127.0.0.1:{port}", None, websocket=False) == 200
    assert receives_scene(port, f"http://127.0.0.1:{port}") > 1000  # the mesh's GLB at least


def test_refuses_to_serve_when_viser_bypasses_the_guard(monkeypatch):
    """A viser that no longer starts its server through websockets.asyncio.server.serve cannot be guarded:
    ``start_viewer_server`` stops it and raises instead of serving unprotected."""
    import types

    import viser.infra._infra as infra
    import websockets.asyncio.server as ws_server

    from photorecon.errors import PhotoreconError
    from photorecon.report import start_viewer_server

    unguarded = types.SimpleNamespace(**vars(infra.websockets))  # viser's own reference to the library,
    unguarded.asyncio = types.SimpleNamespace(server=types.SimpleNamespace(**vars(ws_server)))  # unpatched
    unguarded.asyncio.server.serve = ws_server.serve
    monkeypatch.setattr(infra, "websockets", unguarded)
    with pytest.raises(PhotoreconError, match="cannot check who connects"):
        start_viewer_server(trimesh.creation.box(), None, None, "127.0.0.1", 0, lighting="plain")


@pytest.mark.parametrize("host, origin, refused", [
    ("127.0.0.1:8080", "http://127.0.0.1:8080", False),
    ("localhost:8080", "http://localhost:8080", False),
    ("[::1]:8080", "http://[::1]:8080", False),
    ("127.0.0.1:8080", None, False),  # not a browser
    ("127.0.0.1:8080", "https://evil.example", True),
    ("127.0.0.1:8080", "http://localhost:8080", True),  # another origin than the page's
    ("evil.example:8080", "http://evil.example:8080", True),
    ("localhost.evil.example:8080", None, True),
    ("127.0.0.1:80x", None, True),
])
def test_request_check(host, origin, refused):
    from websockets.datastructures import Headers

    from photorecon.report.html import viewer_request_refusal

    h = Headers([("Host", host)] + ([("Origin", origin)] if origin else []))
    assert (viewer_request_refusal(h, "127.0.0.1") is not None) == refused
    two = Headers([("Host", "127.0.0.1:8080"), ("Host", "evil.example")])
    assert viewer_request_refusal(two, "127.0.0.1") is not None
