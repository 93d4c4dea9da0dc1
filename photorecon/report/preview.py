"""PNG previews of results: a mesh rendered from a few viewpoints (with camera frusta), error-coloured meshes."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import trimesh

from ..cameras import Intrinsics, View, invert_rigid, look_at_views, project
from ..io.images import write_image


def bulk_frame(mesh: trimesh.Trimesh, coverage: float = 97.0, n: int = 20_000) -> tuple[np.ndarray, float]:
    """Centre and radius of the bulk of a mesh's *area*: the per-axis median of area-uniform surface samples,
    and the ``coverage`` percentile of their distances from it. A small
    fragment far away (a floater the cleaning kept) or a long thin spike moves neither, unlike the bounding
    box."""
    if not len(mesh.faces) or not mesh.area > 0:
        lo, hi = mesh.bounds
        return (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2 or 1.0
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=0)
    center = np.median(pts, axis=0)
    radius = float(np.percentile(np.linalg.norm(pts - center, axis=1), coverage))
    return center, max(radius, 1e-9)


def _preview_views(mesh: trimesh.Trimesh, n: int, size: int, up=(0.0, 0.0, 1.0),
                   extra_points: np.ndarray | None = None, front: np.ndarray | None = None) -> list[View]:
    center, radius = bulk_frame(mesh)
    if extra_points is not None and len(extra_points):
        radius = max(radius, float(np.linalg.norm(extra_points - center, axis=1).max()))
    # distance at which the sphere holding the bulk of the surface fills the 55-degree view
    radius = radius / np.sin(np.radians(55.0 / 2)) * 1.05
    up = np.asarray(up, float)
    el = np.radians(25.0)
    # an orthonormal frame around `up`; with a `front` direction (cameras on one side, e.g. a facade) the
    # views spread over an arc on that side, else all around
    a = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
    if front is not None:
        f = front - (front @ up) * up
        if np.linalg.norm(f) > 1e-9:
            a = f / np.linalg.norm(f)
    e1 = a - (a @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    az = np.radians(np.linspace(-40, 40, n) if front is not None else np.linspace(30, 390, n, endpoint=False))
    pos = center + radius * (np.cos(el) * (np.cos(az)[:, None] * e1 + np.sin(az)[:, None] * e2) + np.sin(el) * up)
    intr = Intrinsics.from_fov(size, size, 55.0)
    return [View(f"preview_{i}", intr, T) for i, T in enumerate(look_at_views(pos, center, up))]


def render_preview(mesh: trimesh.Trimesh, path: str | Path, cameras: list[View] | None = None, n: int = 4,
                   size: int = 360, up=None) -> Path:
    """Render ``mesh`` (its texture unlit, else vertex colours if any, else grey) from ``n`` viewpoints side by
    side, drawing the ``cameras`` as frusta; write a PNG. The views frame the bulk of the surface's area
    (``bulk_frame``), not its bounding box."""
    from ..render import Renderer

    if up is None:
        up = (0.0, 0.0, 1.0)
        if cameras:  # the cameras' average "up" (-y in OpenCV) is a good guess of the scene's up
            ups = np.array([-invert_rigid(c.cam_from_world)[:3, 1] for c in cameras]).mean(0)
            if np.linalg.norm(ups) > 0.3:
                up = tuple(ups / np.linalg.norm(ups))
    has_colors = mesh.visual.kind == "vertex" and np.asarray(mesh.visual.vertex_colors)[:, :3].std() > 1
    textured = isinstance(mesh.visual, trimesh.visual.TextureVisuals) and mesh.visual.uv is not None
    r = Renderer(mesh, plain=not (has_colors or textured), background_color=(1.0, 1.0, 1.0),
                 soft_light=has_colors, unlit=textured)
    tiles = []
    bulk_center, bulk_radius = bulk_frame(mesh)
    diag = 2 * bulk_radius
    centers = np.array([c.center for c in cameras]) if cameras else None
    front = None
    if cameras:
        dirs = centers - bulk_center
        mean_dir = (dirs / np.linalg.norm(dirs, axis=1, keepdims=True)).mean(0)
        if np.linalg.norm(mean_dir) > 0.5:  # the cameras look from one side
            front = mean_dir
    # the first tiles frame the mesh alone; the rest also the cameras, drawn as frusta
    n_cam = n // 2 if cameras else 0
    close = _preview_views(mesh, n, size, up, front=front)[: n - n_cam]
    wide = _preview_views(mesh, n, size, up, centers, front)[n - n_cam:] if n_cam else []
    for k, v in enumerate(close + wide):
        img = r.render(v).rgb.copy()
        if k >= len(close):
            for cam in cameras or []:
                _draw_frustum(img, v, cam, 0.06 * diag)
        tiles.append(img)
    grid = np.concatenate(tiles, axis=1)
    return write_image(path, grid)


def _draw_frustum(img: np.ndarray, viewer: View, cam: View, scale: float) -> None:
    W, H = cam.intrinsics.size
    corners_px = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
    rays = cam.intrinsics.pixel_rays(corners_px)
    rays *= scale / np.linalg.norm(rays, axis=1, keepdims=True).max()
    wfc = invert_rigid(cam.cam_from_world)
    pts = np.vstack([wfc[:3, 3], rays @ wfc[:3, :3].T + wfc[:3, 3]])
    uv, z = project(pts, viewer.intrinsics, viewer.cam_from_world)
    if np.any(~(z > 0)):
        return
    p = [tuple(int(round(c)) for c in q) for q in uv]
    col = (220, 40, 40)
    for i in range(1, 5):
        cv2.line(img, p[0], p[i], col, 1, cv2.LINE_AA)
        cv2.line(img, p[i], p[1 + i % 4], col, 1, cv2.LINE_AA)
