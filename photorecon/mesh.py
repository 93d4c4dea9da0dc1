"""Mesh cleaning, simplification, hole filling, cropping and export.

trimesh ``Trimesh`` (with ``process=False``: geometry is never rewritten behind the caller's back) is the
in-memory type; Open3D does the decimation and hole filling, trimesh the GLB/OBJ export.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh

from .errors import BadArgumentError, EmptyMeshError, InputDataError
from .io.atomic import atomic_path

log = logging.getLogger("photorecon")

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")


@dataclass
class CleanConfig:
    """Settings of the cleaning stage."""

    min_component: float | None = field(default=None, metadata={"help": "components below this fraction of the largest's area are dropped when far from it (default: 0.05; grid: off)", "range": (0.0, 1.0)})
    floater_distance: float = field(default=0.05, metadata={"help": "a small component farther than this from the main surface is a floater and dropped; fraction of the scene size", "range": (0.0, 100.0)})
    min_detail: float = field(default=0.002, metadata={"help": "components with less area than this fraction of the largest are dropped wherever they are (debris)", "range": (0.0, 1.0)})
    fill_holes: float = field(default=0.0, metadata={"help": "fill holes up to this radius, scene units (0 = the --fill-holes-voxels default)", "range": (0.0, None)})
    fill_holes_voxels: float = field(default=15.0, metadata={"help": "TSDF meshes: fill holes up to this radius, voxels (0 = off)", "range": (0.0, 100_000.0)})
    target_faces: int = field(default=0, metadata={"help": "quadric decimation to this many faces (0 = off)", "range": (0, 2_000_000_000)})
    cluster_voxel: float = field(default=0.0, metadata={"help": "vertex-clustering simplification cell size, scene units (0 = off)", "range": (0.0, None)})
    crop: tuple[float, ...] | None = field(default=None, metadata={"help": "crop box xmin,ymin,zmin,xmax,ymax,zmax, scene units", "range": (None, None), "length": 6, "box": True, "metavar": "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX"})
    scene: Literal["auto", "object", "open"] = field(default="auto", metadata={"help": "object: remove the table or turntable an object stands on; open: keep the ground; auto: object when the cameras look at one point from around it and a support plane lies under it"})
    object: bool = field(default=False, metadata={"help": "the same as --scene object"})
    object_cut: float = field(default=0.0, metadata={"help": "--object: remove up to this height above the support plane, scene units (0 = the support's fused thickness)", "range": (0.0, None)})


def to_open3d(mesh: trimesh.Trimesh):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
                                  o3d.utility.Vector3iVector(np.asarray(mesh.faces, np.int32)))
    vc = _vertex_colors(mesh)
    if vc is not None:
        m.vertex_colors = o3d.utility.Vector3dVector(vc[:, :3].astype(np.float64) / 255.0)
    return m


def raycasting_scene(mesh: trimesh.Trimesh):
    """An Open3D ``RaycastingScene`` holding ``mesh`` (ray casting, closest points, distances)."""
    import open3d as o3d

    t = o3d.t.geometry.TriangleMesh()
    t.vertex.positions = o3d.core.Tensor(np.asarray(mesh.vertices, np.float32))
    t.triangle.indices = o3d.core.Tensor(np.asarray(mesh.faces, np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(t)
    return scene


def from_open3d(m) -> trimesh.Trimesh:
    colors = None
    if m.has_vertex_colors():
        colors = (np.clip(np.asarray(m.vertex_colors), 0, 1) * 255).astype(np.uint8)
    return trimesh.Trimesh(np.asarray(m.vertices), np.asarray(m.triangles), vertex_colors=colors, process=False)


def _vertex_colors(mesh: trimesh.Trimesh) -> np.ndarray | None:
    if mesh.visual.kind == "vertex":
        return np.asarray(mesh.visual.vertex_colors)
    return None


def clean(mesh: trimesh.Trimesh, cfg: CleanConfig | None = None, cameras=None) -> trimesh.Trimesh:
    """Remove duplicated and degenerate faces, unreferenced vertices, debris and floaters (``drop_floaters``;
    ``cameras``: Views or camera centres (N, 3), the scale of "far"); then optionally crop, fill holes (by
    default, on a TSDF mesh whose ``metadata["voxel_size"]`` is known, those up to ``fill_holes_voxels``
    voxels in radius) and simplify. Scalar metadata (mesher, voxel size, ...) is kept. Raises
    ``EmptyMeshError`` if nothing is left."""
    cfg = cfg or CleanConfig()
    min_component = cfg.min_component
    if min_component is None:
        min_component = 0.0 if mesh.metadata.get("mesher") == "grid" else 0.05
    if not len(mesh.faces):
        raise EmptyMeshError("the mesh has no triangle")
    m = to_open3d(mesh)
    m.remove_duplicated_vertices()
    m.remove_duplicated_triangles()
    m.remove_degenerate_triangles()
    m.remove_unreferenced_vertices()
    if cfg.crop is not None:
        if len(cfg.crop) != 6:
            raise BadArgumentError(f"crop: expected 6 numbers xmin,ymin,zmin,xmax,ymax,zmax, got {len(cfg.crop)}")
        import open3d as o3d

        lo, hi = np.array(cfg.crop[:3]), np.array(cfg.crop[3:])
        if np.any(hi <= lo):
            raise BadArgumentError(f"crop: expected min < max on every axis, got {list(cfg.crop)}")
        m = m.crop(o3d.geometry.AxisAlignedBoundingBox(lo, hi))
    mode = "object" if cfg.object else cfg.scene
    if mode not in ("auto", "object", "open"):
        raise BadArgumentError(f"scene: expected auto, object or open, got {mode!r}")
    scene = {"mode": "open", "detected": "open", "reason": "--scene open", "support_removed": None}
    if mode != "open" and len(m.triangles):
        from .scene import detect_and_remove

        scene = detect_and_remove(m, cameras, mesh.metadata.get("voxel_size"), cfg.object_cut, mode)
    support = scene["support_removed"]
    if len(m.triangles) and min_component > 0:
        drop = floater_mask(m, min_component, cfg.floater_distance, min(cfg.min_detail, min_component), cameras)
        if drop.any():
            m.remove_triangles_by_mask(drop)
            m.remove_unreferenced_vertices()
    if not len(m.triangles):
        raise EmptyMeshError("cleaning left no triangle (everything cropped or in small components)")
    out = from_open3d(m)
    del m  # the Open3D copy: the hole filling makes its own
    hole = cfg.fill_holes
    if not hole > 0 and cfg.fill_holes_voxels > 0 and mesh.metadata.get("voxel_size"):
        hole = cfg.fill_holes_voxels * float(mesh.metadata["voxel_size"])  # the pinholes of a TSDF surface
    if hole > 0:
        out = fill_holes(out, hole)
    out.metadata.update({k: v for k, v in mesh.metadata.items() if isinstance(v, (bool, int, float, str))})
    if support is not None:
        out.metadata.update(support)
    out.metadata["scene"] = scene
    if cfg.cluster_voxel > 0:
        out = from_open3d(to_open3d(out).simplify_vertex_clustering(cfg.cluster_voxel))
    if cfg.target_faces > 0 and len(out.faces) > cfg.target_faces:
        out = simplify(out, cfg.target_faces)
    return out


def triangle_components(V: np.ndarray, T: np.ndarray, block: int = 1 << 20) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of triangles that share an edge (as Open3D's ``cluster_connected_triangles``):
    (per-triangle label (F,), per-component area (C,)). Built from one sorted int64 key per face edge and a
    sparse face graph, a few tens of bytes per face (Open3D's edge map took about 400 per face)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    F = len(T)
    if not F:
        return np.zeros(0, np.int64), np.zeros(0)
    n = int(T.max()) + 1
    keys = np.empty(3 * F, np.int64)
    for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        a, b = T[:, i].astype(np.int64), T[:, j].astype(np.int64)
        keys[k * F:(k + 1) * F] = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(keys, kind="stable")
    same = keys[order[1:]] == keys[order[:-1]]
    del keys
    face = order % F
    del order
    u, v = face[:-1][same].astype(np.int32), face[1:][same].astype(np.int32)  # faces sharing an edge, chained
    del face, same
    graph = coo_matrix((np.ones(len(u), np.int8), (u, v)), shape=(F, F)).tocsr()
    del u, v
    _, labels = connected_components(graph, directed=False)
    del graph
    area = np.empty(F)
    for s in range(0, F, block):
        t = V[T[s:s + block]]
        area[s:s + block] = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    return labels.astype(np.int64), np.bincount(labels, weights=area)


def floater_mask(m, min_component: float, floater_distance: float, min_detail: float, cameras=None) -> np.ndarray:
    """Per triangle of the Open3D mesh ``m``: True where it belongs to debris or a floater.

    Components are connected triangles; their size is their area relative to the largest. The *main surface*
    is every component of at least ``min_component`` of the largest. A smaller component is a floater when
    its gap to the main surface (the nearest pair of vertices) exceeds ``floater_distance`` x the scene
    size: the extent of the main surface (its area-weighted 1-99 percentile box diagonal) or, with
    ``cameras``, the median camera distance to it when that is smaller. Small components within that gap
    are details and kept, unless below ``min_detail`` of the largest (debris)."""
    from scipy.spatial import cKDTree

    labels, areas = triangle_components(np.asarray(m.vertices), np.asarray(m.triangles))
    n = len(areas)
    if n < 2:
        return np.zeros(len(labels), bool)
    rel = areas / areas.max()
    main = rel >= min_component
    drop = rel < min_detail
    small = np.flatnonzero(~main & ~drop)
    if len(small):
        V = np.asarray(m.vertices)
        T = np.asarray(m.triangles)
        main_tris = main[labels]
        main_v = np.unique(T[main_tris])
        # the scene's size: area-weighted triangle centres of the main surface, robust to its own outliers
        tri = V[T[main_tris]]
        centres = tri.mean(1)
        w = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        lo, hi = _weighted_percentile(centres, w, 1), _weighted_percentile(centres, w, 99)
        size = float(np.linalg.norm(hi - lo))
        if cameras is not None and len(cameras):
            cams = np.array([c.center if hasattr(c, "center") else c for c in cameras], float).reshape(-1, 3)
            mid = _weighted_percentile(centres, w, 50)
            size = min(size, float(np.median(np.linalg.norm(cams - mid, axis=1))))
        tree = cKDTree(V[main_v])
        rng = np.random.default_rng(0)
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(n + 1))
        for c in small:
            verts = np.unique(T[order[bounds[c]:bounds[c + 1]]])
            if len(verts) > 2000:
                verts = rng.choice(verts, 2000, replace=False)
            gap = float(tree.query(V[verts], k=1)[0].min())
            if gap > floater_distance * size:
                drop[c] = True
        far = small[drop[small]]
        if len(far):  # a fragment near a kept fragment is kept too: a speckled surface is one piece
            drop[far[_linked(V[T].mean(1), labels, ~drop, far, floater_distance * size)]] = False
    n_drop = int(drop.sum())
    if n_drop:
        log.debug("cleaning: %d of %d components dropped (debris or floaters)", n_drop, n)
    return drop[labels]


def _linked(centres: np.ndarray, labels: np.ndarray, kept: np.ndarray, candidates: np.ndarray, gap: float) -> np.ndarray:
    """Per component in ``candidates``: True when a chain of components (the ``kept`` ones and the candidates),
    each within about ``gap`` of the next (triangle ``centres`` in the same or neighbouring cells of a grid of
    gap / 2: always linked closer than gap / 2, never farther than gap along an axis), reaches a kept one."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(kept)
    use = kept.copy()
    use[candidates] = True
    tri = np.flatnonzero(use[labels])
    cell = np.floor(centres[tri] / (0.5 * gap)).astype(np.int64)
    cell -= cell.min(0)
    dims = cell.max(0) + 3

    def code(c):
        return ((c[:, 0] + 1) * dims[1] + (c[:, 1] + 1)) * dims[2] + (c[:, 2] + 1)

    keys, inv = np.unique(code(cell), return_inverse=True)
    cells = np.unique(cell, axis=0)
    own = np.searchsorted(keys, code(cells))
    rows, cols = [n + inv.ravel()], [labels[tri]]  # a cell and the components in it
    for off in np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T:
        k = code(cells + off)
        j = np.minimum(np.searchsorted(keys, k), len(keys) - 1)
        hit = keys[j] == k
        rows.append(n + own[hit])
        cols.append(n + j[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(n + len(keys),) * 2)
    _, comp = connected_components(graph, directed=False)
    reach = np.zeros(comp.max() + 1, bool)
    reach[comp[:n][kept]] = True
    return reach[comp[candidates]]


def ransac_plane(P: np.ndarray, tol: float, iters: int, rng, up: np.ndarray | None = None,
                 max_tilt_deg: float = 90.0, accept=None, normals: np.ndarray | None = None,
                 max_normal_deg: float = 30.0):
    """(unit normal n, offset c) of the plane n . X = c through three of the points ``P`` (N, 3) that has the
    most points within ``tol``, and that count; with ``up``, only planes whose normal is within
    ``max_tilt_deg`` of it; with ``accept(n, c)``, only planes it returns True for (either sign of n: the
    caller orients); with ``normals`` (N, 3) unit surface normals at the points, only points whose normal is
    within ``max_normal_deg`` of the plane's (either way) count: a flat area, not a curved surface that the
    plane crosses. (None, 0) when no plane qualifies."""
    best, best_k = None, 0
    min_cos = np.cos(np.radians(max_normal_deg))
    for _ in range(iters):
        a, b, c = P[rng.choice(len(P), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-15:
            continue
        n /= np.linalg.norm(n)
        if up is not None and abs(n @ up) < np.cos(np.radians(max_tilt_deg)):
            continue
        if accept is not None and not accept(n, float(n @ a)):
            continue
        near = np.abs(P @ n - n @ a) < tol
        if normals is not None:
            near &= np.abs(normals @ n) > min_cos
        k = int(near.sum())
        if k > best_k:
            best, best_k = (n, float(n @ a)), k
    return best, best_k


def _look_at_point(cameras) -> np.ndarray | None:
    """The point nearest (least squares) to every camera's optical axis: what a ring or dome of cameras looks
    at. None without ``View``s, or when the axes are nearly parallel (a forward-facing set)."""
    views = [c for c in cameras if hasattr(c, "cam_from_world")]
    if len(views) < 2:
        return None
    A, b = np.zeros((3, 3)), np.zeros(3)
    for v in views:
        d = np.asarray(v.cam_from_world, float)[2, :3]  # the optical axis (camera z) in world coordinates
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ v.center
    w = np.linalg.eigvalsh(A)
    if w[0] < 0.05 * w[-1]:
        return None
    return np.linalg.solve(A, b)


def find_support_plane(points: np.ndarray, normals: np.ndarray, cameras, tol: float, min_fraction: float = 0.05,
                       max_below: float = 0.2, iters: int = 1000, sectors: int = 12, min_sectors: int = 6,
                       seed: int = 0):
    """The plane an object stands on, from surface samples ``points`` (N, 3) and the ``cameras`` (Views, or
    camera centres (M, 3)) that photographed it: a RANSAC plane (inliers within ``tol``) with every camera
    centre strictly on one side, the point the cameras look at (``_look_at_point``; else the samples' median)
    on the cameras' side by more than ``tol`` (a flat object the cameras look at is not its own support), at most ``max_below`` of the surface off the plane below it (the object stands on
    it; a plane through the object has much of it on each side), at least ``min_fraction`` of the samples on
    it, and inliers (points within ``tol`` whose surface ``normals`` (N, 3) are within 30 degrees of the
    plane's: a flat area, not a curved side the plane cuts) around the foot of the look-at point in at least ``min_sectors`` of ``sectors`` directions
    (a support under the object, not a flat face of it or a wall beside it). Refined by least squares on the
    inliers. Returns (n, c) with n towards the cameras (n . X = c on the plane, > c above it), or None."""
    P = np.asarray(points, np.float64)
    cams = np.array([c.center if hasattr(c, "center") else c for c in cameras], float).reshape(-1, 3)
    if len(P) < 100 or len(cams) < 2:
        return None
    target = _look_at_point(cameras)
    if target is None:
        target = np.median(P, axis=0)
    rng = np.random.default_rng(seed)
    probe = P[rng.choice(len(P), min(len(P), 5000), replace=False)]

    def accept(n, c):
        h = cams @ n - c
        side = np.sign(np.median(h))
        if side == 0 or not np.all(h * side > tol) or (target @ n - c) * side <= tol:
            return False
        hp = (probe @ n - c) * side
        below, above = int((hp < -tol).sum()), int((hp > tol).sum())
        return below <= max_below * max(below + above, 1)

    Nrm = np.asarray(normals, np.float64)
    flat = np.cos(np.radians(30.0))
    best, k = ransac_plane(P, tol, iters, rng, accept=accept, normals=Nrm)
    if best is None or k < min_fraction * len(P):
        return None
    n, c = best
    for _ in range(2):  # least squares on the inliers
        inl = P[(np.abs(P @ n - c) < tol) & (np.abs(Nrm @ n) > flat)]
        centre = inl.mean(0)
        n2 = np.linalg.svd(inl - centre, full_matrices=False)[2][2]
        n = n2 if n2 @ n >= 0 else -n2
        c = float(n @ centre)
    if np.median(cams @ n - c) < 0:
        n, c = -n, -c
    if not accept(n, c):
        return None
    inl = P[(np.abs(P @ n - c) < tol) & (np.abs(Nrm @ n) > flat)]
    if len(inl) < min_fraction * len(P):
        return None
    foot = target - (target @ n - c) * n
    e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    rel = inl - foot
    ang = np.arctan2(rel @ e2, rel @ e1)
    occupied = np.unique(np.floor((ang + np.pi) / (2 * np.pi) * sectors).astype(int) % sectors)
    if len(occupied) < min_sectors:
        return None
    return n, c


def find_support(m, cameras, voxel: float | None = None, cut: float = 0.0, n_samples: int = 100_000,
                 seed: int = 0):
    """The support plane of the Open3D mesh ``m`` (``find_support_plane``, fitted to ``n_samples`` area-uniform
    surface samples, inliers within 2 voxels, or 1/1000 of the samples' extent without ``voxel``) and the cut
    above it (``cut``; 0: the support's own thickness as fused, 1.25 x the 99th percentile depth of its flat
    samples below the plane, mirrored: nothing of the object lies below it; at least 2 voxels). Returns
    (n, c, cut, drop): the plane n . X = c (n towards the cameras), the cut height and, per triangle, True where
    its centre lies below the cut; or None when there is no such plane. Changes nothing."""
    if cameras is None or not len(cameras):
        raise BadArgumentError("--object needs the cameras (to tell which side of the table they are on)")
    V = np.asarray(m.vertices)
    T = np.asarray(m.triangles)
    if not len(T):
        return None
    tri = V[T]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        return None
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(T), n_samples, p=area / area.sum())
    r = rng.random((n_samples, 2))
    flip = r.sum(1) > 1
    r[flip] = 1 - r[flip]
    t = tri[pick]
    pts = t[:, 0] + r[:, :1] * (t[:, 1] - t[:, 0]) + r[:, 1:] * (t[:, 2] - t[:, 0])
    nrm = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    extent = float(np.linalg.norm(np.percentile(pts, 99, 0) - np.percentile(pts, 1, 0)))
    unit = float(voxel) if voxel else extent / 1000
    tol = 2 * unit
    plane = find_support_plane(pts, nrm, cameras, tol, seed=seed)
    if plane is None:
        return None
    n, c = plane
    if not cut > 0:  # the fused support is not flat (a bowed board, noise): mirror its spread below the plane
        h_pts = pts @ n - c
        under = (h_pts < 0) & (h_pts > -10 * unit) & (np.abs(nrm @ n) > np.cos(np.radians(30.0)))
        spread = float(np.percentile(-h_pts[under], 99)) if under.sum() >= 100 else 0.0
        cut = max(2 * unit, 1.25 * spread)
    h = tri.mean(1) @ n - c
    drop = h < cut
    target = _look_at_point(cameras)
    if target is None:
        target = np.median(pts, axis=0)
    return n, c, float(cut), drop | _support_rims(m, n, h, drop, 0.25 * float(target @ n - c))


def _support_rims(m, n: np.ndarray, h: np.ndarray, below: np.ndarray, max_height: float,
                  max_tilt_deg: float = 30.0) -> np.ndarray:
    """Per triangle of the Open3D mesh ``m``: True on the support's surface that rises above the cut (a bowed or
    warped board, its rims): triangles that face up like the support (normal within ``max_tilt_deg`` of ``n``,
    on the side the support's own flat triangles face), lie less than ``max_height`` above the plane (``h``:
    their heights) and are connected through such triangles to the part ``below`` the cut. An object's sides and
    underside do not face up, so the growth stops at its foot."""
    import open3d as o3d

    T = np.asarray(m.triangles)
    V = np.asarray(m.vertices)
    tri = V[T]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    cos = (fn @ n) / np.maximum(np.linalg.norm(fn, axis=1), 1e-300)
    flat_below = below & (np.abs(cos) > np.cos(np.radians(max_tilt_deg)))
    if not flat_below.any():
        return np.zeros(len(T), bool)
    if np.median(cos[flat_below]) < 0:  # the mesh's faces wound the other way: "up" is -n for them
        cos = -cos
    cand = (cos > np.cos(np.radians(max_tilt_deg))) & (h < max_height)
    idx = np.flatnonzero(cand)
    if not len(idx):
        return np.zeros(len(T), bool)
    sub = o3d.geometry.TriangleMesh(m.vertices, o3d.utility.Vector3iVector(T[idx]))
    labels = np.asarray(sub.cluster_connected_triangles()[0])
    seeds = np.unique(labels[below[idx]])
    out = np.zeros(len(T), bool)
    out[idx[np.isin(labels, seeds)]] = True
    return out & ~below


def remove_support(m, cameras, voxel: float | None = None, cut: float = 0.0, n_samples: int = 100_000,
                   seed: int = 0, found=None, quiet: bool = False) -> dict | None:
    """Object capture: remove from the Open3D mesh ``m`` (in place) the plane the object stands on and every
    triangle whose centre lies below the cut above it (``find_support``, or ``found``, its result for this
    mesh). Logs one line (unless ``quiet``); returns what was removed (metadata: ``support_normal``,
    ``support_offset``, ``support_cut``, ``support_removed_faces``, ``support_removed_area``) or None (logged)
    when no support plane is found."""
    if found is None:
        found = find_support(m, cameras, voxel, cut, n_samples, seed)
    if found is None:
        if not quiet:
            log.info("object: no support plane found (no large flat part of the surface with every camera on one "
                     "side and the object on theirs); nothing removed")
        return None
    n, c, cut, drop = found
    V = np.asarray(m.vertices)
    tri = V[np.asarray(m.triangles)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    removed = float(area[drop].sum())
    total = float(area.sum())
    m.remove_triangles_by_mask(drop)
    m.remove_unreferenced_vertices()
    info = {"support_normal": ",".join(f"{x:.5f}" for x in n), "support_offset": float(c), "support_cut": float(cut),
            "support_removed_faces": int(drop.sum()), "support_removed_area": removed}
    if not quiet:
        log.info("object: support plane %s . X = %.5g found; removed it and everything below %.3g above it: %d "
                 "faces, %.4g of %.4g area (%.0f%%)", info["support_normal"], c, cut, int(drop.sum()), removed,
                 total, 100 * removed / max(total, 1e-300))
    return info


def _weighted_percentile(x: np.ndarray, w: np.ndarray, q: float) -> np.ndarray:
    """Per column of ``x`` (N, D), the ``q``-th percentile with weights ``w`` (N,)."""
    out = np.empty(x.shape[1])
    total = w.sum()
    for j in range(x.shape[1]):
        order = np.argsort(x[:, j])
        cw = np.cumsum(w[order])
        k = min(int(np.searchsorted(cw, q / 100.0 * total)), len(order) - 1)
        out[j] = x[order[k], j]
    return out


def edge_use_counts(faces: np.ndarray) -> np.ndarray:
    """How many faces use each distinct (undirected) edge of ``faces`` (F, 3): one int64 key per face edge,
    sorted in place, no (E, 2) edge arrays (a few bytes per face edge on a mesh of millions of faces)."""
    F = np.asarray(faces)
    if not len(F):
        return np.zeros(0, np.int64)
    n = int(F.max()) + 1
    m = len(F)
    keys = np.empty(3 * m, np.int64)
    for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        a, b = F[:, i].astype(np.int64), F[:, j].astype(np.int64)
        keys[k * m:(k + 1) * m] = np.minimum(a, b) * n + np.maximum(a, b)
    keys.sort()
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    return np.diff(np.r_[starts, len(keys)])


def boundary_edges(mesh: trimesh.Trimesh) -> int:
    """Number of edges used by exactly one face (the rims of holes; 0 for a closed surface)."""
    return int((edge_use_counts(mesh.faces) == 1).sum())


def simplify(mesh: trimesh.Trimesh, target_faces: int) -> trimesh.Trimesh:
    """Quadric error decimation to about ``target_faces`` triangles, vertex colours carried.

    MeshLab's quadric edge collapse (pymeshlab) where installed: optimal vertex placement, collapses that would
    flip a face's normal or leave a needle triangle refused; it keeps sharp edges and thin
    walls where Open3D's decimation (the fallback) folds them. Texturing the room scene's fused mesh at 30,000
    faces (tools/bench_texture.py): 27.5 dB against 26.9 dB with Open3D's decimation."""
    if target_faces < 4:
        raise BadArgumentError(f"target faces: expected >= 4, got {target_faces}")
    try:
        import pymeshlab
    except ImportError:  # pymeshlab is an optional extra (GPL-3): Open3D as the fallback
        return from_open3d(to_open3d(mesh).simplify_quadric_decimation(int(target_faces)))
    V = np.asarray(mesh.vertices, np.float64)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=np.asarray(mesh.faces, np.int32)))
    # every parameter given: pymeshlab keeps a filter's parameters from one call to the next within a process. Not
    # preserveboundary: with it, a fused mesh with many small holes came out torn (F-score 0.11 vs 0.999 without)
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(target_faces), qualitythr=0.3, preserveboundary=False,
                                                boundaryweight=1.0, preservetopology=False, planarquadric=False,
                                                planarweight=0.001, qualityweight=False, selected=False, targetperc=0.0,
                                                preservenormal=True, optimalplacement=True, autoclean=True)
    out = ms.current_mesh()
    V2 = out.vertex_matrix()
    colors = _vertex_colors(mesh)
    vc = None
    if colors is not None and len(colors) == len(V) and len(V2):
        # each new vertex: the mean colour of the old vertices nearest to it (the area it stands for), as
        # Open3D's decimation averages the colours of the vertices it merges
        from scipy.spatial import cKDTree

        _, j = cKDTree(V2).query(V, k=1)
        n = np.bincount(j, minlength=len(V2))
        acc = np.stack([np.bincount(j, np.asarray(colors, np.float64)[:, c], minlength=len(V2)) for c in range(3)], 1)
        # a vertex no old one is nearest to (rare): its nearest old vertex's colour
        _, k = cKDTree(V).query(V2[n == 0], k=1)
        acc[n == 0] = np.asarray(colors, np.float64)[k, :3]
        vc = np.clip(acc / np.maximum(n, 1)[:, None] + 0.5, 0, 255).astype(np.uint8)
    return trimesh.Trimesh(V2, out.face_matrix(), vertex_colors=vc, process=False)


