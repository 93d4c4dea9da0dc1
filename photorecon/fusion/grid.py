"""Grid meshing (the original article's mesher, done right): depth frames in, one mesh out.

Every valid 2x2 pixel quad of a view gives an upper-left and a lower-right triangle; triangles across depth
discontinuities are rejected by a scale-free test (edge length relative to the pixel footprint ``z / f``);
per-view meshes are then merged into one surface by voxel ownership (each small cell of space keeps the
triangles of the one view that sees it best, so overlapping shells are dropped) and near-duplicate vertices
are welded.
"""
from __future__ import annotations

import logging

from dataclasses import dataclass

import numpy as np
import trimesh

from ..arrays import row_keys, unique_sorted
from ..cameras import backproject_depth, camera_center
from ..errors import EmptyMeshError, NoDepthError
from ..progress import bar
from .config import DepthFrame, FusionConfig

log = logging.getLogger("photorecon")


# --- grid meshing --------------------------------------------------------------------------------------------
@dataclass
class _GridPatch:
    points: np.ndarray  # (V, 3) world
    tris: np.ndarray  # (F, 3) indices into points
    colors: np.ndarray | None  # (V, 3) uint8


def _grid_triangles(frame: DepthFrame, max_stretch: float | None) -> _GridPatch:
    """Triangulate a view's pixel grid: quad (r, c) -> upper-left (TL, BL, TR) and lower-right (TR, BL, BR).

    A triangle is kept when all three pixels have depth and, with ``max_stretch``, every edge is shorter
    than ``max_stretch`` pixel footprints (``z_min / f``): scale-free, so it works in any SfM scale.
    """
    view, d = frame.view, frame.depth
    H, W = d.shape
    pts = backproject_depth(d, view.intrinsics, view.cam_from_world)
    valid = d > 0
    index = np.full((H, W), -1, np.int64)
    index[valid] = np.arange(len(pts))
    tl, tr, bl, br = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    tris = np.concatenate([np.stack([tl, bl, tr], -1).reshape(-1, 3), np.stack([tr, bl, br], -1).reshape(-1, 3)])
    tris = tris[(tris >= 0).all(1)]
    if len(tris) and max_stretch is not None:
        zv = d[valid].astype(np.float64)
        P = pts[tris]
        e2 = np.maximum.reduce([((P[:, 0] - P[:, 1]) ** 2).sum(1), ((P[:, 1] - P[:, 2]) ** 2).sum(1),
                                ((P[:, 2] - P[:, 0]) ** 2).sum(1)])
        footprint = zv[tris].min(1) / min(view.intrinsics.fx, view.intrinsics.fy)
        # the diagonal edge spans sqrt(2) pixels
        tris = tris[e2 <= (max_stretch * np.sqrt(2) * footprint) ** 2]
    colors = frame.color[valid] if frame.color is not None else None
    return _GridPatch(pts, tris, colors)


def grid_mesh_view(frame: DepthFrame, max_stretch: float | None = 8.0) -> trimesh.Trimesh:
    """One view's grid mesh (see ``_grid_triangles``) as a ``Trimesh``."""
    p = _grid_triangles(frame, max_stretch)
    m = trimesh.Trimesh(p.points, p.tris, vertex_colors=p.colors, process=False)
    m.remove_unreferenced_vertices()
    return m


def _cell_keys(points: np.ndarray, cell: float) -> np.ndarray:
    """``row_keys`` of the cells of size ``cell`` that ``points`` fall in."""
    return row_keys(np.floor(points / cell))


def grid_fuse(frames: list[DepthFrame], cfg: FusionConfig) -> trimesh.Trimesh:
    """Grid-mesh every view and merge them into one surface.

    Overlapping shells are dropped by *voxel ownership*: space is cut into cells of 4 pixel footprints; each
    cell keeps only the triangles of the view that sees it best (most fronto-parallel, closest). Vertices
    that coincide after rounding to 1/20 of a cell are welded.
    """
    patches, quality, footprints = [], [], []
    for f in bar(frames, desc="grid meshing"):
        p = _grid_triangles(f, cfg.max_stretch)
        if not len(p.tris):
            log.warning("view %s: no valid triangle in its depth map; skipped", f.view.name)
            continue
        c = camera_center(f.view.cam_from_world)
        T = p.points[p.tris]
        n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        ray = T.mean(1) - c
        dist = np.linalg.norm(ray, axis=1)
        patches.append((p, T.mean(1)))
        quality.append(np.abs(np.einsum("nc,nc->n", n, ray)) / np.maximum(dist, 1e-12) ** 2)
        footprints.append(np.median(dist) / f.view.intrinsics.fx)
    if not patches:
        raise NoDepthError("no view produced a single valid triangle: nothing to fuse")
    cell = 4.0 * float(np.median(footprints))
    keys = np.concatenate([_cell_keys(centroids, cell) for _, centroids in patches])
    q = np.concatenate(quality)
    owner = np.concatenate([np.full(len(qq), k) for k, qq in enumerate(quality)])
    uniq, inv = np.unique(keys, return_inverse=True)
    order = np.lexsort((-q, inv))  # per cell, best quality first
    first = np.ones(len(order), bool)
    first[1:] = inv[order][1:] != inv[order][:-1]
    cell_owner = np.empty(len(uniq), np.int64)
    cell_owner[inv[order][first]] = owner[order][first]
    keep = owner == cell_owner[inv]
    verts, faces, cols, offset, start = [], [], [], 0, 0
    for (p, _), qq in zip(patches, quality):
        sel = keep[start:start + len(qq)]
        start += len(qq)
        t = p.tris[sel]
        used = unique_sorted(t)
        remap = np.full(len(p.points), -1, np.int64)
        remap[used] = np.arange(len(used)) + offset
        verts.append(p.points[used])
        faces.append(remap[t])
        if p.colors is not None:
            cols.append(p.colors[used])
        offset += len(used)
    V = np.concatenate(verts)
    F = np.concatenate(faces)
    # weld: vertices closer than cell / 20 (patch borders) become one
    _, first_idx, vmap = np.unique(np.round(V / (cell / 20)).astype(np.int64), axis=0, return_index=True,
                                   return_inverse=True)
    F = vmap.ravel()[F]
    V = V[first_idx]
    C = np.concatenate(cols)[first_idx] if len(cols) == len(patches) else None
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    if not len(F):
        raise EmptyMeshError("grid meshing left no triangle")
    merged = trimesh.Trimesh(V, F, vertex_colors=C, process=False)
    merged.metadata["cell_size"] = cell
    merged.metadata["mesher"] = "grid"
    return merged
