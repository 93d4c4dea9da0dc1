"""Seam levelling of a texture atlas: colour steps where neighbouring faces take different photos, evened out.

**Global levelling** (Waechter et al., ECCV 2014, "Let there be color!", as in MVS-Texturing and OpenMVS's
TextureMesh): every output vertex of the textured mesh (one per mesh vertex and atlas rectangle, so a vertex on a
seam has one per photo meeting there) gets a colour offset ``g`` (RGB, 0-255 units). They minimise

    sum over seam vertices v and photo pairs (a, b) meeting there of |f_a(v) + g_a(v) - f_b(v) - g_b(v)|^2
    + lambda^2 sum over edges (i, j) inside one chart of |g_i - g_j|^2

where ``f_a(v)`` is the colour of photo ``a`` along the seam edges at ``v`` (samples along each seam edge
taken from the baked atlas, weighted by their closeness to ``v``: 1 at ``v``, 0 at the edge's other end). The
first term closes the steps at the seams, the second spreads each correction smoothly over its chart. Seam
vertices whose step stands out from the others between the same two charts (``seam_inliers``: a silhouette or
an occluder in one photo, a misplaced surface) are left out of the first term.
``solve_offsets`` solves this sparse least-squares problem, for the three channels at once (conjugate gradients
on its normal equations with a chart-wise coarse correction; a tiny ridge ``1e-10 |g|^2`` picks the smallest
offsets where only differences are fixed: a constant per seam-connected group of charts). ``apply_offsets`` adds the offsets
to the atlas, interpolated barycentrically over each triangle in atlas space; texels no triangle covers (the
padding around charts, gaps inside a rectangle) take the offset of the nearest covered texel, so bilinear
filtering at chart borders stays consistent.

**Local blending** (``blend_seams``) then evens out what is left along the seams themselves, at texel scale (the
offsets vary only from vertex to vertex): in a strip ``BLEND`` texels wide on each side of a seam, a texel moves
towards the other photo's colour at the nearest point of the seam, by half the difference on the seam, fading
to nothing at the strip's edge. A linear stand-in for MVS-Texturing's Poisson editing of the strip.

``seam_steps`` measures the result: the mean colour step across chart borders against the one across edges
inside charts (``tools/bench_texture.py``, tests/mesh/test_seams.py).
"""
from __future__ import annotations

import numpy as np

from ..io.images import sample_bilinear
from ..jit import njit
from ..progress import bar

BLEND = 2.0  # texels each side of a seam that local blending reaches (0 = none)
LAMBDA = 0.1  # the regulariser's weight (its rows' coefficient, as in MVS-Texturing)
RIDGE = 1e-10  # weight of |g|^2: fixes the free constant of each group of charts at the smallest offsets
# (small against LAMBDA^2: the offsets of a chart would fall off over sqrt(LAMBDA^2 / RIDGE) = 10^4 edges)


def _corner_of(faces: np.ndarray, face: np.ndarray, vertex: np.ndarray) -> np.ndarray:
    """The corner (0-2) of ``face`` that is ``vertex`` (both (E,))."""
    return np.argmax(faces[face] == vertex[:, None], axis=1)