def harmonic_fill(n_vertices: int, edges: np.ndarray, known: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Values (n_vertices, C) on a graph's nodes (a mesh's vertices, or its faces with ``face_adjacency``):
    ``values`` (k, C) at the nodes ``known`` (k,) kept, the others the solution of the (uniform-weight) Laplace
    equation over ``edges`` (E, 2): each unknown node is the mean of its neighbours, so values diffuse
    smoothly from the known ones (a hole patch's colour blends its rim's instead of copying the nearest rim
    point's). Unknown nodes not connected to a known one get the known values' mean (0 without any)."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import spsolve

    values = np.asarray(values, np.float64).reshape(len(known), -1)
    out = np.empty((n_vertices, values.shape[1]))
    out[:] = values.mean(0) if len(values) else 0.0
    out[known] = values
    e = np.asarray(edges, np.int64).reshape(-1, 2)
    is_known = np.zeros(n_vertices, bool)
    is_known[known] = True
    if is_known.all() or not len(e) or not len(known):
        return out
    e = np.vstack([e, e[:, ::-1]])
    A = sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n_vertices, n_vertices)).tocsr()
    A.data[:] = 1.0
    # only unknown vertices in a component with a known one are solvable
    _, comp = connected_components(A, directed=False)
    reach = np.isin(comp, np.unique(comp[is_known]))
    free = np.flatnonzero(~is_known & reach)
    if not len(free):
        return out
    L = (sparse.diags(np.asarray(A.sum(1)).ravel()) - A).tocsr()
    fixed = np.flatnonzero(is_known)
    rhs = -(L[free][:, fixed] @ out[fixed])
    sol = spsolve(L[free][:, free].tocsc(), rhs)
    out[free] = np.asarray(sol).reshape(len(free), -1)
    return out


