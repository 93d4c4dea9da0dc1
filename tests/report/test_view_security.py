"""``photorecon view``'s server answers only the viewer's own page: a request whose ``Origin`` is another site
(a web page open in the same browser) or whose ``Host`` is not this machine (DNS rebinding) is refused with
403 before any byte of the scene is sent; the viewer's own origin (127.0.0.1 or localhost) gets the scene.
Loopback only, every wait bounded.
"""
from __future__ import annotations

import socket
import time
from pathlib import Path

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


def _receive(port: int, origin: str, timeout: float, enough: int | None = None, quiet: float | None = None) -> int:
    """Bytes of scene messages a WebSocket client with this ``Origin`` receives within ``timeout`` s: until it has
    ``enough`` of them, or until none comes for ``quiet`` s."""
    import viser
    from websockets.sync.client import connect

    got = 0
    with connect(f"ws://127.0.0.1:{port}", origin=origin, subprotocols=[f"viser-v{viser.__version__}"],
                 open_timeout=timeout, max_size=None) as ws:
        deadline = time.time() + timeout
        while (enough is None or got < enough) and time.time() < deadline:
            wait = max(0.1, deadline - time.time()) if quiet is None else quiet
            try:
                got += len(ws.recv(timeout=wait))
            except TimeoutError:
                break
    return got


def receives_all(port: int, origin: str, quiet: float = 2.0, timeout: float = 30.0) -> int:
    """Bytes of scene messages received until none comes for ``quiet`` s (or ``timeout`` s in all)."""
    return _receive(port, origin, timeout, quiet=quiet)


def receives_scene(port: int, origin: str, timeout: float = 10.0) -> int:
    """Bytes of scene messages a WebSocket client with this ``Origin`` receives within ``timeout`` s (it stops
    after 10,000)."""
    return _receive(port, origin, timeout, enough=10_000)


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


@pytest.mark.slow
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

    from photorecon.report.live import viewer_request_refusal

    h = Headers([("Host", host)] + ([("Origin", origin)] if origin else []))
    assert (viewer_request_refusal(h, "127.0.0.1") is not None) == refused
    two = Headers([("Host", "127.0.0.1:8080"), ("Host", "evil.example")])
    assert viewer_request_refusal(two, "127.0.0.1") is not None


# --- report.html and the viewer page: names shown as text, never as markup ------------------------------------------
NASTY = "q</script><script>alert(1)</script>\"x'<!--.png"  # a photo in subfolders 'q<' and 'script><script>alert(1)<'


class _Page:
    """What an HTML parser (the same tokenizer rules as a browser's) makes of a page: its tags and its text."""

    def __init__(self, text: str):
        from html.parser import HTMLParser

        self.tags, self.attrs, self.text, self.scripts = [], [], [], []
        page = self

        class P(HTMLParser):
            def handle_starttag(self, tag, attrs):
                page.tags.append(tag)
                page.attrs += attrs

            def handle_data(self, data):
                (page.scripts if page.tags and page.tags[-1] == "script" else page.text).append(data)

        p = P(convert_charrefs=True)
        p.feed(text)
        p.close()
        self.all_text = "".join(self.text)


def test_report_html_shows_names_with_markup_as_text(tmp_path):
    """Photo names holding '</script>', '<script>', quotes and '<!--' (in the unregistered list, the warnings,
    the parameters, a depth map's file name, the cameras) neither end the page's scripts nor add an element or
    an attribute: the page has exactly the viewer's three scripts and shows each name as text."""
    from photorecon.cameras import Intrinsics, View, look_at, ring_positions
    from photorecon.io.colmap_text import SparseModel, write_colmap_text
    from photorecon.io.images import write_image
    from photorecon.mesh import export
    from photorecon.report import write_html_report

    out = tmp_path / "out"
    out.mkdir()
    export(trimesh.creation.icosphere(2), out / "mesh.ply")
    names = [NASTY, "plain.png"]
    views = [View(n, Intrinsics.from_fov(64, 48, 50), look_at(p, [0, 0, 0]), image_file=n)
             for n, p in zip(names, ring_positions(2, 4.0, 20))]
    write_colmap_text(SparseModel(views), out / "sparse" / "0")
    depth_name = "d\"'<img src=x onerror=alert(1)>.png"
    (out / "depth").mkdir()
    write_image(out / "depth" / depth_name, np.full((8, 8, 3), 128, np.uint8))
    report = {"photorecon": "test", "input": f"/photos/{NASTY}", "stages": {"poses": {"seconds": 1.0}},
              "poses": {"registered": 1, "unregistered": [NASTY]}, "mesh": {"vertices": 1, "faces": 2},
              "warnings": [f"view {NASTY}: few points"], "parameters": {"run": {"masks": NASTY}}}
    text = write_html_report(out, report).read_text()
    page = _Page(text)
    assert page.tags.count("script") == 3 and text.lower().count("</script") == 3  # the viewer's own
    assert page.tags.count("img") == 1  # the depth map (no preview.png here); no element from a name
    assert not any(k.startswith("on") for k, _ in page.attrs)
    assert page.all_text.count(NASTY) >= 3  # input, unregistered, warning (and the parameters, JSON-escaped)
    assert ("alt", depth_name) in page.attrs
    assert "No 3D view" not in page.all_text  # the viewer's data and script are whole


