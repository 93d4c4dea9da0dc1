"""Oriented points from depth frames (for Poisson), the observed points thinned on a grid, and
``surface_report``: how much of a mesh's area is *invented*, farther than two cells from every observed point.
"""
from __future__ import annotations

import numpy as np
import trimesh

from ..cameras import backproject_depth, camera_center
from ..errors import NoDepthError
from ..progress import bar
from ..mesh.clean import edge_use_counts
from .config import DepthFrame
from .frames import nonempty, pixel_footprint
from .grid import _cell_keys


# --- screened Poisson --------------------------------------------------------------------------------------
def oriented_points(frame: DepthFrame, max_stretch: float = 8.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points (N, 3) of a depth map's valid pixels, their unit normals (N, 3), turned toward the
    camera, and the (H, W) mask of the pixels they come from. Normals: the frame's own (``frame.normal``, camera frame, e.g. PatchMatch's) where non-zero, else
    the cross product of the central differences to the pixel's four neighbours; a pixel whose neighbours
    are missing or farther than ``max_stretch`` pixel footprints (a depth discontinuity) is left out."""
    d = frame.depth
    H, W = d.shape
    intr, T = frame.view.intrinsics, frame.view.cam_from_world
    valid = d > 0
    grid = np.zeros((H, W, 3))
    grid[valid] = backproject_depth(d, intr, T)
    ok = np.zeros((H, W), bool)
    normals = np.zeros((H, W, 3))
    if frame.normal is not None:
        n_cam = np.asarray(frame.normal, np.float64)
        given = valid & (np.abs(n_cam).sum(-1) > 0.5)
        normals[given] = n_cam[given] @ T[:3, :3]  # camera -> world: R^T n, as row vectors n @ R
        ok |= given
    if H >= 3 and W >= 3:
        c = (slice(1, -1), slice(1, -1))
        dx = grid[1:-1, 2:] - grid[1:-1, :-2]
        dy = grid[2:, 1:-1] - grid[:-2, 1:-1]
        lim = (2 * max_stretch * d[c] / min(intr.fx, intr.fy)) ** 2
        near = (valid[c] & valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1]
                & ((dx ** 2).sum(-1) < lim) & ((dy ** 2).sum(-1) < lim))
        fill = near & ~ok[c]
        normals[c][fill] = np.cross(dx[fill], dy[fill])
        ok[c] |= fill
    P, N = grid[ok], normals[ok]
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-30)
    away = np.einsum("nc,nc->n", N, P - camera_center(T)) > 0
    N[away] *= -1
    return P, N, ok


def _point_cloud(frames: list[DepthFrame], spacing: float, with_normals: bool = True):
    """The frames' points (oriented, with colours where the frames have them) in one Open3D cloud, thinned to
    one point per ``spacing`` cell (points, normals and colours averaged per cell)."""
    import open3d as o3d

    pts, nrm, col = [], [], []
    for f in bar(frames, desc="oriented points"):
        if with_normals:
            P, N, ok = oriented_points(f)
        else:
            P, N, ok = backproject_depth(f.depth, f.view.intrinsics, f.view.cam_from_world), None, None
        if not len(P):
            continue
        # thin each view first (a voxel grid of the same cell), so all views' points never sit in memory at once
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
        if N is not None:
            pc.normals = o3d.utility.Vector3dVector(N)
        if f.color is not None and ok is not None:
            pc.colors = o3d.utility.Vector3dVector(f.color[ok].astype(np.float64) / 255.0)
        pc = pc.voxel_down_sample(spacing)
        pts.append(np.asarray(pc.points))
        if N is not None:
            nrm.append(np.asarray(pc.normals))
        if pc.has_colors():
            col.append(np.asarray(pc.colors))
    if not pts or sum(len(p) for p in pts) < 10:
        raise NoDepthError("fewer than 10 usable depth points (with normals) in all views: nothing to mesh")
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate(pts)))
    if nrm:
        cloud.normals = o3d.utility.Vector3dVector(np.concatenate(nrm))
    if len(col) == len(pts):
        cloud.colors = o3d.utility.Vector3dVector(np.concatenate(col))
    cloud = cloud.voxel_down_sample(spacing)
    if nrm:  # averaged normals: back to unit length
        n = np.asarray(cloud.normals)
        cloud.normals = o3d.utility.Vector3dVector(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30))
    return cloud


def _observed_per_view(frames: list[DepthFrame], spacing: float):
    """Per view, the points it adds to ``observed_points`` (those in cells no earlier view filled)."""
    cell = spacing / 2
    keys = np.zeros(0, np.int64)  # sorted: the cells filled so far
    for f in frames:
        z = f.depth[f.depth > 0]
        if not z.size:
            continue
        step = max(1, int(spacing / (float(np.median(z)) / f.view.intrinsics.fx)))
        del z
        sub = np.zeros_like(f.depth)
        sub[::step, ::step] = f.depth[::step, ::step]
        p = backproject_depth(sub, f.view.intrinsics, f.view.cam_from_world)
        del sub
        k, first = np.unique(_cell_keys(p, cell), return_index=True)  # each cell's first point in this view
        j = np.minimum(np.searchsorted(keys, k), max(len(keys) - 1, 0))
        new = keys[j] != k if len(keys) else np.ones(len(k), bool)
        k, first = k[new], first[new]
        if len(k):
            yield p[first]
            keys = np.concatenate([keys, k])
            keys.sort(kind="stable")


def observed_points(frames: list[DepthFrame], spacing: float) -> np.ndarray:
    """The depth maps' world points, every k-th pixel in both directions so that neighbours lie about
    ``spacing`` apart on the surface each camera looks at: what the cameras observed. Views that see the same
    surface add no points there: one point per cell of ``spacing / 2`` is kept (the first view's), so the
    count follows the observed area, not the number of views. Ordered by view, then by cell."""
    parts = list(_observed_per_view(frames, spacing))
    return np.concatenate(parts) if parts else np.zeros((0, 3))


def observed_distance(frames: list[DepthFrame], spacing: float, points: np.ndarray, upper: float) -> np.ndarray:
    """For each of ``points`` (N, 3), the distance to the nearest of ``observed_points(frames, spacing)``, inf
    where none lies within ``upper``: the same numbers as a KD-tree of all the observed points, found one view's
    points at a time (the observed points are never all in memory)."""
    from scipy.spatial import cKDTree

    dist = np.full(len(points), np.inf)
    for p in _observed_per_view(frames, spacing):
        d, _ = cKDTree(p).query(points, k=1, distance_upper_bound=upper)
        np.minimum(dist, d, out=dist)
    return dist


def surface_report(mesh: trimesh.Trimesh, frames: list[DepthFrame], n_samples: int = 50_000) -> dict:
    """Watertightness (trimesh ``is_watertight``, boundary edges) and the *invented* fraction of a mesh's area:
    area-uniform samples farther than ``invent_distance`` from every observed depth point. The distance is two
    cells of the mesher (Poisson octree cell, TSDF voxel), at least three pixel footprints."""
    frames = nonempty(frames)
    footprint = pixel_footprint(frames)
    cell = float(mesh.metadata.get("poisson_cell") or mesh.metadata.get("voxel_size") or 0.0)
    tau = max(2 * cell, 3 * footprint)
    pts = _area_samples(np.asarray(mesh.vertices), np.asarray(mesh.faces), n_samples)
    dist = observed_distance(frames, tau / 2, pts, tau)
    counts = edge_use_counts(mesh.faces)
    return {"watertight": bool(len(counts) and (counts == 2).all()), "boundary_edges": int((counts == 1).sum()),
            "invented_fraction": float(np.mean(~np.isfinite(dist))), "invent_distance": tau}


def _area_samples(V: np.ndarray, F: np.ndarray, n: int, seed: int = 0, block: int = 1 << 20) -> np.ndarray:
    """``n`` area-uniform points on the triangles (V, F), the face areas computed a block of faces at a time
    (no per-face triangle array of the whole mesh)."""
    area = np.empty(len(F))
    for s in range(0, len(F), block):
        t = V[F[s:s + block]]
        area[s:s + block] = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    cum = np.cumsum(area)
    face = np.minimum(np.searchsorted(cum, rng.random(n) * cum[-1]), len(F) - 1)
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    t = V[F[face]]
    return t[:, 0] * (1 - r1)[:, None] + t[:, 1] * (r1 * (1 - r2))[:, None] + t[:, 2] * (r1 * r2)[:, None]
