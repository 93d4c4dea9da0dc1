"""The 3D view embedded in report.html and in the standalone viewer page (``photorecon view OUT --html FILE``).

The 3D view is a small hand-written WebGL2 viewer (``viewer.js``, package data; no library, no network): the mesh
(decimated to ``PAGE_MAX_FACES``) travels inside the page as zlib-compressed base64 (uint32 faces, uint16
positions quantised over the bounding box, uint8 vertex colours) and is inflated by the browser's
``DecompressionStream``; the cameras are drawn as frusta (line segments). Orbit / pan / zoom with mouse or
touch, a reset button. The page opens from ``file://`` with no server. With a textured model (report.html when
the run wrote model.glb: ``textured.model_payload``, in the mesh's and cameras' frame) the view opens on the model,
its atlas a WebGL texture, and a toggle switches between it and the vertex-coloured mesh.

The initial view is computed here (``initial_view``) so tests can render the same viewpoint and compare
silhouettes: the camera looks at the mesh's bounding-box centre from direction ``front`` tilted by
``elevation_deg`` towards ``up``, at the distance where the mesh's bounding sphere fills the narrower field
of view (``fov_deg`` vertical, or the horizontal one when the canvas is taller than wide). ``photorecon view``'s
live viewer (``live``) starts from the same view.
"""
from __future__ import annotations

import base64
import html
from importlib import resources
import json
import logging
import zlib
from pathlib import Path

import numpy as np
import trimesh

from ..cameras import View, invert_rigid
from ..errors import EmptyMeshError
from ..io.atomic import atomic_write_text

log = logging.getLogger("photorecon")

PAGE_MAX_FACES = 200_000  # the mesh budget of a page (report.html, --html): about 3 MB of page for 200k faces
VIEWER_FOV_DEG = 45.0
VIEWER_ELEVATION_DEG = 20.0


def decimate_for_viewer(mesh: trimesh.Trimesh, max_faces: int = PAGE_MAX_FACES) -> trimesh.Trimesh:
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
                   max_faces: int = PAGE_MAX_FACES, model: dict | None = None) -> dict:
    """The viewer's data: ``meta`` (JSON-able: counts, quantisation, initial view, frusta) and ``data``
    (base64 of zlib(faces uint32 | positions uint16 | colours uint8)); with ``model`` (``textured.model_payload``:
    the textured model, in the frame of ``mesh`` and ``cameras``) also ``model``, which the view shows first,
    with a toggle to the mesh."""
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
    payload = {"meta": meta, "data": base64.b64encode(blob).decode("ascii")}
    if model is not None:
        payload["model"] = model
    return payload


def _script_text(obj) -> str:
    """JSON for inside a ``<script>`` element: no '<' at all (a name holding '</script>' or '<!--' would end or
    break the element)."""
    return (json.dumps(obj, separators=(",", ":"))
            .replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026"))


def viewer_html(payload: dict, full_window: bool = False) -> str:
    """A ``<div>`` with the canvas, its buttons, the embedded data and the viewer script. ``full_window``:
    the viewer fills the page (the standalone page); otherwise ``#viewer`` in the URL does that."""
    m = dict(payload["meta"])
    model = payload.get("model")
    textured = model is not None and "data" in model
    if textured:
        m["model"] = model["meta"]
    shown = (f"{m['faces']:,} of {m['faces_full']:,} faces" if m["faces_full"] > m["faces"] else f"{m['faces']:,} faces")
    if textured:
        shown = f"textured model {model['meta']['faces']:,} faces, mesh {shown}"
    toggle = note = data = ""
    if textured:  # the textured model first; the mesh (mesh.ply decimated, vertex colours) a click away
        toggle = ('<span class="prv-toggle"><button id="prv-show-model" aria-pressed="true" title="model.glb with its '
                  'texture from the photos">Textured model</button><button id="prv-show-mesh" aria-pressed="false" '
                  'title="mesh.ply (decimated for the page) with its vertex colours">Mesh (vertex colours)</button>'
                  '</span>')
        data = (f'<script type="application/octet-stream" id="prv-model-data">{model["data"]}</script>'
                + "".join(f'<script type="application/octet-stream" id="prv-model-tex-{i}">{t}</script>'
                          for i, t in enumerate(model["textures"])))
    elif model is not None:  # a model the page does not hold: say why
        note = f'<p class="prv-note">No textured view: {html.escape(model["meta"].get("skipped", ""))}</p>'
    return (f'<div id="viewer" class="prv{" prv-page" if full_window else ""}">'
            '<canvas id="prv-canvas"></canvas>'
            f'<div class="prv-bar">{toggle}<button id="prv-reset" title="back to the first view">Reset view</button>'
            '<button id="prv-cams" title="show or hide the camera frusta">Cameras</button>'
            '<button id="prv-fitcams" title="frame the mesh and all cameras">Fit cameras</button>'
            '<button id="prv-colors" title="colours (texture or vertex colours) or plain grey (shows the shape of '
            'dark surfaces)">Colours</button>'
            + ('' if full_window else '<a id="prv-full" href="#viewer">full window</a>') +
            f'<span class="prv-info" title="drag: rotate; right-drag or shift-drag: pan; wheel or pinch: zoom; '
            f'double-click: reset">{html.escape(shown)} &middot; {m["cameras"]} cameras &middot; drag, right-drag, '
            'wheel</span></div>'
            '<div id="prv-msg"></div></div>' + note +
            f'<script type="application/json" id="prv-meta">{_script_text(m)}</script>'
            f'<script type="application/octet-stream" id="prv-data">{payload["data"]}</script>' + data +
            f'<script>{_VIEWER_JS}</script>')


VIEWER_CSS = """.prv{position:relative;width:100%;max-width:1100px;height:560px;background:#eef0f3;border:1px solid #ccc}
.prv canvas{width:100%;height:100%;display:block;touch-action:none;cursor:grab}
.prv-page,.prv:target{position:fixed;left:0;top:0;width:100vw;height:100vh;max-width:none;border:0;z-index:10}
.prv-bar{position:absolute;left:8px;top:8px;font:13px sans-serif;color:#333}
.prv-bar button,.prv-bar a{font:13px sans-serif;margin-right:4px;padding:3px 8px;background:#fff;border:1px solid #999;border-radius:3px;color:#222;text-decoration:none}
.prv-bar button[aria-pressed=true]{background:#dbe6f5;border-color:#4a6a9a}
.prv-toggle{margin-right:8px}
.prv-info{margin-left:6px;background:rgba(255,255,255,.7);padding:2px 4px}
#prv-msg{position:absolute;left:8px;bottom:8px;font:14px sans-serif;color:#a00}"""

# the 3D viewer of report.html and of `photorecon view`'s page: a package data file (viewer.js)
_VIEWER_JS = resources.files(__package__).joinpath("viewer.js").read_text(encoding="utf-8")


def write_viewer_page(path: str | Path, mesh: trimesh.Trimesh, cameras: list[View] | None = None,
                      title: str = "photorecon viewer", max_faces: int = PAGE_MAX_FACES) -> Path:
    """A standalone page holding only the 3D viewer (full window), written atomically."""
    body = viewer_html(viewer_payload(mesh, cameras, max_faces), full_window=True)
    page = (f'<!doctype html><html><head><meta charset="utf-8"><meta name="viewport" content="width=device-width">'
            f'<title>{html.escape(title)}</title><style>body{{margin:0}}{VIEWER_CSS}</style></head>'
            f'<body>{body}</body></html>')
    return atomic_write_text(path, page)