def test_viewer_data_holds_no_markup(tmp_path):
    """The viewer's embedded JSON has no '<' at all (no '</script>' nor '<!--' that would end or break its
    element) and still decodes to the same data; the standalone page's title shows a folder name as text."""
    import json
    import re

    from photorecon.cli import main
    from photorecon.mesh import export
    from photorecon.report import viewer_html, viewer_payload

    payload = viewer_payload(trimesh.creation.icosphere(1))
    payload["meta"]["note"] = NASTY + " & <b>"
    body = viewer_html(payload)
    meta = re.search(r'id="prv-meta">(.*?)</script>', body, re.S).group(1)
    assert "<" not in meta and ">" not in meta and json.loads(meta) == payload["meta"]
    folder = tmp_path / "r\"'<script>alert(1)<!--"
    folder.mkdir()
    export(trimesh.creation.icosphere(1), folder / "mesh.ply")
    assert main(["view", str(folder), "--html", str(tmp_path / "v.html")]) == 0
    page = _Page((tmp_path / "v.html").read_text())
    assert page.tags.count("script") == 3 and f"photorecon: {folder}" in page.all_text


# --- view while another run writes the folder ------------------------------------------------------------------------
WRITER = r"""
import sys, time
from pathlib import Path
from photorecon.io.output import output_lock
out = Path(sys.argv[1])
with output_lock(out):
    images_txt = out / "sparse" / "0" / "images.txt"
    kept = images_txt.read_bytes()
    images_txt.unlink()  # the model as a run leaves it between two steps
    print("ready", flush=True)
    sys.stdin.readline()
    time.sleep(0.5)
    images_txt.write_bytes(kept)  # the run's next step completes it
    sys.stdin.readline()
"""


@pytest.mark.slow
def test_view_while_a_run_writes_the_folder(tmp_path, capsys, caplog):
    """Another process holds the folder's lock (a run writing it) and its model is incomplete at the moment:
    ``view`` tries again, and shows the result once the model is whole (a warning names the run); when it
    stays incomplete, one line names the run (exit 3), never a traceback."""
    import json
    import os
    import re
    import subprocess
    import sys

    from photorecon.cameras import Intrinsics, View, look_at, ring_positions
    from photorecon.cli import main
    from photorecon.io.colmap_text import SparseModel, write_colmap_text
    from photorecon.mesh import export
    from photorecon.report import result as report_result

    out = tmp_path / "out"
    out.mkdir()
    export(trimesh.creation.icosphere(2), out / "mesh.ply")
    views = [View(f"v{i}", Intrinsics.from_fov(64, 48, 50), look_at(p, [0, 0, 0]))
             for i, p in enumerate(ring_positions(3, 4.0, 20))]
    write_colmap_text(SparseModel(views), out / "sparse" / "0")
    page = tmp_path / "v.html"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    writer = subprocess.Popen([sys.executable, "-c", WRITER, str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True, env=env)
    try:
        assert writer.stdout.readline().strip() == "ready"
        old = report_result.LOAD_RETRY_SECONDS
        report_result.LOAD_RETRY_SECONDS = 1.0
        try:
            t0 = time.monotonic()
            assert main(["view", str(out), "--html", str(page)]) == 3
            err = capsys.readouterr().err.strip()
            assert len(err.splitlines()) == 1 and "images.txt" in err and f"process {writer.pid}" in err, err
            assert "is writing" in err and time.monotonic() - t0 < 10
            assert not page.exists()
            writer.stdin.write("fix\n")
            writer.stdin.flush()
            report_result.LOAD_RETRY_SECONDS = 10.0
            assert main(["view", str(out), "--html", str(page)]) == 0  # tried again until the model was whole
        finally:
            report_result.LOAD_RETRY_SECONDS = old
        assert any(f"process {writer.pid}" in r.getMessage() and "is writing" in r.getMessage()
                   for r in caplog.records if r.levelname == "WARNING")
        meta = json.loads(re.search(r'id="prv-meta">(.*?)</script>', page.read_text()).group(1))
        assert meta["cameras"] == 3
        writer.stdin.write("quit\n")
        writer.stdin.flush()
        assert writer.wait(10) == 0
    finally:
        if writer.poll() is None:
            writer.kill()
            writer.wait(10)
    caplog.clear()
    assert main(["view", str(out), "--html", str(page), "--overwrite"]) == 0  # the run ended: no warning
    assert not any("is writing" in r.getMessage() for r in caplog.records)
