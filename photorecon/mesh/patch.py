"""Patches over holes: each given rim (``mesh.boundary``) triangulated by ear clipping in its best-fit plane (the
shortest diagonal first, never a diagonal that is already an edge of the mesh), the patch's edges longer than
the rim's split (midpoints; the rim's own edges never, so no observed face gets a T-junction) and the new
vertices solving the bi-Laplace equation (uniform weights) with the surface around them fixed: the patch
continues the surface's slope across the rim (Liepa, "Filling holes in meshes", SGP 2003), where a membrane
would cut flat across it. The surface's own vertices and faces stay as they are.

What a patch adds is marked: ``vertex_attributes["filled"]`` (1 on a patch's new vertices, 0 elsewhere) and
``face_attributes["filled"]`` (1 on patch faces), written to PLY as ``filled`` properties.
"""
from __future__ import annotations

import logging

import numpy as np
import trimesh

from ..arrays import isin, unique_sorted
from ..jit import njit
from .boundary import hole_stats
from .geometry import edge_keys, face_areas, face_edge_keys, face_edges
from .solve import harmonic_fill, solve_spd, uniform_laplacian

log = logging.getLogger("photorecon")

MAX_FILL_FACES = 20_000  # about the most faces a patch over one hole gets (fill_loops' max_faces)


@njit(cache=True)
def _diagonal(P3, idx, k, m):
    """3D length of the diagonal that cutting corner ``k`` of the ``m`` corners ``idx`` would leave."""
    a, c = idx[(k - 1) % m], idx[(k + 1) % m]
    return np.sqrt(((P3[a] - P3[c]) ** 2).sum())

@njit(cache=True)
def _ear_clip(xy, P3, chords, max_tries=48):
    """Ear clipping of the simple polygon ``xy`` (n, 2) (3D corners ``P3`` (n, 3)): at each step the ear with the
    shortest diagonal (3D) among those that are convex and hold no other corner; a diagonal whose local key
    (i * n + j, i < j) is in the sorted ``chords`` (an existing edge of the mesh) is never cut. Without such an
    ear among the ``max_tries`` shortest diagonals (a rim whose projection folds over itself) the convex corner,
    else any corner, with the shortest allowed diagonal among them. Returns (n - 2, 3) local corner indices, wound like the polygon."""
    n = xy.shape[0]
    out = np.empty((max(n - 2, 0), 3), np.int64)
    idx = np.arange(n)
    area = 0.0
    for i in range(n):
        j = (i + 1) % n
        area += xy[i, 0] * xy[j, 1] - xy[j, 0] * xy[i, 1]
    sgn = 1.0 if area >= 0 else -1.0
    m = n
    t = 0
    # each corner's diagonal length, kept up to date as ears go (only the two corners beside an ear change)
    d = np.empty(n)
    for k in range(n):
        d[k] = _diagonal(P3, idx, k, n)
    tried = np.zeros(n, np.bool_)
    tl = np.empty(max_tries, np.int64)
    while m > 3:
        pick, fallback_convex, fallback_any = -1, -1, -1
        nt = 0
        for q in range(min(m, max_tries)):  # a long rim whose projection folds: bounded work per ear
            k = -1  # the shortest diagonal not tried yet
            bd = np.inf
            for r in range(m):
                if not tried[r] and d[r] < bd:
                    bd = d[r]
                    k = r
            tried[k] = True
            tl[nt] = k
            nt += 1
            a, b, c = idx[(k - 1) % m], idx[k], idx[(k + 1) % m]
            lo, hi = min(a, c), max(a, c)
            key = lo * n + hi
            s = np.searchsorted(chords, key)
            if s < chords.shape[0] and chords[s] == key:
                continue
            if fallback_any < 0:
                fallback_any = k
            ux, uy = xy[b, 0] - xy[a, 0], xy[b, 1] - xy[a, 1]
            vx, vy = xy[c, 0] - xy[b, 0], xy[c, 1] - xy[b, 1]
            cr = (ux * vy - uy * vx) * sgn
            if cr <= 0:
                continue
            if fallback_convex < 0:
                fallback_convex = k
            inside = False
            for r in range(m):
                p = idx[r]
                if p == a or p == b or p == c:
                    continue
                px, py = xy[p, 0], xy[p, 1]
                d1 = ((xy[b, 0] - xy[a, 0]) * (py - xy[a, 1]) - (xy[b, 1] - xy[a, 1]) * (px - xy[a, 0])) * sgn
                d2 = ((xy[c, 0] - xy[b, 0]) * (py - xy[b, 1]) - (xy[c, 1] - xy[b, 1]) * (px - xy[b, 0])) * sgn
                d3 = ((xy[a, 0] - xy[c, 0]) * (py - xy[c, 1]) - (xy[a, 1] - xy[c, 1]) * (px - xy[c, 0])) * sgn
                if d1 >= 0 and d2 >= 0 and d3 >= 0:
                    inside = True
                    break
            if not inside:
                pick = k
                break
        for q in range(nt):
            tried[tl[q]] = False
        if pick < 0:
            pick = fallback_convex if fallback_convex >= 0 else (fallback_any if fallback_any >= 0 else tl[0])
        out[t, 0], out[t, 1], out[t, 2] = idx[(pick - 1) % m], idx[pick], idx[(pick + 1) % m]
        t += 1
        for k in range(pick, m - 1):
            idx[k] = idx[k + 1]
            d[k] = d[k + 1]
        m -= 1
        for k in ((pick - 1) % m, pick % m):  # the ear's two neighbours, now next to each other
            d[k] = _diagonal(P3, idx, k, m)
    if m == 3:
        out[t, 0], out[t, 1], out[t, 2] = idx[0], idx[1], idx[2]
    return out