def seam_differences(faces: np.ndarray, out_faces: np.ndarray, labels: np.ndarray, adjacency: np.ndarray,
                     adjacency_edges: np.ndarray, tex: np.ndarray, atlas: np.ndarray, samples: int = 7):
    """The seam terms: pairs of output vertices (``a``, ``b``) at one mesh vertex on a seam and the colour
    difference ``f_b - f_a`` (P, 3) between their photos along the seam edges there.

    ``faces`` (F, 3) mesh vertex ids, ``out_faces`` (F, 3) output vertex ids (one per vertex and rectangle),
    ``labels`` (F,) photo per face (-1 = none), ``adjacency`` (E, 2) face pairs and ``adjacency_edges`` (E, 2)
    their shared vertices, ``tex`` (F, 3, 2) corners in atlas texel coordinates, ``atlas`` the baked atlas."""
    adjacency = np.asarray(adjacency, np.int64).reshape(-1, 2)
    edges = np.asarray(adjacency_edges, np.int64).reshape(-1, 2)
    fa, fb = adjacency.T
    la, lb = labels[fa], labels[fb]
    seam = (la >= 0) & (lb >= 0) & (la != lb)
    fa, fb, (v0, v1) = fa[seam], fb[seam], edges[seam].T
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))
    if not len(fa):
        return empty
    t = np.linspace(0.0, 1.0, samples)
    cols = []
    outs = []
    for f in (fa, fb):
        c0, c1 = _corner_of(faces, f, v0), _corner_of(faces, f, v1)
        p0, p1 = tex[f, c0], tex[f, c1]  # (E, 2)
        pts = p0[:, None] * (1 - t)[None, :, None] + p1[:, None] * t[None, :, None]  # (E, S, 2)
        cols.append(sample_bilinear(atlas, pts.reshape(-1, 2)).reshape(len(f), samples, -1)[..., :3].astype(np.float64))
        outs.append((out_faces[f, c0], out_faces[f, c1]))
    # per end of each seam edge: the samples weighted by closeness to that end
    w = np.stack([1 - t, t])  # (2, S): end 0 (v0), end 1 (v1)
    keys, ca, cb, ws = [], [], [], []
    for end in (0, 1):
        wa = (cols[0] * w[end][None, :, None]).sum(1)
        wb = (cols[1] * w[end][None, :, None]).sum(1)
        keys.append(np.stack([outs[0][end], outs[1][end]], 1))
        ca.append(wa)
        cb.append(wb)
        ws.append(np.full(len(fa), w[end].sum()))
    keys, ca, cb, ws = np.concatenate(keys), np.concatenate(ca), np.concatenate(cb), np.concatenate(ws)
    swap = keys[:, 0] > keys[:, 1]  # one orientation per pair
    keys[swap] = keys[swap][:, ::-1]
    ca[swap], cb[swap] = cb[swap].copy(), ca[swap].copy()
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    wsum = np.bincount(inv, ws, minlength=len(uniq))
    diff = np.stack([np.bincount(inv, cb[:, c] - ca[:, c], minlength=len(uniq)) for c in range(3)], 1)
    return uniq[:, 0], uniq[:, 1], diff / wsum[:, None]


def seam_inliers(group: np.ndarray, diff: np.ndarray, k: float = 3.0, floor: float = 4.0) -> np.ndarray:
    """(P,) bool: the seam pairs whose colour difference ``diff`` (P, 3) is within ``k`` robust standard
    deviations (1.4826 MAD, at least ``floor`` RGB units) of the median over their ``group`` (P,: the pair of
    charts they join), in every channel. A step that an exposure or light difference makes is about the same
    all along the seam between two charts; one that only a few vertices show (a silhouette or an occluder in one
    photo, a misplaced surface) is not levelled, it would spread over the chart."""
    if not len(group):
        return np.zeros(0, bool)
    _, g = np.unique(group, return_inverse=True)
    g = g.reshape(-1)
    order = np.argsort(g, kind="stable")
    gs = g[order]
    starts = np.flatnonzero(np.r_[True, gs[1:] != gs[:-1]])
    counts = np.diff(np.r_[starts, len(gs)])
    d = diff[order]
    med = np.empty_like(d)
    mad = np.empty_like(d)
    for n in np.unique(counts):
        sel = (starts[counts == n][:, None] + np.arange(n)[None]).reshape(-1)
        block = d[sel].reshape(-1, n, 3)
        m = np.median(block, axis=1, keepdims=True)
        med[sel] = np.broadcast_to(m, block.shape).reshape(-1, 3)
        mad[sel] = np.repeat(np.median(np.abs(block - m), axis=1), n, axis=0)
    ok = np.all(np.abs(d - med) <= np.maximum(k * 1.4826 * mad, floor), axis=1)
    out = np.empty(len(g), bool)
    out[order] = ok
    return out


