"""Looking at results: report.html's embedded WebGL viewer and ``photorecon view`` (viser), checked in a real
headless Chromium (software WebGL): the mesh's rendered silhouette matches a ray-cast of the same viewpoint.

Chromium comes from Debian (``apt-get install chromium``; tools/install.sh does it). Without it these tests
skip, except under CI (``CI=true``), where a missing browser fails them.
"""
from __future__ import annotations

import base64
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from photorecon.cameras import Intrinsics, View, look_at, project, ring_positions
from photorecon.io.colmap_text import SparseModel, write_colmap_text
from photorecon.io.images import write_image
from photorecon.mesh import export

BACKGROUND = np.array([238, 240, 243])  # the viewer's clear colour (0.933, 0.941, 0.953)
REPO = Path(__file__).resolve().parents[2]


# --- a small result folder: a "snowman" (up is +z) with vertex colours, 8 cameras, their images ------------------
def snowman() -> trimesh.Trimesh:
    a = trimesh.creation.icosphere(3, radius=1.0)
    b = trimesh.creation.icosphere(3, radius=0.5)
    b.vertices += [0, 0, 1.3]
    m = trimesh.util.concatenate([a, b])
    v = np.asarray(m.vertices)
    rgb = np.clip(np.c_[0.5 + 0.4 * v[:, 0], 0.5 + 0.4 * v[:, 1], 0.3 + 0.3 * v[:, 2]], 0, 1) * 255
    return trimesh.Trimesh(v, m.faces, vertex_colors=np.c_[rgb.astype(np.uint8), np.full(len(v), 255, np.uint8)],
                           process=False)


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("viewer_result")
    export(snowman(), out / "mesh.ply")
    intr = Intrinsics.from_fov(64, 48, 50)
    views = []
    (out / "images").mkdir()
    for i, p in enumerate(ring_positions(8, 5.0, 20, center=(0, 0, 0.3))):
        views.append(View(f"v{i}", intr, look_at(p, [0, 0, 0.3]), image_file=f"v{i}.png"))
        write_image(out / "images" / f"v{i}.png", np.full((48, 64, 3), (30 * i, 100, 200 - 20 * i), np.uint8))
    write_colmap_text(SparseModel(views), out / "sparse" / "0")
    (out / "depth").mkdir()
    write_image(out / "depth" / "v0.png", np.full((48, 64, 3), 128, np.uint8))
    write_image(out / "preview.png", np.full((30, 40, 3), 200, np.uint8))
    return out


# --- headless Chromium through the DevTools protocol ----------------------------------------------------------
def chromium_or_skip() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        exe = shutil.which(name)
        if exe:
            return exe
    if os.environ.get("CI", "").lower() in ("true", "1"):
        pytest.fail("CI=true but no chromium on PATH: tools/install.sh installs it (apt-get install chromium)")
    pytest.skip("no chromium on PATH (apt-get install chromium): the headless-browser checks need it")


class Browser:
    """One headless Chromium with software WebGL (SwiftShader); ``open(url)``, ``eval(js)``, ``screenshot()``."""

    def __init__(self, profile: Path, width: int, height: int):
        from websockets.sync.client import connect

        self.proc = subprocess.Popen(
            [chromium_or_skip(), "--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--hide-scrollbars", "--no-first-run", "--remote-debugging-port=0",
             f"--user-data-dir={profile}", f"--window-size={width},{height}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file = profile / "DevToolsActivePort"
        deadline = time.time() + 20
        while not (port_file.is_file() and port_file.read_text().strip()):
            if time.time() > deadline or self.proc.poll() is not None:
                self.close()
                raise RuntimeError("chromium did not open its DevTools port")
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        pages = []
        while not pages and time.time() < deadline:
            pages = [t for t in json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list"))
                     if t["type"] == "page"]
            time.sleep(0.1)
        self.ws = connect(pages[0]["webSocketDebuggerUrl"], max_size=None)
        self.n = 0
        self.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1, mobile=False)

    def call(self, method: str, **params) -> dict:
        self.n += 1
        self.ws.send(json.dumps({"id": self.n, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=30))
            if msg.get("id") == self.n:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg["result"]

    def open(self, url: str) -> None:
        self.call("Page.navigate", url=url)

    def eval(self, js: str):
        return self.call("Runtime.evaluate", expression=js, returnByValue=True)["result"].get("value")

    def screenshot(self) -> np.ndarray:
        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]  # RGB

    def close(self) -> None:
        if getattr(self, "ws", None) is not None:
            self.ws.close()
        self.proc.kill()
        self.proc.wait(10)


def wait_for(predicate, timeout: float, what: str):
    deadline = time.time() + timeout
    while True:
        value = predicate()
        if value is not None:
            return value
        if time.time() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.25)