def _triangulate(V: np.ndarray, loop: np.ndarray, normal: np.ndarray, edge_set: set | None) -> np.ndarray:
    """Faces (global indices) closing ``loop`` (wound like it), ear-clipped in the plane of ``normal``."""
    n = len(loop)
    if n == 3:
        return loop[None, :].copy()
    P = V[loop].astype(np.float64)
    e1 = np.cross(normal, [1.0, 0, 0] if abs(normal[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    xy = np.stack([(P - P.mean(0)) @ e1, (P - P.mean(0)) @ e2], 1)
    chords = np.zeros(0, np.int64)
    if edge_set is not None:
        local = {int(v): i for i, v in enumerate(loop)}
        ch = []
        for v in loop.tolist():
            for w in edge_set.get(v, ()):
                j = local.get(w)
                if j is not None:
                    i = local[v]
                    lo, hi = min(i, j), max(i, j)
                    if hi - lo not in (1, n - 1):
                        ch.append(lo * n + hi)
        chords = np.unique(np.array(ch, np.int64))
    return loop[_ear_clip(xy, P, chords)]


def _subdivide_patch(V: np.ndarray, patch: np.ndarray, locked: np.ndarray, target, max_iter: int = 12):
    """Split the patch faces' edges longer than 4/3 ``target`` (a length, or one per face of ``patch``: the
    faces of one hole share theirs) at their midpoints (red-green: a face with one, two or three split edges
    becomes two, three or four), never an edge whose key is in ``locked`` (the rims).
    Returns (vertices with the new ones appended, faces)."""
    V = np.asarray(V, np.float64)
    n0 = len(V)
    new_v = []
    F = np.asarray(patch, np.int64)
    tgt = np.broadcast_to(np.asarray(target, np.float64), (len(F),)).copy()
    total = n0
    for _ in range(max_iter):
        if not len(F):
            break
        allV = V if not new_v else np.vstack([V] + new_v)
        e = np.stack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], 1)  # (k, 3, 2)
        big = total + 1
        keys = np.minimum(e[..., 0], e[..., 1]) * big + np.maximum(e[..., 0], e[..., 1])
        ln = np.linalg.norm(allV[e[..., 0]] - allV[e[..., 1]], axis=2)
        split = (ln > 4.0 / 3.0 * tgt[:, None]) & ~_in_locked(e, locked, n0)
        if not split.any():
            break
        uk, inv = np.unique(keys[split], return_inverse=True)
        a, b = uk // big, uk % big
        mids = 0.5 * (allV[a] + allV[b])
        mid_idx = np.full(keys.shape, -1, np.int64)
        mid_idx[split] = total + inv.ravel()
        new_v.append(mids)
        total += len(uk)
        keep = ~split.any(1)
        out, out_t = [F[keep]], [tgt[keep]]
        ns = split.sum(1)
        for s in range(3):  # one split edge, edge s: (v_s, m_s, v_s+2), (m_s, v_s+1, v_s+2)
            sel = (ns == 1) & split[:, s]
            if sel.any():
                f, m = F[sel], mid_idx[sel, s]
                v0, v1, v2 = f[:, s], f[:, (s + 1) % 3], f[:, (s + 2) % 3]
                out += [np.stack([v0, m, v2], 1), np.stack([m, v1, v2], 1)]
                out_t += [tgt[sel]] * 2
        for s in range(3):  # two split edges: edge s+2 kept; edges s, s+1 split
            sel = (ns == 2) & ~split[:, (s + 2) % 3]
            if sel.any():
                f = F[sel]
                v0, v1, v2 = f[:, s], f[:, (s + 1) % 3], f[:, (s + 2) % 3]
                m0, m1 = mid_idx[sel, s], mid_idx[sel, (s + 1) % 3]
                out += [np.stack([m0, v1, m1], 1), np.stack([v0, m0, m1], 1), np.stack([v0, m1, v2], 1)]
                out_t += [tgt[sel]] * 3
        sel = ns == 3
        if sel.any():
            f, m = F[sel], mid_idx[sel]
            out += [np.stack([f[:, 0], m[:, 0], m[:, 2]], 1), np.stack([f[:, 1], m[:, 1], m[:, 0]], 1),
                    np.stack([f[:, 2], m[:, 2], m[:, 1]], 1), m.copy()]
            out_t += [tgt[sel]] * 4
        F = np.concatenate(out)
        tgt = np.concatenate(out_t)
    allV = V if not new_v else np.vstack([V] + new_v)
    return allV, F


def _in_locked(e: np.ndarray, locked: np.ndarray, n0: int) -> np.ndarray:
    """Per edge of ``e`` (..., 2): True where both ends are original vertices (< ``n0``) and its key
    (lo * n0 + hi) is in the sorted ``locked``."""
    lo, hi = np.minimum(e[..., 0], e[..., 1]), np.maximum(e[..., 0], e[..., 1])
    orig = hi < n0
    k = np.where(orig, lo * n0 + hi, -1)
    if not len(locked):
        return np.zeros(k.shape, bool)
    j = np.minimum(np.searchsorted(locked, k), len(locked) - 1)
    return orig & (locked[j] == k)


def _fair_patch(V: np.ndarray, faces: np.ndarray, patch: np.ndarray, n_old: int, floor=None) -> np.ndarray:
    """The new vertices (index >= ``n_old``) of ``patch`` moved to solve the bi-Laplace equation (uniform
    weights) over the patch and the observed faces around its rims, everything else fixed; one small system per
    connected patch. ``floor``: (n, c) a plane n . X = c the new vertices are kept above (an object's support)."""
    from scipy.sparse.csgraph import connected_components

    n_new = len(V) - n_old
    if n_new <= 0:
        return V
    rim = unique_sorted(patch[patch < n_old])
    near = np.zeros(n_old, bool)
    near[rim] = True
    ring = faces[near[faces].any(1)]  # the observed faces around the rims: the rim vertices' full 1-ring
    G = np.concatenate([ring, patch])
    used = unique_sorted(G)  # local numbering: the fixed vertices, then the new ones (all of them are in G)
    nf = int(np.searchsorted(used, n_old))
    loc = np.full(len(V), -1, np.int64)
    loc[used] = np.arange(len(used))
    G = loc[G]
    m = len(used)
    L = uniform_laplacian(m, face_edges(G))
    # the new vertices grouped by the blocks of the system (patches, and patches that share a rim vertex:
    # the bi-Laplacian couples vertices two edges apart), solved one block at a time
    L2 = (L[nf:] @ L).tocsc()
    _, comp = connected_components(L2[:, nf:], directed=False)
    order = np.argsort(comp, kind="stable")
    bounds = np.searchsorted(comp[order], np.arange(comp.max() + 2))
    new = nf + order
    L2 = L2[order]
    M = L2[:, new].tocsr()
    rhs = -(L2[:, :nf] @ V[used[:nf]])
    sol = np.empty((n_new, 3))
    X = V.copy()
    for c in range(len(bounds) - 1):
        r0, r1 = bounds[c], bounds[c + 1]
        try:
            x = solve_spd(M[r0:r1].tocsc()[:, r0:r1], rhs[r0:r1])  # rows and columns of L L: symmetric
        except Exception as exc:  # singular: keep the flat patch
            log.debug("hole filling: fairing skipped (%s)", exc)
            x = V[used[new[r0:r1]]]
        x = np.asarray(x).reshape(r1 - r0, 3)
        sol[r0:r1] = x if np.isfinite(x).all() else V[used[new[r0:r1]]]
    if floor is not None:
        nrm, c0 = floor
        h = sol @ nrm - c0
        low = h < 0
        sol[low] -= h[low, None] * nrm[None, :]
    X[used[new]] = sol
    return X


# red-green splits (``_subdivide_patch``) leave edges of 2/3 to 4/3 the target: about this many target^2 a face
REFINED_FACE_AREA = 0.4


def fill_loops(mesh: trimesh.Trimesh, loops: list[np.ndarray], normals: np.ndarray | None = None,
               target: float | None = None, floor=None, max_faces: int = MAX_FILL_FACES,
               fan: bool = False) -> tuple[trimesh.Trimesh, int]:
    """``mesh`` with the holes of ``loops`` (``boundary_loops``) closed: ear-clipped, refined to edges of about
    ``target`` (default: faces as large as the mesh's median face, or edges as long as the median rim edge
    where those are longer; longer over a hole whose patch would otherwise take more than
    about ``max_faces`` faces: a patch carries no detail, and an opening as wide as the object, refined to its
    rim's edges, took most of a million vertices to fair), faired (``_fair_patch``). ``fan``: each rim joined to a new
    vertex at its centre instead of ear-clipped (a rim whose every diagonal is already an edge of the mesh). The mesh's vertices and faces come first and
    unchanged; vertex colours of new vertices diffuse from the rims (``harmonic_fill``). Marks ``filled`` vertex
    and face attributes (kept from ``mesh`` where it has them). Returns (mesh, number of new faces)."""
    V0 = np.asarray(mesh.vertices, np.float64)
    F0 = np.asarray(mesh.faces, np.int64)
    n0 = len(V0)
    old_vf = _attr(mesh.vertex_attributes, "filled", n0)
    old_ff = _attr(mesh.face_attributes, "filled", len(F0))
    if not loops:
        out = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=_colors(mesh), process=False)
        _mark(out, old_vf, old_ff)
        out.metadata.update(mesh.metadata)
        return out, 0
    if normals is None:
        normals = hole_stats(V0, loops)["normal"]
    in_loop = np.zeros(n0, bool)
    for lp in loops:
        in_loop[lp] = True
    # the mesh's edges between rim vertices (a diagonal along one would be used by three faces)
    e = face_edges(F0)
    e = e[in_loop[e[:, 0]] & in_loop[e[:, 1]]]
    edge_set: dict = {}
    for a, b in e.tolist():
        edge_set.setdefault(a, set()).add(b)
        edge_set.setdefault(b, set()).add(a)
    Vs = V0
    if fan:  # a new vertex at each rim's centre, the rim joined to it: no diagonal that could repeat an edge
        centre = n0 + np.arange(len(loops))
        Vs = np.vstack([V0, [V0[lp].mean(0) for lp in loops]])
        pieces = [np.stack([lp, np.roll(lp, -1), np.full(len(lp), c)], 1) for lp, c in zip(loops, centre)]
    else:
        pieces = [_triangulate(V0, lp, nr, edge_set) for lp, nr in zip(loops, normals)]
    patch = np.concatenate(pieces)
    rim_e = np.concatenate([np.stack([lp, np.roll(lp, -1)], 1) for lp in loops])
    if target is None:  # patch faces as large as the surface's own, edges no shorter than the rims'
        target = float(np.sqrt(np.median(face_areas(V0, F0)) / REFINED_FACE_AREA)) if len(F0) else 0.0
        target = max(target, float(np.median(np.linalg.norm(V0[rim_e[:, 0]] - V0[rim_e[:, 1]], axis=1))))
    if max_faces > 0:
        area = np.array([face_areas(Vs, p).sum() for p in pieces])
        per_hole = np.maximum(target, np.sqrt(area / (REFINED_FACE_AREA * max_faces)))
        target = np.repeat(per_hole, [len(p) for p in pieces])
    # every edge of the observed mesh is locked (rims, and any chord the ear clipping could not avoid)
    locked = unique_sorted(edge_keys(rim_e[:, 0], rim_e[:, 1], len(Vs)))
    V, patch = _subdivide_patch(Vs, patch, locked, target)
    V = _fair_patch(V, F0, patch, n0, floor)
    V[:n0] = V0  # the observed surface exactly as it was
    colors = _colors(mesh)
    if colors is not None and len(V) > n0:
        pe = face_edges(patch)
        known = unique_sorted(patch[patch < n0])
        # a graph of the patch vertices only (the rims known)
        used = unique_sorted(patch)
        remap = np.full(len(V), -1, np.int64)
        remap[used] = np.arange(len(used))
        vals = harmonic_fill(len(used), remap[pe], remap[known], np.asarray(colors, np.float64)[known])
        new_c = np.clip(vals[remap[np.arange(n0, len(V))]] + 0.5, 0, 255).astype(np.uint8)
        colors = np.vstack([colors, new_c])
    out = trimesh.Trimesh(V, np.concatenate([F0, patch]), vertex_colors=colors, process=False)
    vf = np.concatenate([old_vf, np.ones(len(V) - n0, np.uint8)])
    ff = np.concatenate([old_ff, np.ones(len(patch), np.uint8)])
    _mark(out, vf, ff)
    out.metadata.update(mesh.metadata)
    return out, len(patch)


