"""What people look at: report.html (previews, an interactive 3D view, depth maps, numbers) and the
standalone 3D viewer page.

The 3D view is a small hand-written WebGL2 viewer (no library, no network): the mesh (decimated to
``VIEWER_MAX_FACES``) travels inside the page as zlib-compressed base64 (uint32 faces, uint16 positions
quantised over the bounding box, uint8 vertex colours) and is inflated by the browser's
``DecompressionStream``; the cameras are drawn as frusta (line segments). Orbit / pan / zoom with mouse or
touch, a reset button. The page opens from ``file://`` with no server.

The initial view is computed here (``initial_view``) so tests can render the same viewpoint and compare
silhouettes: the camera looks at the mesh's bounding-box centre from direction ``front`` tilted by
``elevation_deg`` towards ``up``, at the distance where the mesh's bounding sphere fills the narrower field
of view (``fov_deg`` vertical, or the horizontal one when the canvas is taller than wide).
"""
from __future__ import annotations

import base64
import contextlib
import html
from importlib import resources
import io
import struct
import json
import logging
import threading
import zlib
from pathlib import Path

import numpy as np
import trimesh

from ..cameras import View, invert_rigid
from ..errors import EmptyMeshError
from ..io.atomic import atomic_write_text
from ..io.paths import inside
from ..layout import Layout

log = logging.getLogger("photorecon")

VIEWER_MAX_FACES = 200_000  # report.html's mesh budget: about 3 MB of page for 200k faces
VIEWER_FOV_DEG = 45.0
VIEWER_ELEVATION_DEG = 20.0
MESH_NAMES = ("mesh.ply", "mesh.glb", "mesh.obj")


# --- the viewer's data ---------------------------------------------------------------------------------------
def decimate_for_viewer(mesh: trimesh.Trimesh, max_faces: int = VIEWER_MAX_FACES) -> trimesh.Trimesh:
    """``mesh`` itself when it has at most ``max_faces`` faces, else decimated to that budget: quadric
    decimation (Open3D), after a vertex-clustering pass down to about twice the budget when the mesh is
    more than 4x over it (quadric decimation alone took 18 s for 466k -> 200k faces on 2 cores)."""
    if not len(mesh.faces):
        raise EmptyMeshError("the mesh has no triangle: nothing to show")
    if len(mesh.faces) <= max_faces:
        return mesh
    from ..mesh import from_open3d, simplify, to_open3d

    n0 = len(mesh.faces)
    if n0 > 4 * max_faces:
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        edge = float(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1).mean())
        if edge > 0:  # faces scale with 1 / cell^2
            mesh = from_open3d(to_open3d(mesh).simplify_vertex_clustering(edge * np.sqrt(n0 / (2 * max_faces))))
    out = simplify(mesh, max_faces) if len(mesh.faces) > max_faces else mesh
    log.debug("viewer: mesh decimated from %d to %d faces", n0, len(out.faces))
    return out


def scene_up(cameras: list[View] | None) -> np.ndarray:
    """The cameras' mean "up" (-y in OpenCV axes) when they agree on one, else +z."""
    if cameras:
        ups = np.array([-invert_rigid(c.cam_from_world)[:3, 1] for c in cameras]).mean(0)
        if np.linalg.norm(ups) > 0.3:
            return ups / np.linalg.norm(ups)
    return np.array([0.0, 0.0, 1.0])


