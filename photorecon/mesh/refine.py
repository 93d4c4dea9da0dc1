"""Photometric refinement of the fused mesh against the photos (``--refine``).

The fused mesh carries the TSDF's smoothing and voxel quantisation (about 1.5 pixel footprints). Refinement
moves each vertex along its normal to where the photos agree best, after Vu et al. (2012)'s mesh refinement,
in a search-and-regularise form:

1. visibility: a vertex is seen by a view when it lies in the image, faces the camera (cosine above
   ``MIN_COS``) and a ray from the camera hits the current mesh no nearer than 2 pixel footprints in front of
   it (Open3D ``RaycastingScene``);
2. views: the ``views`` visible views the surface faces most; the most frontal one is the reference;
3. data term (``patch_scores``, numba): for ``2 * STEPS + 1`` candidate offsets along the normal (up to
   ``RANGE`` pixel footprints of the reference view each side), a ``PATCH`` x ``PATCH`` grid on the tangent
   plane (one footprint apart) is projected into the reference and the other views; the score of an offset is
   the mean ZNCC of the reference patch with the others' (each clipped at 0: an occluded or blurred view
   weighs nothing rather than pulling). A parabola through the best score and its neighbours gives a sub-step
   offset; its weight grows with the best score (``weights``); a textureless patch (reference standard deviation
   below ``MIN_STD``) has none;
4. smoothness: the offsets, not the surface, are smoothed on the mesh graph (``smooth_offsets``: weighted
   Jacobi steps of ``(W + smooth * L) d = W d*``), so where the photos say nothing the vertex moves with its
   neighbours and existing detail is kept; then one umbrella step restricted to the normal
   (``umbrella_normal``) damps noise;
5. coarse to fine: ``levels`` image pyramid levels (each half the size of the one below), ``iterations``
   rounds per level, the search range shrinking each round.

Before refining, faces longer than ``MAX_EDGE`` footprints are split (``subdivide_long``): a mesh simplified
to a face budget has too few vertices to carry detail. The kernel (``patch_scores``) runs on all cores.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import trimesh
from numba import njit, prange

from ..cameras import View
from ..errors import BadArgumentError
from ..fields import check_config
from .geometry import face_edges

log = logging.getLogger("photorecon")

MIN_COS = 0.2  # a view sees a vertex under at most ~78 degrees from its normal
PATCH = 5  # patch side, samples (one reference pixel footprint apart)
STEPS = 4  # candidate offsets each side of the vertex
RANGE = 2.0  # search range of the first round of a level, reference pixel footprints each side
SHRINK = 0.6  # range factor from one round to the next
MIN_STD = 0.002  # a reference patch with a lower grey standard deviation (0..1; half an 8-bit level) is textureless
MAX_EDGE = 2.5  # faces with a longer edge (reference footprints, at the working size) are split first
MAX_VERTICES = 8_000_000  # subdivision stops before this many vertices
UMBRELLA = 0.2  # umbrella step along the normal, per round


@dataclass
class RefineConfig:
    """Settings of the photometric mesh refinement (``reconstruct --refine``)."""

    refine: bool = field(default=False, metadata={"help": "refine the fused mesh against the photos: vertices move along their normals to where the views agree best (ZNCC), with a smoothness term, coarse to fine; report.json's mesh.refine has its time and mean displacement"})
    refine_levels: int = field(default=2, metadata={"help": "refinement: image pyramid levels, coarse to fine (1 = the working size only)", "range": (1, 6)})
    refine_iterations: int = field(default=3, metadata={"help": "refinement: rounds per pyramid level (the search range shrinks each round)", "range": (1, 50)})
    refine_views: int = field(default=4, metadata={"help": "refinement: views compared per vertex (the most frontal is the reference)", "range": (2, 32)})
    refine_smooth: float = field(default=1.0, metadata={"help": "refinement: weight of the smoothness term against the photos (0 = photos only)", "range": (0.0, 1000.0)})
    refine_max_size: int = field(default=1600, metadata={"help": "refinement: longest image side used, pixels (0 = the photos' size)", "range": (64, 65536), "also": (0,)})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.fields)


# --- the numba kernels ------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _sample(img, P, x, y, z, w, h):
    """Bilinear grey value at the projection of (x, y, z) by the 3x4 ``P`` (pixel (0, 0) at the centre of the
    top-left pixel), NaN outside the image or behind the camera."""
    zc = P[2, 0] * x + P[2, 1] * y + P[2, 2] * z + P[2, 3]
    if zc <= 0:
        return np.nan
    u = (P[0, 0] * x + P[0, 1] * y + P[0, 2] * z + P[0, 3]) / zc
    v = (P[1, 0] * x + P[1, 1] * y + P[1, 2] * z + P[1, 3]) / zc
    if not (u >= 0.0 and v >= 0.0 and u <= w - 1.0 and v <= h - 1.0):
        return np.nan
    u0 = min(int(u), w - 2)
    v0 = min(int(v), h - 2)
    a = u - u0
    b = v - v0
    return ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1]
            + (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])


@njit(cache=True, inline="always")
def _patch(img, P, pts, w, h, out):
    """``_sample`` at each of ``pts`` (S, 3) into ``out`` (S,); returns their mean, NaN when one is outside."""
    m = 0.0
    for k in range(pts.shape[0]):
        out[k] = _sample(img, P, pts[k, 0], pts[k, 1], pts[k, 2], w, h)
        if not np.isfinite(out[k]):
            return np.nan
        m += out[k]
    return m / pts.shape[0]


@njit(cache=True, parallel=True)
def patch_scores(pos, nrm, t1, t2, spacing, step, offsets, sel, P, imgs, sizes, half, min_std):
    """Photo-consistency of candidate positions: (V, C) float32, NaN where not scored.

    Vertex ``v``'s candidate ``c`` is ``pos[v] + offsets[c] * step[v] * nrm[v]``; its patch is the
    ``(2 half + 1)^2`` grid ``a t1[v] + b t2[v]`` (a, b in -half..half, times ``spacing[v]``) around it. Its score
    is the mean over the views ``sel[v, 1:]`` (-1 = none) of max(0, ZNCC) with the reference view ``sel[v, 0]``;
    NaN when the reference patch leaves the image or its standard deviation is below ``min_std``, or no other
    view sees the whole patch. ``P``: (n_views, 3, 4) projections; ``imgs``: (n_views, H, W) grey float32, view
    ``i`` occupying ``[:sizes[i, 1], :sizes[i, 0]]``."""
    V = pos.shape[0]
    C = offsets.shape[0]
    K = sel.shape[1]
    side = 2 * half + 1
    S = side * side
    out = np.full((V, C), np.nan, np.float32)
    for v in prange(V):
        r = sel[v, 0]
        if r < 0 or K < 2 or sel[v, 1] < 0:
            continue
        pts = np.empty((S, 3))
        ref = np.empty(S)
        oth = np.empty(S)
        for c in range(C):
            d = offsets[c] * step[v]
            k = 0
            for a in range(-half, half + 1):
                for b in range(-half, half + 1):
                    for q in range(3):
                        pts[k, q] = pos[v, q] + d * nrm[v, q] + (a * t1[v, q] + b * t2[v, q]) * spacing[v]
                    k += 1
            mr = _patch(imgs[r], P[r], pts, sizes[r, 0], sizes[r, 1], ref)
            if not np.isfinite(mr):
                continue
            vr = 0.0
            for k in range(S):
                ref[k] -= mr
                vr += ref[k] * ref[k]
            if vr < S * min_std * min_std:
                continue
            total = 0.0
            n = 0
            for j in range(1, K):
                o = sel[v, j]
                if o < 0:
                    break
                mo = _patch(imgs[o], P[o], pts, sizes[o, 0], sizes[o, 1], oth)
                if not np.isfinite(mo):
                    continue
                vo = 0.0
                cross = 0.0
                for k in range(S):
                    e = oth[k] - mo
                    vo += e * e
                    cross += e * ref[k]
                z = cross / np.sqrt(vr * vo) if vo > 1e-12 else 0.0
                total += max(z, 0.0)
                n += 1
            if n:
                out[v, c] = total / n
    return out


@njit(cache=True)
def smooth_offsets(d_star, w, indptr, nbr, lam, iterations):
    """Weighted Jacobi steps of ``(W + lam L) d = W d_star`` on the mesh graph (CSR ``indptr``, ``nbr``):
    where the weight ``w`` is 0 the offset becomes its neighbours' mean."""
    d = d_star * (w > 0)
    for _ in range(iterations):
        new = np.empty_like(d)
        for i in range(d.shape[0]):
            s = 0.0
            m = indptr[i + 1] - indptr[i]
            for k in range(indptr[i], indptr[i + 1]):
                s += d[nbr[k]]
            den = w[i] + lam * m
            new[i] = (w[i] * d_star[i] + lam * s) / den if den > 0 else 0.0
        d = new
    return d