def solve_offsets(n: int, a: np.ndarray, b: np.ndarray, diff: np.ndarray, reg_edges: np.ndarray,
                  lam: float = LAMBDA, ridge: float = RIDGE, rtol: float = 1e-4, max_iter: int = 3000,
                  stats: dict | None = None) -> np.ndarray:
    """Offsets ``g`` (n, 3) minimising ``sum |g[a] - g[b] - diff|^2 + lam^2 sum_(i, j) |g[i] - g[j]|^2 +
    ridge |g|^2`` over the seam pairs (``a``, ``b``, ``diff`` (P, 3)) and the regulariser's edges ``reg_edges``
    (R, 2). Variables in no seam pair's reach stay 0.

    The normal equations are solved by conjugate gradients, the three channels together, preconditioned by
    Jacobi plus a coarse correction on the functions constant over each chart (connected through
    ``reg_edges``): the chart-wide shifts the seams need converge in one step, the rest is local (a direct
    factorisation fills in too much on meshes of 100k+ vertices). Stops at a residual of ``rtol`` times the
    right-hand side's. ``stats``, if given, gets the iterations run (``iterations``)."""
    from scipy.sparse import coo_matrix, csr_matrix, identity
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import splu

    g = np.zeros((n, 3))
    a, b = np.asarray(a, np.int64), np.asarray(b, np.int64)
    if not len(a) or n == 0:
        return g
    reg = np.asarray(reg_edges, np.int64).reshape(-1, 2)
    # only the variables connected to a seam pair through seams and chart edges take part
    ii, jj = np.r_[a, reg[:, 0]], np.r_[b, reg[:, 1]]
    _, comp = connected_components(coo_matrix((np.ones(len(ii)), (ii, jj)), shape=(n, n)), directed=False)
    idx = np.flatnonzero(np.isin(comp, np.unique(comp[a])))
    m = len(idx)
    loc = np.full(n, -1, np.int64)
    loc[idx] = np.arange(m)
    keep = (loc[reg[:, 0]] >= 0) & (loc[reg[:, 1]] >= 0)
    ra, rb = loc[reg[keep, 0]], loc[reg[keep, 1]]
    sa, sb = loc[a], loc[b]

    def laplacian(i, j, w):
        return coo_matrix((np.r_[w, w, -w, -w], (np.r_[i, j, i, j], np.r_[i, j, j, i])), shape=(m, m))

    A = (laplacian(sa, sb, np.ones(len(sa))) + laplacian(ra, rb, np.full(len(ra), lam * lam))).tocsr() \
        + ridge * identity(m, format="csr")
    rhs = np.stack([np.bincount(sa, diff[:, c], minlength=m) - np.bincount(sb, diff[:, c], minlength=m)
                    for c in range(3)], 1)
    # the coarse space: one constant per chart (an affine function per chart adds little, and is singular on
    # flat charts)
    nc, chart = connected_components(coo_matrix((np.ones(len(ra)), (ra, rb)), shape=(m, m)), directed=False)
    Z = csr_matrix((np.ones(m), (np.arange(m), chart)), shape=(m, nc)).tocsc()
    coarse = splu((Z.T @ A @ Z).tocsc(), permc_spec="COLAMD")
    dinv = 1.0 / A.diagonal()

    def precondition(r):
        return dinv[:, None] * r + Z @ coarse.solve(np.asarray(Z.T @ r))

    def dot(u, v):  # per channel
        return np.einsum("ij,ij->j", u, v)

    x = np.zeros((m, 3))
    r = rhs.copy()
    stop = rtol * np.maximum(np.sqrt(dot(rhs, rhs)), 1e-30)
    z = precondition(r)
    p = z.copy()
    rz = dot(r, z)
    it = 0
    for it in range(1, max_iter + 1):
        Ap = A @ p
        alpha = rz / np.maximum(dot(p, Ap), 1e-300)
        x += alpha * p
        r -= alpha * Ap
        if np.all(np.sqrt(dot(r, r)) <= stop):
            break
        z = precondition(r)
        rz_new = dot(r, z)
        p = z + (rz_new / np.maximum(rz, 1e-300)) * p
        rz = rz_new
    g[idx] = x
    if stats is not None:
        stats["iterations"] = it
    return g