def initial_view(mesh: trimesh.Trimesh, cameras: list[View] | None = None) -> dict:
    """Where the viewer starts: ``target`` (bounding-box centre), ``radius`` (bounding sphere about it),
    ``up``, ``front`` (unit, perpendicular to ``up``: from the target towards the cameras' mean position
    when they stand on one side, as for a facade, else between the first camera and its nearest neighbour;
    +x-ish without cameras),
    ``elevation_deg`` and ``fov_deg``. All in the mesh's world units and frame."""
    verts = np.asarray(mesh.vertices, np.float64)
    lo, hi = verts.min(0), verts.max(0)
    target = (lo + hi) / 2
    radius = float(np.linalg.norm(verts - target, axis=1).max()) or 1.0
    up = scene_up(cameras)
    front = None
    if cameras:
        dirs = np.array([c.center for c in cameras]) - target
        dirs /= np.maximum(np.linalg.norm(dirs, axis=1, keepdims=True), 1e-12)
        mean_dir = dirs.mean(0)
        if np.linalg.norm(mean_dir) > 0.5 or len(dirs) == 1:
            front = mean_dir
        else:  # all around: between the first camera and its nearest neighbour, so that no camera (nor its
            # image, in 'photorecon view') stands in front of the eye
            front = dirs[0] + dirs[1 + int(np.argmax(dirs[1:] @ dirs[0]))]
    if front is not None:
        front = front - (front @ up) * up
    if front is None or np.linalg.norm(front) < 1e-6:
        a = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
        front = a - (a @ up) * up
    front = front / np.linalg.norm(front)
    return {"target": target.tolist(), "radius": radius, "up": up.tolist(), "front": front.tolist(),
            "elevation_deg": VIEWER_ELEVATION_DEG, "fov_deg": VIEWER_FOV_DEG}


def initial_eye(view: dict, width: int, height: int) -> np.ndarray:
    """The viewer's first eye position for a ``width`` x ``height`` canvas (the JavaScript's ``reset``)."""
    fov_y = np.radians(view["fov_deg"])
    fov_min = min(fov_y, 2 * np.arctan(np.tan(fov_y / 2) * width / height))
    dist = view["radius"] / np.sin(fov_min / 2) * 1.05
    el = np.radians(view["elevation_deg"])
    d = np.cos(el) * np.asarray(view["front"]) + np.sin(el) * np.asarray(view["up"])
    return np.asarray(view["target"]) + dist * d


def frustum_scale(view: dict, cameras: list[View]) -> float:
    """Frustum depth for drawing: a tenth of the cameras' median distance to the target (readable when the
    view frames all the cameras), at least 0.12 of the mesh's radius."""
    d = np.linalg.norm(np.array([c.center for c in cameras]) - view["target"], axis=1)
    return max(0.1 * float(np.median(d)), 0.12 * view["radius"])


def frustum_segments(cameras: list[View], scale: float) -> np.ndarray:
    """(16 * len(cameras), 3) float32: per camera, 8 line segments (centre to the 4 image corners, and the
    image rectangle) with the image plane at ``scale`` from the centre along the longest corner ray."""
    segs = []
    for cam in cameras:
        W, H = cam.intrinsics.size
        corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
        rays = cam.intrinsics.pixel_rays(corners)
        rays *= scale / np.linalg.norm(rays, axis=1, keepdims=True).max()
        world_from_cam = invert_rigid(cam.cam_from_world)
        c = world_from_cam[:3, 3]
        p = rays @ world_from_cam[:3, :3].T + c
        for i in range(4):
            segs += [c, p[i], p[i], p[(i + 1) % 4]]
    return np.asarray(segs, np.float32).reshape(-1, 3)


def viewer_payload(mesh: trimesh.Trimesh, cameras: list[View] | None = None,
                   max_faces: int = VIEWER_MAX_FACES) -> dict:
    """The viewer's data: ``meta`` (JSON-able: counts, quantisation, initial view, frusta) and ``data``
    (base64 of zlib(faces uint32 | positions uint16 | colours uint8))."""
    shown = decimate_for_viewer(mesh, max_faces)
    verts = np.asarray(shown.vertices, np.float64)
    faces = np.ascontiguousarray(shown.faces, dtype="<u4")
    lo, hi = verts.min(0), verts.max(0)
    step = max(float((hi - lo).max()), 1e-12) / 65535.0
    q = np.clip(np.round((verts - lo) / step), 0, 65535).astype("<u2")
    colors = None
    if shown.visual.kind == "texture":  # a textured mesh: its texture sampled at the vertices
        try:
            shown = trimesh.Trimesh(shown.vertices, shown.faces, process=False,
                                    vertex_colors=shown.visual.to_color().vertex_colors)
        except Exception as exc:  # a texture trimesh cannot sample: grey, and say so
            log.warning("viewer: texture not shown (%s)", exc)
    if shown.visual.kind == "vertex":
        colors = np.asarray(shown.visual.vertex_colors)[:, :3].astype(np.uint8)
    has_colors = colors is not None and colors.std() > 1
    if not has_colors:
        colors = np.full((len(verts), 3), 190, np.uint8)
    blob = zlib.compress(faces.tobytes() + q.tobytes() + np.ascontiguousarray(colors).tobytes(), 6)
    view = initial_view(shown, cameras)
    cams = cameras or []
    lines = frustum_segments(cams, frustum_scale(view, cams)) if cams else np.zeros((0, 3), np.float32)
    meta = {"faces": int(len(faces)), "vertices": int(len(verts)), "faces_full": int(len(mesh.faces)),
            "offset": lo.tolist(), "step": step, "colored": bool(has_colors), "view": view,
            "cameras": len(cams), "frustum_scale": frustum_scale(view, cams) if cams else 0.0, "frusta": np.round(lines, 6).ravel().tolist(),
            "camera_centers": [np.round(c.center, 6).tolist() for c in cams]}
    return {"meta": meta, "data": base64.b64encode(blob).decode("ascii")}