def fill_holes(mesh: trimesh.Trimesh, hole_size: float) -> trimesh.Trimesh:
    """Close holes that fit in a sphere of radius ``hole_size`` (scene units; Open3D's tensor ``fill_holes``,
    VTK's vtkFillHolesFilter)."""
    import open3d as o3d

    t = o3d.t.geometry.TriangleMesh.from_legacy(to_open3d(mesh))
    filled = t.fill_holes(hole_size=float(hole_size)).to_legacy()
    out = from_open3d(filled)
    return out if len(out.faces) >= len(mesh.faces) else mesh


MESH_FORMATS = ("ply", "obj", "glb")


def parse_formats(text: str) -> tuple[str, ...]:
    """``"ply,glb"`` -> ("ply", "glb"); raises ``BadArgumentError`` for an empty list or an unknown format."""
    formats = tuple(f.strip().lower() for f in text.split(",") if f.strip())
    if not formats or any(f not in MESH_FORMATS for f in formats):
        raise BadArgumentError(f"--formats: expected ply, obj and/or glb, got {text!r}")
    return formats


def export(mesh: trimesh.Trimesh, path: str | Path) -> Path:
    """Write PLY (binary, vertex colours), OBJ or GLB by suffix, atomically."""
    path = Path(path)
    suf = path.suffix.lower()
    if suf[1:] not in MESH_FORMATS:
        raise BadArgumentError(f"{path}: unsupported mesh format; expected .ply, .obj or .glb")
    if not len(mesh.faces):
        raise EmptyMeshError(f"{path}: refusing to write an empty mesh")
    with atomic_path(path) as tmp:
        if suf == ".ply":
            data = trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=False)
            Path(tmp).write_bytes(data)
        else:
            mesh.export(tmp, file_type=suf[1:])
    return path


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """Load a mesh file as one ``Trimesh`` (scenes are concatenated), keeping texture/vertex colours.

    Raises ``InputDataError`` naming the file when it is missing, unreadable or has no faces.
    """
    path = Path(path)
    if not path.is_file():
        raise InputDataError(f"{path}: no such mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputDataError(f"{path}: unsupported mesh format {path.suffix!r}; expected one of {MESH_SUFFIXES}")
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InputDataError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)] if loaded.geometry else []
        loaded = trimesh.util.concatenate(geoms) if geoms else None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputDataError(f"{path}: the mesh has no faces; a triangle mesh is needed to render")
    return loaded