def expected_silhouette(mesh: trimesh.Trimesh, cameras, width: int, height: int) -> np.ndarray:
    """The mesh's mask from the viewer's first viewpoint, by ray casting (photorecon's own renderer)."""
    from photorecon.report import initial_eye, initial_view
    from photorecon.render import Renderer

    v = initial_view(mesh, cameras)
    eye = initial_eye(v, width, height)
    view = View("viewer", Intrinsics.from_fov(width, height, v["fov_deg"], axis="y"), look_at(eye, v["target"], v["up"]))
    return Renderer(mesh).render(view).mask


# --- tests ----------------------------------------------------------------------------------------------------
def test_viewer_payload_holds_the_mesh_and_frusta(result):
    """The embedded data decodes to the mesh (positions within half a quantisation step, faces and colours
    exact); a mesh over the budget is decimated to it; each frustum's corner lines end on the image corners."""
    from photorecon.report import frustum_segments, result_cameras, viewer_payload

    mesh = snowman()
    cams = result_cameras(result)
    p = viewer_payload(mesh, cams)
    m = p["meta"]
    buf = zlib.decompress(base64.b64decode(p["data"]))
    nf, nv = m["faces"], m["vertices"]
    assert (nf, nv) == (len(mesh.faces), len(mesh.vertices)) and m["colored"] and m["cameras"] == 8
    faces = np.frombuffer(buf, "<u4", nf * 3).reshape(-1, 3)
    q = np.frombuffer(buf, "<u2", nv * 3, offset=nf * 12).reshape(-1, 3)
    rgb = np.frombuffer(buf, np.uint8, nv * 3, offset=nf * 12 + nv * 6).reshape(-1, 3)
    assert np.array_equal(faces, mesh.faces)
    assert np.abs(np.asarray(m["offset"]) + q * m["step"] - mesh.vertices).max() <= 0.51 * m["step"]
    assert np.array_equal(rgb, np.asarray(mesh.visual.vertex_colors)[:, :3])
    small = viewer_payload(mesh, cams, max_faces=1000)["meta"]
    assert 900 <= small["faces"] <= 1000 and small["faces_full"] == len(mesh.faces)
    # frusta: 8 segments per camera; the 4 rays from the centre pass through the image corners
    seg = frustum_segments(cams[:1], 0.5).reshape(-1, 2, 3)
    assert seg.shape == (8, 2, 3)
    c = cams[0]
    assert np.allclose(seg[0::2, 0], c.center, atol=1e-5)
    uv, z = project(seg[0::2, 1], c.intrinsics, c.cam_from_world)
    W, H = c.intrinsics.size
    assert np.all(z > 0) and np.allclose(uv, [[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]],
                                          atol=1e-3)


