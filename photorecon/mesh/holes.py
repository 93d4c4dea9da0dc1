"""Hole filling that leaves the observed surface as it is: each hole's rim (a loop of boundary edges) is
triangulated, the patch refined to faces about as large as the surface's own and its new vertices faired, the surface's own vertices
and faces untouched.

1. ``boundary_loops``: the rims, as simple loops of vertices (a vertex where two holes touch splits them).
2. ``fill_loops``: which holes to fill is the caller's (``hole_stats``: each rim's length, radius and how far it
   lies off its best-fit plane); each chosen rim is triangulated by ear clipping in its best-fit plane (the
   shortest diagonal first, never a diagonal that is already an edge of the mesh), the patch's edges longer
   than the rim's are split (midpoints; the rim's own edges never, so no observed face gets a T-junction) and
   the new vertices solve the bi-Laplace equation (uniform weights) with the surface around them fixed: the
   patch continues the surface's slope across the rim (Liepa, "Filling holes in meshes", SGP 2003), where a
   membrane would cut flat across it.
3. ``fill_small_holes`` (the cleaning stage's ``mesh.ply``) and ``close_mesh`` (the closed companion of an object,
   ``mesh_closed.ply``) on top. An object whose surface came out in pieces (a dark, rough one: its largest piece
   under 90% of the area) is closed as one screened Poisson surface through them instead (``poisson_closed``):
   closing each piece on its own would give a heap of closed crumbs.

Both mark what they added: ``vertex_attributes["filled"]`` (1 on a patch's new vertices, 0 elsewhere) and
``face_attributes["filled"]`` (1 on patch faces), written to PLY as ``filled`` properties.
"""
from __future__ import annotations

import logging

import numpy as np
import trimesh

from ..arrays import isin, unique_sorted
from ..jit import njit
from .geometry import edge_keys, face_areas, face_cross, face_edge_keys, face_edges, triangle_components

log = logging.getLogger("photorecon")

# what fill_small_holes reports (and the cleaning, when it fills nothing)
NO_FILL = {"holes": None, "filled_holes": 0, "filled_notches": 0, "filled_faces": 0, "kept_open": 0, "unseen": 0}
MAX_FILL_FACES = 20_000  # about the most faces a patch over one hole gets (fill_loops' max_faces)


def boundary_directed(faces: np.ndarray, n: int | None = None) -> np.ndarray:
    """The boundary edges of ``faces`` (F, 3) (used by one face), (E, 2) as that face runs them."""
    F = np.asarray(faces, np.int64)
    if not len(F):
        return np.zeros((0, 2), np.int64)
    n = int(F.max()) + 1 if n is None else n
    e = face_edges(F)
    k = face_edge_keys(F, n)
    _, inv, cnt = np.unique(k, return_inverse=True, return_counts=True)
    return e[cnt[inv.ravel()] == 1]


def boundary_length(mesh: trimesh.Trimesh) -> float:
    """Total length of the edges used by one face only (the rims of the holes), scene units."""
    e = boundary_directed(mesh.faces, len(mesh.vertices))
    V = np.asarray(mesh.vertices, np.float64)
    return float(np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1).sum()) if len(e) else 0.0