@njit(cache=True)
def umbrella_normal(pos, nrm, indptr, nbr, mu):
    """One umbrella (graph Laplacian) step restricted to the normal: each vertex moves ``mu`` of the way towards
    its neighbours' mean, along its normal only (no sliding along the surface)."""
    out = pos.copy()
    for i in range(pos.shape[0]):
        m = indptr[i + 1] - indptr[i]
        if m == 0:
            continue
        dot = 0.0
        for q in range(3):
            s = 0.0
            for k in range(indptr[i], indptr[i + 1]):
                s += pos[nbr[k], q]
            dot += (s / m - pos[i, q]) * nrm[i, q]
        for q in range(3):
            out[i, q] = pos[i, q] + mu * dot * nrm[i, q]
    return out


# --- geometry helpers -------------------------------------------------------------------------------------
def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (a vertex of no face gets +z)."""
    fn = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    n = np.zeros_like(vertices)
    for q in range(3):
        for c in range(3):
            n[:, q] += np.bincount(faces[:, c], fn[:, q], minlength=len(vertices))
    norm = np.linalg.norm(n, axis=1)
    n[norm == 0] = (0.0, 0.0, 1.0)
    return n / np.where(norm > 0, norm, 1.0)[:, None]


def tangents(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane normal to each of ``n`` (N, 3)."""
    axis = np.zeros_like(n)
    axis[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    t1 = np.cross(n, axis)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(n, t1)


def adjacency(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's vertex graph as CSR (indptr, neighbours), each edge once per direction."""
    e = face_edges(faces)
    e = np.concatenate([e, e[:, ::-1]])
    e = np.unique(e, axis=0) if len(e) < 4_000_000 else e[np.unique(e[:, 0] * n_vertices + e[:, 1],
                                                                    return_index=True)[1]]
    order = np.argsort(e[:, 0], kind="stable")
    e = e[order]
    indptr = np.zeros(n_vertices + 1, np.int64)
    np.cumsum(np.bincount(e[:, 0], minlength=n_vertices), out=indptr[1:])
    return indptr, e[:, 1].astype(np.int64)


def border_vertices(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(V,) bool: the vertices on an edge that only one face uses (the rims of holes and of open surfaces)."""
    e = np.sort(face_edges(faces), axis=1).astype(np.int64)
    keys, counts = np.unique(e[:, 0] * n_vertices + e[:, 1], return_counts=True)
    rim = keys[counts == 1]
    out = np.zeros(n_vertices, bool)
    out[rim // n_vertices] = True
    out[rim % n_vertices] = True
    return out


def parabola_offsets(scores: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``scores`` (V, C; NaN = not scored): the best offset refined by a parabola through the best
    score and its two neighbours (in ``offsets``' units), and the best score (NaN where nothing was scored)."""
    s = np.where(np.isfinite(scores), scores, -1.0)
    best = np.argmax(s, axis=1)
    rows = np.arange(len(s))
    sb = s[rows, best]
    C = s.shape[1]
    inner = (best > 0) & (best < C - 1)
    lo = s[rows, np.maximum(best - 1, 0)]
    hi = s[rows, np.minimum(best + 1, C - 1)]
    den = lo - 2 * sb + hi
    frac = np.where(inner & (den < -1e-9) & (lo > -1) & (hi > -1), 0.5 * (lo - hi) / np.where(den < -1e-9, den, -1.0), 0.0)
    h = offsets[1] - offsets[0] if C > 1 else 0.0
    off = offsets[best] + np.clip(frac, -0.5, 0.5) * h
    return off, np.where(sb > -1, sb, np.nan)


def weights(best: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """Trust in a vertex's best offset: 0 below a mean ZNCC of 0.3, 1 from 0.8; times how much the best
    stands out from the candidates' mean (a flat score curve says little about the offset); 0 unless every
    candidate was scored."""
    import warnings

    with warnings.catch_warnings(), np.errstate(invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # a row with no score: its mean is NaN, weight 0
        contrast = best - np.nanmean(scores, axis=1)
    w = np.clip((best - 0.3) / 0.5, 0, 1) * np.clip(contrast / 0.1, 0, 1)
    # every candidate scored: else the best may be the only textured one (a plain patch whose far candidates
    # reach an edge), not the truth
    return np.where(np.isfinite(w) & np.isfinite(scores).all(axis=1), w, 0.0)


def subdivide_long(mesh: trimesh.Trimesh, max_edge: np.ndarray | float, max_vertices: int = MAX_VERTICES,
                   rounds: int = 4) -> trimesh.Trimesh:
    """Split (1-to-4, vertex colours interpolated) the faces with an edge longer than ``max_edge`` (scene units,
    one per vertex or one for all), up to ``rounds`` times and while under ``max_vertices`` vertices."""
    from trimesh.remesh import subdivide

    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    colors = mesh.visual.vertex_colors if mesh.visual.kind == "vertex" else None
    limit = np.broadcast_to(np.asarray(max_edge, float), (len(v),)).reshape(-1, 1)
    for _ in range(rounds):
        e = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2).max(1)
        long = np.flatnonzero(e > limit[f, 0].min(1))
        if not len(long) or len(v) + 3 * len(long) > max_vertices:
            break
        attrs = {"limit": limit} if colors is None else {"limit": limit, "color": colors.astype(float)}
        v, f, attrs = subdivide(v, f, face_index=long, vertex_attributes=attrs)
        limit = attrs["limit"]
        colors = attrs.get("color")
    out = trimesh.Trimesh(v, f, process=False,
                          vertex_colors=None if colors is None else np.clip(np.round(colors), 0, 255).astype(np.uint8))
    out.metadata.update(mesh.metadata)
    return out


# --- views ------------------------------------------------------------------------------------------------
@dataclass
class _Level:
    """The views at one pyramid level: projections, images stacked (zero-padded) and focal lengths."""

    P: np.ndarray  # (n, 3, 4)
    imgs: np.ndarray  # (n, H, W) float32
    sizes: np.ndarray  # (n, 2) int32: width, height
    focal: np.ndarray  # (n,) mean of fx, fy


def _level(views: list[View], grey: list[np.ndarray], factor: float) -> _Level:
    import cv2

    Ps, ims, sizes, focal = [], [], [], []
    for v, g in zip(views, grey):
        h, w = g.shape
        W, H = max(8, round(w * factor)), max(8, round(h * factor))
        im = g if (W, H) == (w, h) else cv2.resize(g, (W, H), interpolation=cv2.INTER_AREA)
        intr = v.intrinsics.scaled(W, H)
        Ps.append(intr.K @ np.asarray(v.cam_from_world, float)[:3, :4])
        ims.append(im)
        sizes.append((W, H))
        focal.append(0.5 * (intr.fx + intr.fy))
    Hm, Wm = max(s[1] for s in sizes), max(s[0] for s in sizes)
    stack = np.zeros((len(ims), Hm, Wm), np.float32)
    for i, im in enumerate(ims):
        stack[i, :im.shape[0], :im.shape[1]] = im
    return _Level(np.array(Ps), stack, np.array(sizes, np.int32), np.array(focal))


def _scaled_views(views: list[View], grey: list[np.ndarray]) -> list[View]:
    """The views with intrinsics for their grey images' sizes."""
    out = []
    for v, g in zip(views, grey):
        h, w = g.shape
        intr = v.intrinsics if v.intrinsics.size == (w, h) else v.intrinsics.scaled(w, h)
        out.append(View(v.name, intr, v.cam_from_world))
    return out


def visibility(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray, views: list[View],
               lvl: _Level) -> tuple[np.ndarray, np.ndarray]:
    """Which views see which vertices: (cos (n_views, V) float32, 0 where not seen; depth (n_views, V)).
    Seen: inside the image, facing the camera (cosine >= ``MIN_COS``), and no surface of the mesh more than 2
    pixel footprints in front of the vertex along the camera's ray."""
    from . import raycasting_scene
    import open3d as o3d

    scene = raycasting_scene(trimesh.Trimesh(vertices, faces, process=False))
    n = len(views)
    cos = np.zeros((n, len(vertices)), np.float32)
    depth = np.zeros((n, len(vertices)), np.float32)
    for i, v in enumerate(views):
        c = v.center
        d = vertices - c
        dist = np.linalg.norm(d, axis=1)
        cs = -np.einsum("nc,nc->n", normals, d) / np.maximum(dist, 1e-12)
        P = lvl.P[i]
        z = vertices @ P[2, :3] + P[2, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (vertices @ P[0, :3] + P[0, 3]) / z
            w = (vertices @ P[1, :3] + P[1, 3]) / z
        W, H = lvl.sizes[i]
        cand = np.flatnonzero((cs >= MIN_COS) & (z > 0) & (u >= 0) & (w >= 0) & (u <= W - 1) & (w <= H - 1))
        if not len(cand):
            continue
        rays = np.concatenate([np.broadcast_to(c, (len(cand), 3)), d[cand]], axis=1).astype(np.float32)
        t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        tol = 2.0 * z[cand] / lvl.focal[i]  # two pixel footprints
        seen = ~(np.isfinite(t) & ((1.0 - t) * dist[cand] > tol))  # a miss: the ray slipped past its own vertex
        cos[i, cand[seen]] = cs[cand[seen]]
        depth[i, cand[seen]] = z[cand[seen]]
    return cos, depth


def select_views(cos: np.ndarray, k: int) -> np.ndarray:
    """Per vertex, the ``k`` views with the largest cosines (seen ones only; -1 pads), most frontal first:
    (V, k) int32."""
    k = min(k, cos.shape[0])
    order = np.argsort(-cos, axis=0, kind="stable")[:k].T.astype(np.int32)
    seen = np.take_along_axis(cos.T, order, axis=1) > 0
    return np.where(seen, order, -1)


# --- the refinement ---------------------------------------------------------------------------------------
def refine_mesh(mesh: trimesh.Trimesh, views: list[View], grey: list[np.ndarray], cfg: RefineConfig,
                subdivide: bool = True) -> tuple[trimesh.Trimesh, dict]:
    """``mesh`` refined against the photos ``grey`` (one float32 image in 0..1 per view, any size: the views'
    intrinsics are scaled to it). Returns the refined mesh (same faces unless ``subdivide`` split long ones)
    and its facts: seconds, CPU seconds, vertices before and after, mean and 95th-percentile displacement
    (scene units), the share of vertices the photos moved (weight > 0) in the last round."""
    if len(views) != len(grey):
        raise BadArgumentError(f"refine: {len(views)} views but {len(grey)} images")
    if any(v.intrinsics.has_distortion for v in views):
        raise BadArgumentError("refine: the views must be undistorted pinhole cameras (undistort the images first)")
    t0, c0 = time.perf_counter(), time.process_time()
    views = _scaled_views(views, grey)
    faces = np.asarray(mesh.faces, np.int64)
    verts = np.asarray(mesh.vertices, float)
    info = {"vertices_before": len(verts)}
    fine = _level(views, grey, 1.0)
    if subdivide and len(faces) and len(views) >= 2:
        cos, depth = visibility(verts, faces, vertex_normals(verts, faces), views, fine)
        ref = np.argmax(cos, axis=0)
        fp = depth[ref, np.arange(len(verts))] / fine.focal[ref]
        fp = np.where(fp > 0, fp, np.inf)  # a vertex no view sees: nothing to gain from splitting
        mesh = subdivide_long(trimesh.Trimesh(verts, faces, process=False, vertex_colors=mesh.visual.vertex_colors
                                              if mesh.visual.kind == "vertex" else None), MAX_EDGE * fp)
        faces, verts = np.asarray(mesh.faces, np.int64), np.asarray(mesh.vertices, float)
    start = verts.copy()
    indptr, nbr = adjacency(faces, len(verts))
    inner = ~border_vertices(faces, len(verts))  # a patch at the mesh's border reaches past it: no data term
    offsets = np.linspace(-1.0, 1.0, 2 * STEPS + 1)
    moved = 0.0
    for level in range(cfg.refine_levels - 1, -1, -1):
        lvl = fine if level == 0 else _level(views, grey, 0.5 ** level)
        for it in range(cfg.refine_iterations):
            normals = vertex_normals(verts, faces)
            cos, depth = visibility(verts, faces, normals, views, lvl)
            sel = select_views(cos, cfg.refine_views)
            rows = np.arange(len(verts))
            r = np.maximum(sel[:, 0], 0)
            footprint = np.where(sel[:, 0] >= 0, depth[r, rows] / lvl.focal[r], 0.0)
            step = footprint * RANGE * SHRINK ** it
            t1, t2 = tangents(normals)
            scores = patch_scores(verts, normals, t1, t2, footprint, step, offsets, sel, lvl.P, lvl.imgs,
                                  lvl.sizes, PATCH // 2, MIN_STD)
            off, best = parabola_offsets(scores, offsets)
            w = weights(best, scores) * inner
            d = smooth_offsets(off * step, w, indptr, nbr, cfg.refine_smooth, 10)
            verts = verts + d[:, None] * normals
            if cfg.refine_smooth > 0:
                verts = umbrella_normal(verts, vertex_normals(verts, faces), indptr, nbr,
                                        UMBRELLA * min(1.0, cfg.refine_smooth))
            moved = float((w > 0).mean())
            log.debug("refine: level %d round %d: %.0f%% of the vertices scored, mean |offset| %.3g", level, it,
                      100 * moved, float(np.abs(d).mean()))
    disp = np.linalg.norm(verts - start, axis=1)
    out = trimesh.Trimesh(verts, faces, process=False,
                          vertex_colors=mesh.visual.vertex_colors if mesh.visual.kind == "vertex" else None)
    out.metadata.update(mesh.metadata)
    info.update(vertices=len(verts), faces=len(faces), seconds=round(time.perf_counter() - t0, 2),
                cpu_seconds=round(time.process_time() - c0, 2),
                mean_displacement=float(disp.mean()) if len(disp) else 0.0,
                p95_displacement=float(np.percentile(disp, 95)) if len(disp) else 0.0,
                photo_weighted_fraction=moved)
    return out, info


def grey_images(ds, views: list[View], max_size: int) -> list[np.ndarray]:
    """The dataset's images of ``views`` as grey float32 in 0..1, the longest side at most ``max_size``
    (0 = as they are)."""
    import cv2

    out = []
    for v in views:
        img = ds.image(v)
        g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
        g = g.astype(np.float32) / (65535.0 if g.dtype == np.uint16 else 255.0)
        h, w = g.shape
        s = max_size / max(h, w) if max_size else 1.0
        if s < 1:
            g = cv2.resize(g, (max(8, round(w * s)), max(8, round(h * s))), interpolation=cv2.INTER_AREA)
        out.append(g)
    return out


def refine_dataset(mesh: trimesh.Trimesh, ds, cfg: RefineConfig, subdivide: bool = True) -> tuple[trimesh.Trimesh, dict]:
    """``refine_mesh`` against a dataset's photos (``grey_images``); logs what it did."""
    views = list(ds.views)
    mesh, info = refine_mesh(mesh, views, grey_images(ds, views, cfg.refine_max_size), cfg, subdivide)
    log.info("refine: %d vertices moved %.3g on average (95%%: %.3g) in %.1f s", info["vertices"],
             info["mean_displacement"], info["p95_displacement"], info["seconds"])
    return mesh, info