def find_mesh(folder: Path) -> Path | None:
    for name in MESH_NAMES:
        if (folder / name).is_file():
            return folder / name
    return None


def writing_run(folder: str | Path) -> str | None:
    """The photorecon run (another process) that is writing the result folder ``folder`` now, in words
    (``process PID: COMMAND``), or None: nobody holds its lock (``OUT/.photorecon.lock``), or that cannot be
    told (no ``flock`` on this file system)."""
    import os

    from ..io.output import LOCK

    try:
        import fcntl
    except ImportError:  # pragma: no cover (Windows)
        return None
    try:
        fd = os.open(Path(folder) / LOCK, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            return None  # not held: no run, or a stale lock
        except BlockingIOError:
            pass
        except OSError:
            return None
        try:
            info = json.loads(os.pread(fd, 4096, 0).decode("utf-8", "replace") or "{}")
        except (OSError, ValueError):
            info = {}
        info = info if isinstance(info, dict) else {}
        return f"process {info.get('pid', '?')}" + (f": {info['command']}" if info.get("command") else "")
    finally:
        os.close(fd)


# while a run writes the folder, a file may be between its two renames (a folder swapped in): tried again so long
LOAD_RETRY_SECONDS = 3.0


def load_result(path: str | Path) -> tuple[trimesh.Trimesh, list[View], dict[str, Path]]:
    """A result to look at: ``path`` is a result folder (``reconstruct`` or ``fuse`` output: OUT/mesh.ply,
    .glb or .obj, cameras from OUT/sparse/0 or OUT/transforms.json when there, images in OUT/images) or a
    mesh file (with the cameras of its folder when it has any; OUT/textured and a mesh in it: OUT's). Returns (mesh, cameras, view name -> image file). Raises ``InputDataError`` (no mesh, a
    mesh without faces, unreadable cameras).

    A folder that another photorecon run is writing (``writing_run``) is read as it is (its last complete
    stages: every file and folder there is replaced whole), with a warning; a read that fails is tried again
    for ``LOAD_RETRY_SECONDS`` (a folder being swapped in), then the error names the run."""
    import time

    from ..errors import InputDataError

    p = Path(path)
    folder = p if p.is_dir() else p.parent
    deadline = time.monotonic() + LOAD_RETRY_SECONDS
    while True:
        try:
            result = _load_result(p)
        except (InputDataError, OSError) as exc:
            run = writing_run(folder)
            if run is None:
                raise
            if time.monotonic() < deadline:
                time.sleep(0.2)
                continue
            if isinstance(exc, OSError):
                exc = InputDataError(f"{exc.filename or folder}: {exc.strerror or exc}")
            raise InputDataError(f"{exc}; a photorecon run ({run}) is writing {folder} now: look at it when the "
                                 "run has finished") from None
        run = writing_run(folder)
        if run is not None:
            log.warning("view: a photorecon run (%s) is writing %s now: showing what it holds at this moment "
                        "(its last complete stages); look again when the run has finished", run, folder)
        return result


def _load_result(path: Path) -> tuple[trimesh.Trimesh, list[View], dict[str, Path]]:
    from ..errors import InputDataError
    from ..mesh import load_mesh

    if path.is_dir():
        mesh_path = find_mesh(path)
        if mesh_path is None:
            raise InputDataError(f"{path}: no {', '.join(MESH_NAMES)}; expected the output folder of "
                                 "'photorecon reconstruct' or 'fuse', or a mesh file")
    elif path.is_file():
        mesh_path = path
    else:
        raise InputDataError(f"{path}: no such result folder or mesh file")
    mesh = load_mesh(mesh_path)  # InputDataError for an unreadable file or a mesh without faces
    folder = path if path.is_dir() else path.parent
    if Layout(folder.parent).textured == folder and not result_cameras(folder):
        folder = folder.parent  # OUT/textured (or a mesh in it): the cameras and photos of OUT
    cameras = result_cameras(folder)
    images = {}
    for v in cameras:
        p = inside(Layout(folder).images, v.image_file or v.name, f"view {v.name}")
        if p.is_file():
            images[v.name] = p
    return mesh, cameras, images


def result_cameras(folder: Path) -> list[View]:
    """The cameras of a result folder (OUT/sparse/0 or OUT/transforms.json), or [] when it has none."""
    if not (Layout(folder).sparse.is_dir() or Layout(folder).transforms.is_file()):
        return []
    from ..io.dataset import read_model

    return read_model(folder).views


# --- HTML ------------------------------------------------------------------------------------------------------
def viewer_html(payload: dict, full_window: bool = False) -> str:
    """A ``<div>`` with the canvas, its buttons, the embedded data and the viewer script. ``full_window``:
    the viewer fills the page (the standalone page); otherwise ``#viewer`` in the URL does that."""
    # inside <script>: no '<' at all (a name holding '</script>' or '<!--' would end or break the element)
    meta = (json.dumps(payload["meta"], separators=(",", ":"))
            .replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026"))
    m = payload["meta"]
    shown = (f"{m['faces']:,} of {m['faces_full']:,} faces" if m["faces_full"] > m["faces"] else f"{m['faces']:,} faces")
    return (f'<div id="viewer" class="prv{" prv-page" if full_window else ""}">'
            '<canvas id="prv-canvas"></canvas>'
            '<div class="prv-bar"><button id="prv-reset" title="back to the first view">Reset view</button>'
            '<button id="prv-cams" title="show or hide the camera frusta">Cameras</button>'
            '<button id="prv-fitcams" title="frame the mesh and all cameras">Fit cameras</button>'
            '<button id="prv-colors" title="vertex colours or plain grey (shows the shape of dark surfaces)">Colours</button>'
            + ('' if full_window else '<a id="prv-full" href="#viewer">full window</a>') +
            f'<span class="prv-info" title="drag: rotate; right-drag or shift-drag: pan; wheel or pinch: zoom; '
            f'double-click: reset">{html.escape(shown)} &middot; {m["cameras"]} cameras &middot; drag, right-drag, '
            'wheel</span></div>'
            '<div id="prv-msg"></div></div>'
            f'<script type="application/json" id="prv-meta">{meta}</script>'
            f'<script type="application/octet-stream" id="prv-data">{payload["data"]}</script>'
            f'<script>{_VIEWER_JS}</script>')


VIEWER_CSS = """.prv{position:relative;width:100%;max-width:1100px;height:560px;background:#eef0f3;border:1px solid #ccc}
.prv canvas{width:100%;height:100%;display:block;touch-action:none;cursor:grab}
.prv-page,.prv:target{position:fixed;left:0;top:0;width:100vw;height:100vh;max-width:none;border:0;z-index:10}
.prv-bar{position:absolute;left:8px;top:8px;font:13px sans-serif;color:#333}
.prv-bar button,.prv-bar a{font:13px sans-serif;margin-right:4px;padding:3px 8px;background:#fff;border:1px solid #999;border-radius:3px;color:#222;text-decoration:none}
.prv-info{margin-left:6px;background:rgba(255,255,255,.7);padding:2px 4px}
#prv-msg{position:absolute;left:8px;bottom:8px;font:14px sans-serif;color:#a00}"""

# the 3D viewer of report.html and of `photorecon view`'s page: a package data file (viewer.js)
_VIEWER_JS = resources.files(__package__).joinpath("viewer.js").read_text(encoding="utf-8")


def write_viewer_page(path: str | Path, mesh: trimesh.Trimesh, cameras: list[View] | None = None,
                      title: str = "photorecon viewer", max_faces: int = VIEWER_MAX_FACES) -> Path:
    """A standalone page holding only the 3D viewer (full window), written atomically."""
    body = viewer_html(viewer_payload(mesh, cameras, max_faces), full_window=True)
    page = (f'<!doctype html><html><head><meta charset="utf-8"><meta name="viewport" content="width=device-width">'
            f'<title>{html.escape(title)}</title><style>body{{margin:0}}{VIEWER_CSS}</style></head>'
            f'<body>{body}</body></html>')
    return atomic_write_text(path, page)


def _img_tag(path: Path, width: int | None = None) -> str:
    if not path.is_file():
        return ""
    data = base64.b64encode(path.read_bytes()).decode()
    w = f' width="{width}"' if width else ""
    return f'<img src="data:image/png;base64,{data}"{w} alt="{html.escape(path.name)}">'


def _viewer_section(out: Path) -> str:
    """report.html's 3D view of OUT's mesh and cameras (a line saying why when there is none)."""
    small = Layout(out).viewer_mesh
    path = small if small.is_file() else find_mesh(out)
    if path is None:
        return "<p>No mesh in this folder.</p>"
    from ..mesh import load_mesh

    try:
        mesh = load_mesh(path)
        cameras = result_cameras(out)
        return viewer_html(viewer_payload(mesh, cameras))
    except Exception as exc:  # the report's other contents still matter; say what went wrong
        log.warning("report.html: no 3D view (%s)", exc)
        return f"<p>No 3D view: {html.escape(str(exc))}</p>"


def write_html_report(out: Path, report: dict, extra_rows: dict | None = None) -> Path:
    """A self-contained OUT/report.html: an interactive 3D view of OUT's mesh and cameras, the preview, the
    numbers, depth maps, warnings, parameters. Images and mesh are embedded; it opens with no server."""
    from .page import REPORT_CSS, fact_rows, preview_html, sections_html, stage_rows, summary_facts

    out = Path(out)
    facts = {**summary_facts(report), **(extra_rows or {})}
    depth_imgs = "".join(_img_tag(p, 240) for p in sorted((out / "depth").glob("*.png"))[:24]) if (out / "depth").is_dir() else ""
    warn = "".join(f"<li>{html.escape(w)}</li>" for w in report.get("warnings", [])) or "<li>none</li>"
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>photorecon report</title>
<meta name="viewport" content="width=device-width">
<style>{REPORT_CSS}
{VIEWER_CSS}</style>
</head><body><h1>photorecon report</h1>
<p>photorecon {html.escape(str(report.get('photorecon')))} &middot; input {html.escape(str(report.get('input')))}</p>
<h2>3D view</h2>{_viewer_section(out)}
<h2>Mesh</h2>{preview_html(out / 'preview.png')}
<h2>Summary</h2><table>{fact_rows(facts, report.get('units', 'arbitrary'))}</table>
<h2>Stages</h2><table>{stage_rows(report)}</table>
<h2>Depth maps</h2><div class="tiles depth">{depth_imgs}</div>
<h2>Warnings</h2><ul>{warn}</ul>
<h2>Facts by stage</h2>{sections_html(report)}
<h2>Parameters</h2><pre>{html.escape(json.dumps(report.get('parameters', {}), indent=1))}</pre>
</body></html>"""
    return atomic_write_text(out / "report.html", page)


# --- photorecon view: a live viewer on localhost (viser) --------------------------------------------------------
VIEW_MAX_FACES = 1_000_000  # the live viewer sends the mesh over a local websocket: a larger budget


def _thumbnail(path: Path, long_side: int = 240) -> np.ndarray | None:
    """A small RGB copy of an image for a frustum's picture (None when it cannot be read)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        return None
    s = long_side / max(img.shape[:2])
    if s < 1:
        img = cv2.resize(img, (max(1, round(img.shape[1] * s)), max(1, round(img.shape[0] * s))),
                         interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img[:, :, ::-1])


def _matte_glb(mesh: trimesh.Trimesh) -> bytes:
    """``mesh`` as GLB with smooth vertex normals and a matte material (trimesh's default material has
    roughness 0: a glossy surface that mirrors the lights and washes out the vertex colours)."""
    from trimesh.exchange.gltf import export_glb

    glb = export_glb(trimesh.Scene(mesh), include_normals=True)
    n = struct.unpack_from("<I", glb, 12)[0]  # header (12 bytes), then the JSON chunk: length, type, data
    doc = json.loads(glb[20:20 + n])
    for mat in doc.get("materials", []):
        mat.setdefault("pbrMetallicRoughness", {}).update(metallicFactor=0.0, roughnessFactor=1.0)
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    rest = glb[20 + n:]
    return (struct.pack("<III", 0x46546C67, 2, 20 + len(js) + len(rest)) + struct.pack("<II", len(js), 0x4E4F534A)
            + js + rest)


# Who may connect. A web page the user opens elsewhere can make the browser open a WebSocket to any local port
# (browsers do not apply the same-origin policy to WebSockets), and a DNS-rebinding page can make its own
# name point at 127.0.0.1: either would read the scene (the mesh, the photos' thumbnails). So every request,
# the page's files and the WebSocket alike, is refused (403) unless its ``Host`` names this machine (an IP
# address, ``localhost``, the address served on, this host's name) and, when the browser sends an
# ``Origin`` (it always does for a WebSocket), that origin is the viewer's own page: the same host and port
# as ``Host``, over http or https.
def _host_name(netloc: str) -> str | None:
    """The host name of a ``Host`` header or an origin's ``host[:port]``, lower case, IPv6 without brackets;
    None when it is malformed."""
    netloc = netloc.strip().lower()
    if netloc.startswith("["):
        name, sep, rest = netloc[1:].partition("]")
        if not sep:
            return None
    else:
        name, sep, port = netloc.partition(":")
        rest = sep + port
    if rest and not (rest.startswith(":") and rest[1:].isdigit()):
        return None
    return name or None


def _is_ip(name: str) -> bool:
    import ipaddress

    try:
        ipaddress.ip_address(name)
        return True
    except ValueError:
        return False


def viewer_request_refusal(headers, served_host: str) -> str | None:
    """Why a request to ``photorecon view``'s server (``headers``: its HTTP headers, a mapping with
    ``get_all``) is refused, or None when it comes from the viewer's own page or a program that is not a
    browser (no ``Origin``). ``served_host``: the ``--host`` served on."""
    import socket
    from urllib.parse import urlsplit

    hosts = headers.get_all("Host")
    if len(hosts) != 1:
        return f"{len(hosts)} Host headers"
    name = _host_name(hosts[0])
    local = {"localhost", served_host.strip("[]").lower()}
    if served_host not in ("127.0.0.1", "localhost", "::1"):  # served beyond this machine: its names too
        with contextlib.suppress(OSError):
            local |= {socket.gethostname().lower(), socket.getfqdn().lower()}
    if name is None or not (_is_ip(name) or name in local):
        return f"Host {hosts[0]!r} is not this machine"
    origins = headers.get_all("Origin")
    if not origins:
        return None
    if len(origins) > 1:
        return f"{len(origins)} Origin headers"
    try:
        origin = urlsplit(origins[0].strip())
        ok = origin.scheme in ("http", "https") and origin.netloc.lower() == hosts[0].strip().lower()
    except ValueError:
        ok = False
    return None if ok else f"Origin {origins[0]!r} is not the viewer's page"


_SERVE_LOCK = threading.Lock()  # one guarded start at a time: the patch is process-wide


@contextlib.contextmanager
def _guarded_websockets(served_host: str):
    """While the block runs, every ``websockets.asyncio.server.serve`` started gets ``viewer_request_refusal``
    in front of its own ``process_request`` (viser serves its page and its WebSocket through it). Yields a
    list that counts the servers guarded: ``start_viewer_server`` refuses to serve when viser started none."""
    import websockets.asyncio.server as ws_server
    from websockets.datastructures import Headers
    from websockets.http11 import Response

    guarded: list[int] = []
    refused: set[str] = set()
    original = ws_server.serve

    def serve(*args, **kwargs):
        inner = kwargs.get("process_request")

        def process_request(connection, request):
            why = viewer_request_refusal(request.headers, served_host)
            if why is not None:
                if why not in refused:  # once per cause, not per reconnection
                    refused.add(why)
                    log.warning("view: refused a connection (%s): only this viewer's own page may connect", why)
                body = b"Forbidden: only the photorecon viewer's own page may connect\n"
                return Response(403, "Forbidden", Headers([("Content-Type", "text/plain"),
                                                          ("Content-Length", str(len(body)))]), body)
            return inner(connection, request) if inner is not None else None

        kwargs["process_request"] = process_request
        guarded.append(1)
        return original(*args, **kwargs)

    with _SERVE_LOCK:
        ws_server.serve = serve
        try:
            yield guarded
        finally:
            ws_server.serve = original


def start_viewer_server(mesh: trimesh.Trimesh, cameras: list[View] | None = None,
                        images: dict[str, Path] | None = None, host: str = "127.0.0.1", port: int = 8080,
                        max_faces: int = VIEW_MAX_FACES, lighting: str = "environment"):
    """A viser server showing ``mesh`` (decimated to ``max_faces``) and the ``cameras`` as frusta with their
    images (``images``: view name -> image file) as thumbnails. Returns the running ``viser.ViserServer``
    (``get_port()`` gives the bound port; ``stop()`` ends it)."""
    try:
        import viser
    except ImportError:
        from ..errors import InputDataError

        raise InputDataError("photorecon view needs the 'viser' package: pip install viser "
                             "(or use 'photorecon view OUT --html FILE' for a standalone page)") from None
    from ..conventions import quat_from_rotation

    shown = decimate_for_viewer(mesh, max_faces)
    view = initial_view(shown, cameras)
    logging.getLogger("websockets").setLevel(logging.WARNING)  # no line per connection
    with contextlib.redirect_stdout(io.StringIO()), _guarded_websockets(host) as guarded:  # viser's banner:
        # the command prints its own URL line
        server = viser.ViserServer(host=host, port=port, label="photorecon", verbose=False)
    if not guarded:  # this viser serves some other way: it would let any web page read the scene
        stop_viewer_server(server)
        from ..errors import PhotoreconError

        raise PhotoreconError(f"viser {getattr(viser, '__version__', '?')} does not serve through "
                              "websockets.asyncio.server.serve, so photorecon view cannot check who connects and "
                              "does not serve; install viser 1.1 (pip install 'viser==1.1.*') or use "
                              "'photorecon view OUT --html FILE'")
    server.scene.set_up_direction(tuple(view["up"]))
    server.initial_camera.fov = np.radians(view["fov_deg"])
    server.initial_camera.look_at = tuple(view["target"])
    server.initial_camera.up = tuple(view["up"])
    server.initial_camera.position = tuple(initial_eye(view, 16, 9))
    if lighting == "plain":
        server.scene.configure_environment_map(hdri=None)
    else:
        server.scene.configure_environment_map(environment_intensity=0.8)
    server.scene.configure_default_lights(enabled=True, cast_shadow=False)
    server.scene.add_glb("/mesh", _matte_glb(shown), cast_shadow=False, receive_shadow=False)
    scale = frustum_scale(view, cameras) if cameras else 1.0
    for cam in cameras or []:
        W, H = cam.intrinsics.size
        world_from_cam = invert_rigid(cam.cam_from_world)
        img = _thumbnail(images[cam.name]) if images and cam.name in images else None
        server.scene.add_camera_frustum(
            f"/cameras/{cam.name}", fov=2 * np.arctan2(H / 2, cam.intrinsics.fy), aspect=W / H,
            scale=scale, thickness=0.02 * scale, color=(220, 40, 40), image=img,
            wxyz=quat_from_rotation(world_from_cam[:3, :3]),
            position=world_from_cam[:3, 3])
    return server


def stop_viewer_server(server) -> None:
    with contextlib.redirect_stdout(io.StringIO()):  # viser's "Server stopped"
        server.stop()
