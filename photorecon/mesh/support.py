"""Support removal for object captures: the plane an object stands on (a table, a turntable) found from the
mesh and the cameras, and the support with its rims cut away."""
from __future__ import annotations

import logging

import numpy as np

from ..errors import BadArgumentError
from .geometry import face_areas, face_centres, face_cross, triangle_components

log = logging.getLogger("photorecon")

LOCAL_FIT = 200  # support-plane tries fitted to a surface sample and this many of its nearest neighbours


def fit_plane(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares plane of the points ``Q`` (N >= 3, 3): its unit normal (either sign) and their centre."""
    centre = Q.mean(0)
    return np.linalg.svd(Q - centre, full_matrices=False)[2][2], centre


def ransac_plane(P: np.ndarray, tol: float, iters: int, rng, up: np.ndarray | None = None,
                 max_tilt_deg: float = 90.0, accept=None, normals: np.ndarray | None = None,
                 max_normal_deg: float = 30.0, local: int = 0):
    """(unit normal n, offset c) of the plane n . X = c through three of the points ``P`` (N, 3) that has the
    most points within ``tol``, and that count; with ``up``, only planes whose normal is within
    ``max_tilt_deg`` of it; with ``accept(n, c)``, only planes it returns True for (either sign of n: the
    caller orients); with ``normals`` (N, 3) unit surface normals at the points, only points whose normal is
    within ``max_normal_deg`` of the plane's (either way) count: a flat area, not a curved surface that the
    plane crosses. (None, 0) when no plane qualifies.

    With ``local`` > 0 the search does not rest on luck: every other try is the plane fitted (least squares)
    to one random point and its ``local`` nearest neighbours (three random points all fall on a plane holding
    5% of ``P`` once in 8,000 tries, one point once in 20), and every try with at least half the best count so
    far is refitted to its own inliers while its count grows (LO-RANSAC, Chum et al. 2003): a small patch's
    slightly tilted plane becomes the whole flat area's, and the first refitted plane of a bowed support does
    not shut out a better one found later."""
    best, best_k = None, 0
    min_cos = np.cos(np.radians(max_normal_deg))
    min_up = np.cos(np.radians(max_tilt_deg))
    tree = None
    if local > 0 and len(P) > local:
        from scipy.spatial import cKDTree

        tree = cKDTree(P)

    def inliers(n, c):
        near = np.abs(P @ n - c) < tol
        if normals is not None:
            near &= np.abs(normals @ n) > min_cos
        return near

    def allowed(n, c):
        return ((up is None or abs(n @ up) >= min_up)
                and (accept is None or accept(n, c)))

    for i in range(iters):
        if tree is not None and i % 2:
            n, a = fit_plane(P[tree.query(P[rng.integers(len(P))], k=local + 1)[1]])
        else:
            a, b, c = P[rng.choice(len(P), 3, replace=False)]
            n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-15:
            continue
        n = n / np.linalg.norm(n)
        c = float(n @ a)
        if not allowed(n, c):
            continue
        near = inliers(n, c)
        k = int(near.sum())
        if k > best_k:
            best, best_k = (n, c), k
        if tree is None or k < max(3, best_k // 2):
            continue
        for _ in range(5):  # refit to the inliers while the count grows
            n2, centre = fit_plane(P[near])
            c2 = float(n2 @ centre)
            if not allowed(n2, c2):
                break
            near2 = inliers(n2, c2)
            k2 = int(near2.sum())
            if k2 <= k:
                break
            n, c, near, k = n2, c2, near2, k2
            if k > best_k:
                best, best_k = (n, c), k
    return best, best_k


def _look_at_point(cameras) -> np.ndarray | None:
    """The point nearest (least squares) to every camera's optical axis: what a ring or dome of cameras looks
    at. None without ``View``s, or when the axes are nearly parallel (a forward-facing set)."""
    return axes_point([c for c in cameras if hasattr(c, "cam_from_world")], min_views=2)


def axes_point(views, min_views: int = 3) -> np.ndarray | None:
    """The point nearest (least squares) to the optical axes of ``views``; None with fewer than ``min_views``
    or when the axes are nearly parallel (the smallest eigenvalue of the normal matrix below 5% of the
    largest)."""
    if len(views) < min_views:
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
                       max_below: float = 0.35, iters: int = 1000, sectors: int = 12, min_sectors: int = 6,
                       seed: int = 0):
    """The plane an object stands on, from surface samples ``points`` (N, 3) and the ``cameras`` (Views, or
    camera centres (M, 3)) that photographed it: a RANSAC plane (``ransac_plane`` with neighbourhood tries,
    inliers within ``tol``) with every camera centre strictly on one side, the point the cameras look at
    (``_look_at_point``; else the samples' median) on the cameras' side by more than ``tol`` (a flat object the
    cameras look at is not its own support), at most ``max_below`` of the surface off the plane below it (the
    object stands on it; what lies below is the stand's side, a table's edge, the floor past it, a quarter of
    the surface on real captures, where a plane through the object has half of it or more on the far side), at
    least ``min_fraction`` of the samples on it, and inliers (points within ``tol`` whose surface ``normals``
    (N, 3) are within 30 degrees of the plane's: a flat area, not a curved side the plane cuts) around the foot
    of the look-at point in at least ``min_sectors`` of ``sectors`` directions (a support under the object, not
    a flat face of it or a wall beside it). Refined by least squares on the inliers. Returns (n, c) with n
    towards the cameras (n . X = c on the plane, > c above it), or None."""
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
    best, k = ransac_plane(P, tol, iters, rng, accept=accept, normals=Nrm, local=LOCAL_FIT)
    if best is None or k < min_fraction * len(P):
        return None
    n, c = best
    for _ in range(2):  # least squares on the inliers
        n2, centre = fit_plane(P[(np.abs(P @ n - c) < tol) & (np.abs(Nrm @ n) > flat)])
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
        raise BadArgumentError("--scene object needs the cameras (to tell which side of the table they are on)")
    V = np.asarray(m.vertices)
    T = np.asarray(m.triangles)
    if not len(T):
        return None
    area = face_areas(V, T)
    if not area.sum() > 0:
        return None
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(T), n_samples, p=area / area.sum())
    del area
    r = rng.random((n_samples, 2))
    flip = r.sum(1) > 1
    r[flip] = 1 - r[flip]
    t = V[T[pick]]
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
    h = face_centres(V, T) @ n - c
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
    T = np.asarray(m.triangles)
    V = np.asarray(m.vertices)
    fn = face_cross(V, T)
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
    labels = triangle_components(V, T[idx])[0]
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
    area = face_areas(np.asarray(m.vertices), np.asarray(m.triangles))
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