@njit(cache=True)
def _raster(tri: np.ndarray, vals: np.ndarray, w: int, h: int, buf: np.ndarray, covered: np.ndarray) -> None:
    """Write into ``buf`` (h, w, 3) float32 the values ``vals`` (m, 3, 3) float32 at the corners of triangles ``tri``
    (m, 3, 2) float64 (texel coordinates, texel centres at integers), interpolated barycentrically at every texel
    centre inside a triangle (within 1e-4 of its edges); ``covered`` (h, w) marks those texels. A later triangle
    overwrites an earlier one where they share texels."""
    tol = -1e-4
    for t in range(tri.shape[0]):
        ax, ay = tri[t, 0, 0], tri[t, 0, 1]
        bx, by = tri[t, 1, 0], tri[t, 1, 1]
        cx, cy = tri[t, 2, 0], tri[t, 2, 1]
        den = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if abs(den) <= 1e-12:
            continue
        x0 = max(int(np.ceil(min(ax, bx, cx) - 1e-6)), 0)
        x1 = min(int(np.floor(max(ax, bx, cx) + 1e-6)), w - 1)
        y0 = max(int(np.ceil(min(ay, by, cy) - 1e-6)), 0)
        y1 = min(int(np.floor(max(ay, by, cy) + 1e-6)), h - 1)
        for py in range(y0, y1 + 1):
            for px in range(x0, x1 + 1):
                wb = ((px - ax) * (cy - ay) - (py - ay) * (cx - ax)) / den
                wc = ((bx - ax) * (py - ay) - (by - ay) * (px - ax)) / den
                wa = 1.0 - wb - wc
                if wa >= tol and wb >= tol and wc >= tol:
                    for k in range(3):
                        buf[py, px, k] = wa * vals[t, 0, k] + wb * vals[t, 1, k] + wc * vals[t, 2, k]
                    covered[py, px] = True


def apply_offsets(atlas: np.ndarray, offsets: np.ndarray, out_faces: np.ndarray, tex: np.ndarray,
                  face_rect: np.ndarray, pos: np.ndarray, size: np.ndarray, min_offset: float = 0.25) -> int:
    """Add the per-output-vertex ``offsets`` (n, 3) to ``atlas`` in place, interpolated over each face's triangle
    ``tex`` (F, 3, 2, atlas texel coordinates) inside its rectangle ``face_rect`` (F,) at ``pos`` (R, 2) of
    ``size`` (R, 2) = (w, h); the rectangle's other texels take the offset of the nearest covered texel.
    Rectangles whose offsets all stay under ``min_offset`` are left as they are. Returns the rectangles changed."""
    from scipy.ndimage import distance_transform_edt

    seen = np.flatnonzero(face_rect >= 0)
    if not len(seen):
        return 0
    order = seen[np.argsort(face_rect[seen], kind="stable")]
    rects, starts = np.unique(face_rect[order], return_index=True)
    ends = np.r_[starts[1:], len(order)]
    big = np.abs(offsets).max(1) >= min_offset
    changed = 0
    for r, s, e in bar(list(zip(rects, starts, ends)), desc="texture: seam levelling", unit="chart"):
        fs = order[s:e]
        if not big[out_faces[fs]].any():
            continue
        (x, y), (w, h) = pos[r], size[r]
        w, h = int(w), int(h)
        buf = np.zeros((h, w, 3), np.float32)
        covered = np.zeros((h, w), bool)
        _raster(tex[fs] - np.asarray(pos[r], np.float64), offsets[out_faces[fs]].astype(np.float32), w, h, buf, covered)
        if not covered.any():
            continue
        if not covered.all():
            iy, ix = distance_transform_edt(~covered, return_distances=False, return_indices=True)
            buf = buf[iy, ix]
        patch = atlas[y:y + h, x:x + w].astype(np.float32) + buf
        atlas[y:y + h, x:x + w] = np.clip(patch + 0.5, 0, 255).astype(np.uint8)
        changed += 1
    return changed


def _seam_edges(labels: np.ndarray, adjacency: np.ndarray, adjacency_edges: np.ndarray):
    """The adjacent face pairs (fa, fb) with different photos (both seen) and their shared vertices (v0, v1)."""
    adjacency = np.asarray(adjacency, np.int64).reshape(-1, 2)
    edges = np.asarray(adjacency_edges, np.int64).reshape(-1, 2)
    la, lb = labels[adjacency[:, 0]], labels[adjacency[:, 1]]
    seam = (la >= 0) & (lb >= 0) & (la != lb)
    return adjacency[seam, 0], adjacency[seam, 1], edges[seam, 0], edges[seam, 1]


