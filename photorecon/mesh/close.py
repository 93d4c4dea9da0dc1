"""The watertight companion of an object's cleaned mesh (``mesh_closed.ply``): every hole filled (``close_mesh``:
patches from ``mesh.patch``, kept above the support plane), or, for an object whose surface came out in pieces (a
dark, rough one: its largest piece under 90% of the area), one screened Poisson surface through them
(``poisson_closed``): closing each piece on its own would give a heap of closed crumbs.
"""
from __future__ import annotations

import logging

import numpy as np
import trimesh

from ..arrays import isin, unique_sorted
from .boundary import boundary_directed, boundary_loops, support_floor
from .convert import largest_piece, poisson_surface, raycasting_scene
from .geometry import edge_keys, face_areas, face_edge_keys, face_edges, triangle_components
from .patch import _colors, _drop_overused, _mark, _subset, fill_loops, filled_area

log = logging.getLogger("photorecon")


def close_mesh(mesh: trimesh.Trimesh, floor=None, rounds: int = 4) -> trimesh.Trimesh:
    """A watertight companion of ``mesh``: every hole filled (``fill_loops``, new vertices kept above the
    ``floor`` plane (n, c) when given: an object's support; from the second round, rims that reopened are
    closed by fans around a new centre vertex). Edges used by more than two faces, or run the same way by two,
    lose the faces added last (``_drop_overused``), and components that stay open after ``rounds`` are dropped when the
    closed ones hold most of the surface. ``is_watertight`` tells whether it worked."""
    out = _drop_overused(mesh)
    for r in range(rounds):
        loops = boundary_loops(out.faces, len(out.vertices))
        if not loops:
            break
        # from the second round the rims left are those whose ear clipping repeated an edge: fans
        out = _drop_overused(fill_loops(out, loops, floor=floor, fan=r > 0)[0], new_from=len(out.faces))
    if not out.is_watertight:
        out = _closed_components(out)
    return out

def _closed_components(mesh: trimesh.Trimesh, min_share: float = 0.5) -> trimesh.Trimesh:
    """The components of ``mesh`` that are closed (every edge used by two faces), when they hold at least
    ``min_share`` of its area (else ``mesh`` as it is: the object itself stayed open, and a closed crumb is not
    its companion)."""
    F = np.asarray(mesh.faces, np.int64)
    labels, _ = triangle_components(np.asarray(mesh.vertices), F)
    e = boundary_directed(F, len(mesh.vertices))
    if not len(e):
        return mesh
    n = len(mesh.vertices)
    open_face = isin(face_edge_keys(F, n), edge_keys(e[:, 0], e[:, 1], n)).reshape(3, -1).any(0)
    open_comp = unique_sorted(labels[open_face])
    keep = ~isin(labels, open_comp)
    area = face_areas(np.asarray(mesh.vertices, np.float64), F)
    if not keep.any() or area[keep].sum() < min_share * area.sum():
        return mesh
    return _subset(mesh, keep)

def main_share(mesh: trimesh.Trimesh) -> float:
    """The share of ``mesh``'s area in its largest connected piece (faces joined by edges)."""
    V, F = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    if not len(F):
        return 0.0
    labels, _ = triangle_components(V, F)
    area = np.bincount(labels, face_areas(V, F))
    return float(area.max() / max(area.sum(), 1e-300))

def poisson_closed(mesh: trimesh.Trimesh, floor=None) -> trimesh.Trimesh:
    """One closed surface through an object's surface pieces: screened Poisson (Open3D) over ``mesh``'s
    vertices with their normals, at an octree cell of about two of its median edges, the largest piece kept,
    vertices below the ``floor`` plane (n, c) moved onto it; colours from the nearest vertex of ``mesh``; vertices
    farther than a cell from its surface (and faces with two such vertices) marked ``filled``. For an object whose
    surface came out in pieces, which ``close_mesh`` would close one by one into crumbs."""
    import open3d as o3d
    import open3d.core as o3c
    from scipy.spatial import cKDTree

    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    used = unique_sorted(F)
    e = face_edges(F)
    edge = float(np.median(np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1)))
    N = np.asarray(mesh.vertex_normals, np.float64)[used]
    good = np.isfinite(N).all(1) & (np.linalg.norm(N, axis=1) > 0.5)  # a vertex of degenerate faces has none
    used, N = used[good], N[good]
    P = V[used]
    extent = float((P.max(0) - P.min(0)).max()) * 1.1  # Open3D's octree: the points' cube, scale 1.1
    depth = int(np.clip(np.ceil(np.log2(extent / (2 * edge))), 5, 10))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    cloud.normals = o3d.utility.Vector3dVector(N)
    out = largest_piece(poisson_surface(cloud, depth)[0], manifold=True)
    X = np.asarray(out.vertices, np.float64).copy()
    if floor is not None:
        n, c = floor
        below = X @ n < c
        X[below] -= np.outer(X[below] @ n - c, n)
    cell = extent / 2 ** depth
    _, near = cKDTree(P).query(X, k=1)
    dist = raycasting_scene(mesh).compute_distance(o3c.Tensor(X.astype(np.float32))).numpy()
    colors = _colors(mesh)
    out = trimesh.Trimesh(X, out.faces, vertex_colors=None if colors is None else np.asarray(colors)[used][near],
                          process=False)
    if out.volume < 0:
        out.invert()
    vf = (dist > cell).astype(np.uint8)
    _mark(out, vf, (vf[np.asarray(out.faces)].sum(1) >= 2).astype(np.uint8))
    out.metadata.update(mesh.metadata)
    if not out.is_watertight:  # rims where the octree's box cut the surface
        out = close_mesh(out, floor=floor)
    log.info("closed mesh: the object's surface is in pieces; screened Poisson over its %d vertices (depth %d)",
             len(P), depth)
    return out

def closed_companion(mesh: trimesh.Trimesh, min_share: float = 0.9) -> tuple[trimesh.Trimesh, dict]:
    """The watertight companion of an object's cleaned mesh and its facts: ``watertight``, ``filled_area``
    (every patch: the cleaning's and this one's), ``faces``, ``vertices``, ``method``. ``close_mesh`` (the
    observed surface kept, the patch over the support side kept above the support plane when the mesh's metadata
    holds one), unless its largest piece holds less than ``min_share`` of its area: then ``poisson_closed``
    (closing each piece would give a heap of closed crumbs, not the object)."""
    floor = support_floor(mesh.metadata)
    share = main_share(mesh)
    if share >= min_share:
        closed, method = close_mesh(mesh, floor=floor), "holes"
    else:
        closed, method = poisson_closed(mesh, floor=floor), "poisson"
    info = {"watertight": bool(closed.is_watertight), "filled_area": filled_area(closed),
            "vertices": len(closed.vertices), "faces": len(closed.faces), "method": method,
            "main_piece_share": round(share, 4)}
    if not info["watertight"]:
        log.warning("closed mesh: %d boundary edges left after filling every hole (edges used by more than two "
                    "faces, or rims that cross themselves); written anyway", len(boundary_directed(closed.faces)))
    return closed, info