def _attr(attrs, name: str, n: int) -> np.ndarray:
    a = attrs.get(name) if hasattr(attrs, "get") else None
    if a is None or len(a) != n:
        return np.zeros(n, np.uint8)
    return np.asarray(a, np.uint8)

def _mark(mesh: trimesh.Trimesh, vf: np.ndarray, ff: np.ndarray) -> None:
    mesh.vertex_attributes["filled"] = np.asarray(vf, np.uint8)
    mesh.face_attributes["filled"] = np.asarray(ff, np.uint8)

def _colors(mesh: trimesh.Trimesh):
    if mesh.visual.kind == "vertex" and len(mesh.visual.vertex_colors) == len(mesh.vertices):
        return np.asarray(mesh.visual.vertex_colors)
    return None

def filled_area(mesh: trimesh.Trimesh) -> float:
    """The area of the faces marked ``filled`` (0 without the mark)."""
    ff = mesh.face_attributes.get("filled") if hasattr(mesh.face_attributes, "get") else None
    if ff is None or len(ff) != len(mesh.faces) or not np.any(ff):
        return 0.0
    F = np.asarray(mesh.faces)[np.asarray(ff) > 0]
    return float(face_areas(np.asarray(mesh.vertices, np.float64), F).sum())

def _drop_overused(mesh: trimesh.Trimesh, new_from: int = 0) -> trimesh.Trimesh:
    """``mesh`` without the faces that make an edge used by more than two, or by two that run it the same way
    (a patch joined to the surface back to front): on each edge the earliest face is kept, and the earliest
    later one that runs the edge against it; the faces added later lose out. ``new_from``: the faces before it
    are settled (the observed surface, or what an earlier pass left) and stay; only the edges of the faces from
    it on are looked at."""
    F = np.asarray(mesh.faces, np.int64)
    n = len(mesh.vertices)
    k = face_edge_keys(F, n)
    e = face_edges(F)
    fwd = e[:, 0] < e[:, 1]
    fid = np.tile(np.arange(len(F)), 3)
    if new_from > 0:  # the edges the new faces use, with every face on them
        on = isin(k, k[fid >= new_from])
        k, fwd, fid = k[on], fwd[on], fid[on]
    order = np.lexsort((fid, k))  # by edge, then by face: the observed faces first
    ks, fw = k[order], fwd[order]
    first = np.r_[True, ks[1:] != ks[:-1]]
    g0 = np.maximum.accumulate(np.where(first, np.arange(len(ks)), 0))  # where each edge's run starts
    against = (fw != fw[g0]) & ~first
    c = np.cumsum(against)
    keep = first | (against & (c - c[g0] == 1))  # the first face against the edge's first
    drop = np.zeros(len(F), bool)
    drop[fid[order[~keep]]] = True
    drop[:new_from] = False
    if not drop.any():
        return mesh
    return _subset(mesh, ~drop)

def _subset(mesh: trimesh.Trimesh, keep: np.ndarray) -> trimesh.Trimesh:
    """The faces ``keep`` of ``mesh``, its vertices (all of them, unreferenced ones too) and attributes kept."""
    out = trimesh.Trimesh(mesh.vertices, np.asarray(mesh.faces)[keep], vertex_colors=_colors(mesh), process=False)
    _mark(out, _attr(mesh.vertex_attributes, "filled", len(mesh.vertices)),
          _attr(mesh.face_attributes, "filled", len(mesh.faces))[keep])
    out.metadata.update(mesh.metadata)
    return out
