"""The rims of a mesh's holes: boundary edges, their loops, each loop's size and plane, the surface's normals
along a rim, the notches of a rim too big to fill whole, and the test for an object's opening at its support.

``boundary_loops`` traces the rims as simple loops of vertices (a vertex where two holes touch splits them);
``hole_stats`` gives each rim's length, radius and how far it lies off its best-fit plane: what the hole filling
(``mesh.fill``) chooses by.
"""
from __future__ import annotations

import numpy as np
import trimesh

from ..jit import njit
from .geometry import face_cross, face_edge_keys, face_edges


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