def boundary_loops(faces: np.ndarray, n: int | None = None) -> list[np.ndarray]:
    """The rims of the holes of ``faces`` (F, 3): simple loops of vertex indices, each ordered against the winding
    of most of the faces along it (the way a patch that closes the hole runs them). The rims are traced along
    boundary edges whatever the faces' winding (a face wound the wrong way does not break a rim); a vertex where
    two rims touch (or a rim touches itself) splits them into simple loops."""
    e = boundary_directed(faces, n)
    if not len(e):
        return []
    src, dst = e[:, 0].tolist(), e[:, 1].tolist()
    out_e: dict = {}
    in_e: dict = {}
    for k, (a, b) in enumerate(zip(src, dst)):
        out_e.setdefault(a, []).append(k)
        in_e.setdefault(b, []).append(k)
    used = np.zeros(len(e), bool)
    loops: list[np.ndarray] = []

    def next_edge(v):
        # the way the faces run first: where two rims touch at v, an edge into v followed by another edge into v
        # would join them into one loop that runs half of its edges against the other half, and the patch
        # over it would face the wrong way along that half
        for lst in (out_e.get(v), in_e.get(v)):
            while lst:
                k = lst.pop()
                if not used[k]:
                    return k
        return -1

    def emit(cyc_v, cyc_e):
        if len(cyc_v) < 3:
            return
        # the loop runs v0 -> v1 -> ...; a boundary edge the face runs the same way votes for reversing it
        fwd = sum(1 if src[k] == cyc_v[t] else -1 for t, k in enumerate(cyc_e))
        loops.append(np.array(cyc_v[::-1] if fwd >= 0 else cyc_v, np.int64))

    for e0 in range(len(e)):
        if used[e0]:
            continue
        path, path_e = [src[e0]], []
        pos = {src[e0]: 0}
        k = e0
        while k >= 0:
            used[k] = True
            v = dst[k] if src[k] == path[-1] else src[k]
            path_e.append(k)
            at = pos.get(v)
            if at is None:
                pos[v] = len(path)
                path.append(v)
            else:  # a loop closed at v: split it off, go on from v
                emit(path[at:], path_e[at:])
                for u in path[at + 1:]:
                    del pos[u]
                del path[at + 1:]
                del path_e[at:]
            k = next_edge(path[-1])
    return loops


def hole_stats(V: np.ndarray, loops: list[np.ndarray]) -> dict:
    """Per loop: ``length`` (its perimeter), ``radius`` (the farthest rim vertex from the rim's centre: the
    radius of the sphere around the hole), ``offplane`` (the farthest rim vertex from the rim's best-fit plane,
    relative to ``radius``: 0 for a flat rim) and ``normal`` (the best-fit plane's unit normal, (L, 3))."""
    L = len(loops)
    out = {"length": np.zeros(L), "radius": np.zeros(L), "offplane": np.zeros(L), "normal": np.zeros((L, 3))}
    for j, lp in enumerate(loops):
        P = V[lp]
        seg = np.linalg.norm(P - np.roll(P, -1, 0), axis=1)
        c = P.mean(0)
        radius = float(np.linalg.norm(P - c, axis=1).max())
        if len(P) >= 3:
            nrm = np.linalg.svd(P - c, full_matrices=False)[2][2]
        else:
            nrm = np.array([0.0, 0.0, 1.0])
        out["length"][j] = seg.sum()
        out["radius"][j] = radius
        out["offplane"][j] = float(np.abs((P - c) @ nrm).max()) / max(radius, 1e-300)
        out["normal"][j] = nrm
    return out


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


def _refine(V: np.ndarray, patch: np.ndarray, locked: np.ndarray, target, max_iter: int = 12):
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


def _fair(V: np.ndarray, faces: np.ndarray, patch: np.ndarray, n_old: int, floor=None) -> np.ndarray:
    """The new vertices (index >= ``n_old``) of ``patch`` moved to solve the bi-Laplace equation (uniform
    weights) over the patch and the observed faces around its rims, everything else fixed; one small system per
    connected patch. ``floor``: (n, c) a plane n . X = c the new vertices are kept above (an object's support)."""
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    from .solve import solve_spd

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
    e = face_edges(G)
    e = np.concatenate([e, e[:, ::-1]])
    A = sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(m, m)).tocsr()
    A.data[:] = 1.0
    L = (sparse.diags(np.asarray(A.sum(1)).ravel()) - A).tocsr()
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


# red-green splits (``_refine``) leave edges of 2/3 to 4/3 the target: about this many target^2 a face
REFINED_FACE_AREA = 0.4