@pytest.mark.browser
def test_report_html_renders_the_mesh_in_a_headless_browser(result, tmp_path):
    """report.html from file:// in headless Chromium: the WebGL view draws the mesh where a ray-cast of the
    same viewpoint puts it (silhouette IoU), shaded (many distinct colours); the report's other parts stay."""
    from photorecon.report import result_cameras, write_html_report

    report = {"photorecon": "test", "input": "x", "stages": {"poses": {"seconds": 1.0}},
              "mesh": {"vertices": 1, "faces": 2}, "warnings": [], "parameters": {"run": {"a": 1}}}
    page = write_html_report(result, report)
    text = page.read_text()
    assert "<h2>Summary</h2>" in text and "<h2>Depth maps</h2>" in text and text.count("data:image/png;base64") == 2
    assert not re.search(r"""(src|href)=["']?(https?:)?//|url\(|fetch\(|import\(""", text)  # nothing fetched
    W, H = 640, 480
    b = Browser(tmp_path / "profile", W, H)
    try:
        b.open(page.as_uri() + "#viewer")  # the viewer fills the window
        state = wait_for(lambda: b.eval("document.getElementById('prv-canvas').dataset.state") or None, 20, "the viewer")
        msg = b.eval("document.getElementById('prv-msg').textContent")
        assert state == "drawn", msg
        img = b.screenshot()
    finally:
        b.close()
    cv2.imwrite(str(tmp_path / "report.png"), img[:, :, ::-1])
    assert img.shape == (H, W, 3)
    drawn = np.abs(img.astype(int) - BACKGROUND).max(2) > 12
    truth = expected_silhouette(snowman(), result_cameras(result), W, H)
    keep = np.zeros((H, W), bool)
    keep[50:] = True  # below the button bar
    iou = (drawn & truth & keep).sum() / (((drawn | truth) & keep).sum())
    assert truth[keep].mean() > 0.2 and iou > 0.93, iou
    colours = np.unique(img[truth & keep].reshape(-1, 3), axis=0)
    assert len(colours) > 500  # vertex colours and lighting, not a flat fill


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.browser
def test_view_serves_the_result_on_localhost(result, tmp_path):
    """``photorecon view OUT`` serves on 127.0.0.1 and prints the URL; headless Chromium shows the mesh
    (the centre of the page is no longer blank); Ctrl-C stops it with exit code 130."""
    port = _free_port()
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen([sys.executable, "-m", "photorecon", "view", str(result), "--port", str(port),
                             "--lighting", "plain"],  # software WebGL: the environment map takes ~20 s
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    b = None
    try:
        line = proc.stdout.readline()
        assert f"http://127.0.0.1:{port}" in line, line + proc.stderr.read() if proc.poll() is not None else line
        W, H = 800, 600
        b = Browser(tmp_path / "profile", W, H)
        b.open(f"http://127.0.0.1:{port}")

        def mesh_shown():
            try:
                img = b.screenshot()
            except RuntimeError:  # the page is still loading
                return None
            centre = img[int(0.45 * H):int(0.85 * H), int(0.3 * W):int(0.55 * W)]  # the big sphere; no panel
            covered = (centre.astype(int).min(2) < 235).mean()  # viser's background is white
            return img if covered > 0.9 and len(np.unique(centre.reshape(-1, 3), axis=0)) > 100 else None

        img = wait_for(mesh_shown, 25, "viser to draw the mesh")
        cv2.imwrite(str(tmp_path / "view.png"), img[:, :, ::-1])
        # the mesh's own colours: its lower sphere is reddish-green, not the blue of viser's panels
        centre = img[int(0.45 * H):int(0.85 * H), int(0.3 * W):int(0.55 * W)].reshape(-1, 3).astype(int)
        lit = centre[centre.sum(1) > 150]
        assert len(lit) > 0.3 * len(centre) and np.median(lit[:, 0]) > np.median(lit[:, 2]) + 20
    finally:
        if b is not None:
            b.close()
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1].startswith("photorecon view: interrupted")


def test_view_bad_input_and_html(result, tmp_path, capsys):
    """No mesh in the folder, or a mesh without faces: one line, exit 3, nothing served. ``--html FILE``
    writes a standalone page whose embedded mesh decodes."""
    from photorecon.cli import main

    (tmp_path / "empty").mkdir()
    assert main(["view", str(tmp_path / "empty")]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no mesh.ply" in err
    cloud = tmp_path / "cloud" / "mesh.ply"
    cloud.parent.mkdir()
    cloud.write_bytes(trimesh.PointCloud(np.random.default_rng(0).random((50, 3))).export(file_type="ply"))
    assert main(["view", str(cloud.parent)]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no faces" in err
    with pytest.raises(SystemExit) as e:  # refused when the arguments are parsed
        main(["view", str(result), "--max-faces", "2"])
    assert e.value.code == 2
    capsys.readouterr()
    page = tmp_path / "v.html"
    before = sorted(p.name for p in result.rglob("*"))
    assert main(["view", str(result), "--html", str(page), "--max-faces", "1000"]) == 0
    text = page.read_text()
    meta = json.loads(re.search(r'id="prv-meta">(.*?)</script>', text).group(1))
    data = re.search(r'id="prv-data">(.*?)</script>', text).group(1)
    assert meta["faces"] <= 1000 and meta["cameras"] == 8
    assert len(zlib.decompress(base64.b64decode(data))) == meta["faces"] * 12 + meta["vertices"] * 9
    assert sorted(p.name for p in result.rglob("*")) == before  # the result folder is only read
