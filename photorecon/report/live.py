"""``photorecon view``: a live viewer on localhost (viser) showing the textured model (model.glb, when the result has
one) or the mesh, and the cameras as frusta with their photos, served only to the viewer's own page
(``viewer_request_refusal``)."""
from __future__ import annotations

import contextlib
import io
import json
import logging
import struct
import threading
from pathlib import Path

import numpy as np
import trimesh

from ..cameras import View, invert_rigid
from .viewer import decimate_for_viewer, frustum_scale, initial_eye, initial_view

log = logging.getLogger("photorecon")

LIVE_MAX_FACES = 1_000_000  # the live viewer sends the mesh over a local websocket: a larger budget than a page's


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


def model_placement(texture: dict | None) -> dict:
    """viser's ``scale``, ``wxyz`` and ``position`` of a node that puts model.glb's points into the reconstruction's
    frame (``textured.model_to_reconstruction``: a rotation, a translation and a uniform scale), for ``texture``:
    report.json's texture section. Raises ValueError when that section's frame is no such transform."""
    from ..conventions import quat_from_rotation
    from .textured import model_to_reconstruction

    back = model_to_reconstruction(texture)
    det = float(np.linalg.det(back[:3, :3]))
    if not det > 0:
        raise ValueError("report.json's texture.frame.model_from_reconstruction does not keep handedness")
    s = det ** (1.0 / 3.0)
    R = back[:3, :3] / s
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
        raise ValueError("report.json's texture.frame.model_from_reconstruction is no rotation, shift and scale")
    return {"scale": s, "wxyz": quat_from_rotation(R), "position": back[:3, 3].copy()}


def start_viewer_server(mesh: trimesh.Trimesh, cameras: list[View] | None = None,
                        images: dict[str, Path] | None = None, host: str = "127.0.0.1", port: int = 8080,
                        max_faces: int = LIVE_MAX_FACES, lighting: str = "environment",
                        model: tuple[bytes, dict] | None = None):
    """A viser server showing ``mesh`` (decimated to ``max_faces``) and the ``cameras`` as frusta with their
    images (``images``: view name -> image file) as thumbnails. ``model``: (model.glb's bytes, its placement in the
    reconstruction's frame, ``model_placement``): the textured model is shown instead of the mesh, with a checkbox
    to switch between them. Returns the running ``viser.ViserServer`` (``get_port()`` gives the bound port;
    ``stop()`` ends it)."""
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
    shown_mesh = server.scene.add_glb("/mesh", _matte_glb(shown), cast_shadow=False, receive_shadow=False,
                                      visible=model is None)
    if model is not None:
        glb, placement = model
        textured = server.scene.add_glb("/model", glb, cast_shadow=False, receive_shadow=False, **placement)
        toggle = server.gui.add_checkbox("textured model (model.glb)", True,
                                         hint="off: the full mesh with vertex colours (mesh.ply)")

        @toggle.on_update
        def _(_event) -> None:
            textured.visible = toggle.value
            shown_mesh.visible = not toggle.value
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