def fill_loops(mesh: trimesh.Trimesh, loops: list[np.ndarray], normals: np.ndarray | None = None,
               target: float | None = None, floor=None, max_faces: int = MAX_FILL_FACES,
               fan: bool = False) -> tuple[trimesh.Trimesh, int]:
    """``mesh`` with the holes of ``loops`` (``boundary_loops``) closed: ear-clipped, refined to edges of about
    ``target`` (default: faces as large as the mesh's median face, or edges as long as the median rim edge
    where those are longer; longer over a hole whose patch would otherwise take more than
    about ``max_faces`` faces: a patch carries no detail, and an opening as wide as the object, refined to its
    rim's edges, took most of a million vertices to fair), faired (``_fair``). ``fan``: each rim joined to a new
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
    V, patch = _refine(Vs, patch, locked, target)
    V = _fair(V, F0, patch, n0, floor)
    V[:n0] = V0  # the observed surface exactly as it was
    colors = _colors(mesh)
    if colors is not None and len(V) > n0:
        from .clean import harmonic_fill

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


def rim_normals(V: np.ndarray, F: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Per vertex of ``vertices``: the unit normal of the faces around it (their area-weighted mean), (k, 3), as
    the faces are wound."""
    n = len(V)
    want = np.zeros(n, bool)
    want[vertices] = True
    sel = np.flatnonzero(want[F].any(1))
    fc = face_cross(V, F[sel])
    acc = np.zeros((n, 3))
    for k in range(3):
        np.add.at(acc, F[sel, k], fc)
    out = acc[vertices]
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)