def blend_seams(atlas: np.ndarray, faces: np.ndarray, labels: np.ndarray, adjacency: np.ndarray,
                adjacency_edges: np.ndarray, tex: np.ndarray, face_rect: np.ndarray, pos: np.ndarray,
                size: np.ndarray, width: float = 3.0) -> int:
    """Local blending in a strip of ``width`` texels along each seam, in place: a texel at distance ``d`` from a
    seam edge of its chart moves by ``(1 - d / width) / 2`` of the difference between the other photo's and its
    own colour at the nearest point of the edge, so both sides meet at their mean on the seam and keep their own
    colour ``width`` texels away (the nearest seam edge decides for a texel near several). Returns the texels
    changed."""
    fa, fb, v0, v1 = _seam_edges(labels, adjacency, adjacency_edges)
    if not len(fa):
        return 0
    H, W = atlas.shape[:2]
    img = atlas.astype(np.float32)
    k = int(np.ceil(width))
    idx_all, d_all, val_all = [], [], []
    for X, Y in ((fa, fb), (fb, fa)):
        x0 = tex[X, _corner_of(faces, X, v0)]
        x1 = tex[X, _corner_of(faces, X, v1)]
        y0 = tex[Y, _corner_of(faces, Y, v0)]
        y1 = tex[Y, _corner_of(faces, Y, v1)]
        r = face_rect[X]
        rlo = np.asarray(pos, np.int64)[r]
        rhi = rlo + np.asarray(size, np.int64)[r] - 1
        lo = np.maximum(np.floor(np.minimum(x0, x1)).astype(np.int64) - k, rlo)
        hi = np.minimum(np.ceil(np.maximum(x0, x1)).astype(np.int64) + k, rhi)
        nx, ny = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0), np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
        cnt = nx * ny
        e = np.repeat(np.arange(len(X)), cnt)
        j = np.arange(len(e)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        q = np.stack([lo[e, 0] + j % nx[e], lo[e, 1] + j // nx[e]], 1).astype(np.float64)
        seg = x1[e] - x0[e]
        t = np.clip(((q - x0[e]) * seg).sum(1) / np.maximum((seg * seg).sum(1), 1e-12), 0, 1)
        d = np.linalg.norm(q - (x0[e] + t[:, None] * seg), axis=1)
        near = d < width
        e, q, t, d = e[near], q[near].astype(np.int64), t[near], d[near]
        own = sample_bilinear(img, x0[e] + t[:, None] * (x1[e] - x0[e]))
        other = sample_bilinear(img, y0[e] + t[:, None] * (y1[e] - y0[e]))
        idx_all.append(q[:, 1] * W + q[:, 0])
        d_all.append(d)
        val_all.append((0.5 * (1 - d / width))[:, None] * (other - own))
    idx, d, val = np.concatenate(idx_all), np.concatenate(d_all), np.concatenate(val_all)
    order = np.lexsort((d, idx))
    idx, val = idx[order], val[order]
    first = np.r_[True, idx[1:] != idx[:-1]]
    idx, val = idx[first], val[first]
    flat = img.reshape(-1, img.shape[2])
    flat[idx, :3] += val[:, :3]
    atlas.reshape(-1, atlas.shape[2])[idx] = np.clip(flat[idx] + 0.5, 0, 255).astype(np.uint8)
    return int(len(idx))


def level_seams(atlas: np.ndarray, faces: np.ndarray, out_faces: np.ndarray, n_out: int, labels: np.ndarray,
                adjacency: np.ndarray, adjacency_edges: np.ndarray, tex: np.ndarray, face_rect: np.ndarray,
                pos: np.ndarray, size: np.ndarray, lam: float = LAMBDA, blend: float = BLEND) -> dict:
    """Global seam levelling of ``atlas`` in place (the module docstring): seam differences sampled from the
    atlas, offsets solved per output vertex, added to the texels; then local blending in a strip ``blend``
    texels wide along the seams (0 = none). Returns facts for the report."""
    a, b, diff = seam_differences(faces, out_faces, labels, adjacency, adjacency_edges, tex, atlas)
    seen = labels >= 0
    rect_of = np.zeros(n_out, np.int64)
    rect_of[out_faces[seen].reshape(-1)] = np.repeat(face_rect[seen], 3)
    n_pairs = len(a)
    ok = seam_inliers(rect_of[a] * (int(face_rect.max()) + 1) + rect_of[b], diff)
    a, b, diff = a[ok], b[ok], diff[ok]
    fo = out_faces[seen]
    reg = np.sort(np.concatenate([fo[:, [0, 1]], fo[:, [1, 2]], fo[:, [2, 0]]]), 1)
    key = np.unique(reg[:, 0] * np.int64(n_out) + reg[:, 1])  # each edge once
    reg = np.stack([key // n_out, key % n_out], 1)
    stats: dict = {}
    g = solve_offsets(n_out, a, b, diff, reg, lam, stats=stats)
    changed = apply_offsets(atlas, g, out_faces, tex, face_rect, pos, size)
    blended = blend_seams(atlas, faces, labels, adjacency, adjacency_edges, tex, face_rect, pos, size, blend) \
        if blend > 0 else 0
    step_before = float(np.abs(diff).mean()) if len(diff) else 0.0
    step_after = float(np.abs(diff - (g[a] - g[b])).mean()) if len(diff) else 0.0
    return {"seam_vertices": int(n_pairs), "seam_outliers": int(n_pairs - len(a)), "rectangles_changed": int(changed), "iterations": stats.get("iterations", 0),
            "texels_blended": blended,
            "seam_step_before": round(step_before, 2), "seam_step_after": round(step_after, 2),
            "mean_abs_offset": round(float(np.abs(g).mean()), 2) if len(g) else 0.0}


# --- the measure ----------------------------------------------------------------------------------------------
def seam_steps(mesh, atlas: np.ndarray, labels: np.ndarray, inset: float = 1.0) -> dict:
    """How much colour steps across chart borders of a textured mesh (``texture_mesh``'s output: ``mesh`` with
    UVs, ``atlas``, ``labels`` per face). For each pair of adjacent faces, the texture is sampled at three points
    along the shared edge, ``inset`` texels inside each face; the step is the mean absolute RGB difference
    (0-255) between the two sides. Returns the mean step over pairs with different photos (``seam``), over
    pairs with the same photo (``interior``: the texture's own change over that distance), their difference
    (``excess``) and the pair counts."""
    import trimesh

    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    N_h, N_w = atlas.shape[:2]
    uv = np.asarray(mesh.visual.uv, np.float64)
    tx = np.stack([uv[:, 0] * N_w - 0.5, (1.0 - uv[:, 1]) * N_h - 0.5], 1)
    _, first, pid = np.unique(V, axis=0, return_index=True, return_inverse=True)
    Fp = pid.reshape(-1)[F]
    merged = trimesh.Trimesh(V[first], Fp, process=False)
    adj = np.asarray(merged.face_adjacency, np.int64).reshape(-1, 2)
    edges = np.asarray(merged.face_adjacency_edges, np.int64).reshape(-1, 2)
    labels = np.asarray(labels)
    ok = (labels[adj[:, 0]] >= 0) & (labels[adj[:, 1]] >= 0)
    adj, edges = adj[ok], edges[ok]
    t = np.array([0.25, 0.5, 0.75])
    cols = []
    for f in adj.T:
        c0, c1 = _corner_of(Fp, f, edges[:, 0]), _corner_of(Fp, f, edges[:, 1])
        c2 = 3 - c0 - c1
        p0, p1, p2 = tx[F[f, c0]], tx[F[f, c1]], tx[F[f, c2]]
        e = p1 - p0
        height = np.abs(e[:, 0] * (p2 - p0)[:, 1] - e[:, 1] * (p2 - p0)[:, 0]) / np.maximum(np.linalg.norm(e, axis=1), 1e-12)
        s = np.minimum(inset / np.maximum(height, 1e-12), 0.45)[:, None, None]
        on = p0[:, None] * (1 - t)[None, :, None] + p1[:, None] * t[None, :, None]
        pts = on * (1 - s) + p2[:, None] * s
        cols.append(sample_bilinear(atlas, pts.reshape(-1, 2)).reshape(len(f), len(t), -1)[..., :3].astype(np.float64))
    step = np.abs(cols[0] - cols[1]).mean((1, 2)) if len(adj) else np.zeros(0)
    diff = labels[adj[:, 0]] != labels[adj[:, 1]]
    seam = float(step[diff].mean()) if diff.any() else 0.0
    interior = float(step[~diff].mean()) if (~diff).any() else 0.0
    return {"seam": seam, "interior": interior, "excess": seam - interior,
            "seam_pairs": int(diff.sum()), "interior_pairs": int((~diff).sum())}