def split_notches(V: np.ndarray, loop: np.ndarray, normals: np.ndarray, max_radius: float,
                  max_offplane: float = 0.5, min_agree: float = 0.0, rounds: int = 8) -> tuple[list[np.ndarray], np.ndarray]:
    """The notches of a hole too big to fill whole: parts of its rim that leave and come back within
    ``max_radius`` of where they left, around a bay of the hole (the rim on one side, a chord across the
    hole on the other: the enclosed area is hole, wound as a hole is, not a peninsula of surface), that fit
    in a sphere of ``max_radius``, lie near a plane (``max_offplane``) and along which the surface faces like
    that plane (``min_agree``: the mean |cos| of the angle). ``normals`` (len(loop), 3): the surface's unit
    normal at each rim vertex (``rim_normals``). Returns (the notches, as loops to fill; what is
    left of the hole, its rim cut short by the chords)."""
    from scipy.spatial import cKDTree

    loop = np.asarray(loop, np.int64)
    nrm = np.asarray(normals, np.float64)
    pieces: list[np.ndarray] = []
    for r in range(rounds):
        n = len(loop)
        if n < 6:
            break
        shift = (n // 2) if r % 2 else 0  # a notch across the loop's start is found in the next round
        loop, nrm = np.roll(loop, -shift), np.roll(nrm, -shift, axis=0)
        P = V[loop]
        seg = np.linalg.norm(P - np.roll(P, -1, 0), axis=1)
        s = np.r_[0.0, np.cumsum(seg)]
        pairs = cKDTree(P).query_pairs(max_radius, output_type="ndarray")
        if not len(pairs):
            break
        i, j = pairs.min(1), pairs.max(1)
        d = np.linalg.norm(P[i] - P[j], axis=1)
        arc = s[j] - s[i]
        ok = (j - i >= 2) & (arc >= 3 * d) & (arc <= 2 * np.pi * max_radius * 4) & (arc <= 0.5 * s[-1])
        i, j, d, arc = i[ok], j[ok], d[ok], arc[ok]
        if not len(i):
            break
        order = np.argsort(-(arc - d), kind="stable")
        taken, busy = _pick_notches(np.ascontiguousarray(P), np.ascontiguousarray(nrm), i[order], j[order],
                                    float(max_radius), float(max_offplane), float(min_agree))
        if not len(taken):
            if r % 2:
                break
            continue
        for a, b in taken.tolist():
            pieces.append(loop[a:b + 1].copy())
        loop, nrm = loop[~busy], nrm[~busy]
    return pieces, loop


@njit(cache=True)
def _pick_notches(P, nrm, ci, cj, max_radius, max_offplane, min_agree):
    """``split_notches``' choice: the candidate chords (ci < cj, best first) taken greedily when their notch
    overlaps none taken before, fits in ``max_radius``, is wound as a hole, lies near a plane and the surface
    along it faces like that plane (``nrm``: unit normals; their mean |cos| to it at least ``min_agree``). Returns
    ((k, 2) taken, per rim vertex True strictly inside a taken notch)."""
    n = P.shape[0]
    busy = np.zeros(n, np.bool_)
    ends = np.zeros(n, np.bool_)
    out = np.empty((len(ci), 2), np.int64)
    t = 0
    for q in range(len(ci)):
        a, b = ci[q], cj[q]
        clash = False
        for k in range(a, b + 1):
            if busy[k] or (k > a and k < b and ends[k]):
                clash = True
                break
        if clash:
            continue
        m = b - a + 1
        c = np.zeros(3)
        for k in range(a, b + 1):
            c += P[k]
        c /= m
        rad = 0.0
        for k in range(a, b + 1):
            rad = max(rad, np.sqrt(((P[k] - c) ** 2).sum()))
        if rad > max_radius:
            continue
        area = np.zeros(3)
        nsum = np.zeros(3)
        for k in range(a, b + 1):
            p, r = P[k] - c, P[a + (k - a + 1) % m] - c
            area[0] += p[1] * r[2] - p[2] * r[1]
            area[1] += p[2] * r[0] - p[0] * r[2]
            area[2] += p[0] * r[1] - p[1] * r[0]
            nsum += nrm[k]
        if (area * nsum).sum() <= 0:  # encloses surface (a peninsula), not hole
            continue
        C = np.zeros((3, 3))
        for k in range(a, b + 1):
            d = P[k] - c
            C += np.outer(d, d)
        w, U = np.linalg.eigh(C)
        pn = U[:, 0]
        off = 0.0
        for k in range(a, b + 1):
            off = max(off, abs(((P[k] - c) * pn).sum()))
        if off > max_offplane * max(rad, 1e-300):
            continue
        agree = 0.0
        for k in range(a, b + 1):
            agree += abs((nrm[k] * pn).sum())
        if agree < min_agree * m:
            continue
        out[t, 0], out[t, 1] = a, b
        t += 1
        for k in range(a + 1, b):
            busy[k] = True
        ends[a] = True
        ends[b] = True
    return out[:t], busy


def fill_small_holes(mesh: trimesh.Trimesh, max_radius: float, max_offplane: float = 0.5,
                     max_angle: float = 90.0, notches: bool = True, keep_open=None, centres=None,
                     min_views: int = 2, view_angle: float = 60.0, pinhole: float = 0.3) -> tuple[trimesh.Trimesh, dict]:
    """Fill the holes whose rim fits in a sphere of ``max_radius`` (scene units), lies near a plane (its farthest
    vertex off the best-fit plane at most ``max_offplane`` x that radius: a hole in a surface, not a gap between
    two sides) and along which the surface faces like that plane (the mean |cos| of the angle between the
    surface's normals at the rim and the plane's at least cos ``max_angle`` degrees: the surface around agrees,
    not a curled fringe); of a bigger hole, its notches (``split_notches``) under the same tests, and then what
    is left of it when that passes them. ``keep_open(vertices)``: True for a rim to leave as it is, notches and
    all (an object's opening at its support, for ``close_mesh``). ``centres`` (N, 3): the cameras; with them a
    hole (or notch) is filled only where at least ``min_views`` of them face it, within ``view_angle`` degrees of
    its outward normal: a gap in surface the photos saw well, not one where they saw nothing (an object's top
    seen at grazing angles from a ring of cameras, which ``mesh_closed`` closes); pinholes (a radius up to
    ``pinhole`` x ``max_radius``) are filled whatever the views. Returns the mesh and the
    facts: ``holes`` (rims found), ``filled_holes`` (whole holes), ``filled_notches``, ``filled_faces``,
    ``kept_open``, ``unseen`` (holes and notches left open for want of views)."""
    loops = boundary_loops(mesh.faces, len(mesh.vertices))
    info = {**NO_FILL, "holes": len(loops)}
    if not loops:
        out, _ = fill_loops(mesh, [])
        return out, info
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    min_agree = float(np.cos(np.radians(max_angle)))
    allv = np.concatenate(loops)
    nv = rim_normals(V, F, allv)
    normal_at = np.zeros((len(V), 3))
    normal_at[allv] = nv  # a notch's rim is part of its hole's
    starts = np.r_[0, np.cumsum([len(lp) for lp in loops])]

    cams = None if centres is None or not min_views else np.asarray(centres, np.float64).reshape(-1, 3)
    cos_view = float(np.cos(np.radians(view_angle)))
    unseen = [0]

    def seen(lp, u, st=None):
        """At least min_views cameras within view_angle of the hole's outward normal (the rim's faces' side);
        ``st``: the rim's ``hole_stats`` when the caller has them."""
        if cams is None:
            return True
        st = hole_stats(V, [lp]) if st is None else st
        if st["radius"][0] <= pinhole * max_radius:  # a pinhole: filled whatever the views
            return True
        n = st["normal"][0]
        n = n if float(u.sum(0) @ n) >= 0 else -n
        d = cams - V[lp].mean(0)
        ok = int(((d @ n) >= cos_view * np.linalg.norm(d, axis=1)).sum()) >= min_views
        unseen[0] += not ok
        return ok

    def passes(lp, u):
        st = hole_stats(V, [lp])
        agree = float(np.abs(u @ st["normal"][0]).mean())
        return (st["radius"][0] <= max_radius and st["offplane"][0] <= max_offplane and agree >= min_agree
                and seen(lp, u, st))

    fill, n_whole, n_notches, n_kept = [], 0, 0, 0
    for j, lp in enumerate(loops):
        if keep_open is not None and keep_open(lp):
            n_kept += 1
            continue
        u = nv[starts[j]:starts[j + 1]]
        if passes(lp, u):
            fill.append(lp)
            n_whole += 1
            continue
        if not notches:
            continue
        pieces, rest = split_notches(V, lp, u, max_radius, max_offplane, min_agree)
        if cams is not None:
            pieces = [pc for pc in pieces if seen(pc, normal_at[pc])]
        fill += pieces
        n_notches += len(pieces)
        if pieces and len(rest) >= 3:
            if passes(rest, normal_at[rest]):
                fill.append(rest)
    # a patch face on an edge the surface already uses twice, or run the surface's way, goes (a few per mesh)
    out = _drop_overused(fill_loops(mesh, fill)[0], new_from=len(mesh.faces))
    nf = len(out.faces) - len(mesh.faces)
    info.update(filled_holes=n_whole, filled_notches=n_notches, filled_faces=int(nf), kept_open=n_kept,
                unseen=unseen[0])
    return out, info


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


def at_support(V: np.ndarray, support: dict | None, margin: float):
    """For an object whose support was cut away (``support``: ``support_normal``, ``support_offset``,
    ``support_cut``): a test of a rim (vertex indices into ``V``) that is True when at least 3 of its vertices lie
    within ``margin`` above the cut: the opening the cut left, or a hole that reaches it. None without one."""
    floor = support_floor(support or {})
    if floor is None:
        return None
    n, c = floor
    top = float(support.get("support_cut", 0.0)) + margin

    def test(loop):
        return int(((V[loop] @ n - c) <= top).sum()) >= 3

    return test


def support_floor(metadata: dict):
    """The support plane (n, c) of an object capture from a cleaned mesh's ``metadata`` (``support_normal``,
    ``support_offset``), n towards the object; None without one."""
    nrm, off = metadata.get("support_normal"), metadata.get("support_offset")
    if not nrm or off is None:
        return None
    n = np.array([float(x) for x in str(nrm).split(",")])
    return n / np.linalg.norm(n), float(off)


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

    from .clean import largest_piece, poisson_surface, raycasting_scene

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
