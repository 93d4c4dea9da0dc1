"""Photometric refinement of the fused mesh against the photos (``--refine``).

The fused mesh carries the TSDF's smoothing and voxel quantisation (about 1.5 pixel footprints). Refinement
moves each vertex along its normal to where the photos agree best, after Vu et al. (2012)'s mesh refinement,
in a search-and-regularise form:

1. visibility: a vertex is seen by a view when it lies in the image, faces the camera (cosine above
   ``MIN_COS``) and a ray from the camera hits the current mesh no nearer than 2 pixel footprints in front of
   it (Open3D ``RaycastingScene``). The rays are cast in a level's first round only (a round moves a vertex
   by less than those 2 footprints); the later rounds redo the facing test with the new normals (``facing``);
2. views: the ``views`` visible views the surface faces most; the most frontal one is the reference;
3. data term (``patch_scores``, numba): for ``2 * STEPS + 1`` candidate offsets along the normal (up to
   ``RANGE`` pixel footprints of the reference view each side; ``2 * LATER_STEPS + 1`` in a level's later
   rounds, whose range has shrunk), a ``PATCH`` x ``PATCH`` grid on the tangent
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

from ..cameras import View
from ..errors import BadArgumentError
from ..config_checks import check_config
from ..jit import njit, prange
from .geometry import face_edges
from .refine_views import MIN_COS, _level, _scaled_views, facing, select_views, visibility

log = logging.getLogger("photorecon")

PATCH = 5  # patch side, samples (one reference pixel footprint apart)
STEPS = 4  # candidate offsets each side of the vertex in a level's first round
LATER_STEPS = 2  # in its later rounds, whose range has shrunk (0.6 and 0.36 footprints apart, the parabola between)
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
        check_config(self)  # types, choices and ranges as declared (photorecon.config_checks)


# --- the numba kernels ------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _bilinear(img, hx, hy, hz, w, h):
    """Bilinear grey value at the homogeneous image point (hx, hy, hz) (pixel (0, 0) at the centre of the
    top-left pixel), NaN outside the image or behind the camera."""
    if hz <= 0:
        return np.nan
    u = hx / hz
    v = hy / hz
    if not (u >= 0.0 and v >= 0.0 and u <= w - 1.0 and v <= h - 1.0):
        return np.nan
    u0 = min(int(u), w - 2)
    v0 = min(int(v), h - 2)
    a = u - u0
    b = v - v0
    return ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1]
            + (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])


@njit(cache=True, inline="always")
def _patch_h(img, Pv, base, d, half, w, h, out):
    """The patch's samples in one view into ``out`` (S,); returns their mean, NaN when one is outside. ``Pv``
    (4, 3): the view's projection of the vertex, its normal and its two tangent steps (homogeneous image
    coordinates, linear in the point), so that sample (a, b) at offset ``d`` projects to
    ``Pv[0] + d Pv[1] + a Pv[2] + b Pv[3]``; ``base`` (3,) scratch."""
    for q in range(3):
        base[q] = Pv[0, q] + d * Pv[1, q]
    m = 0.0
    k = 0
    for a in range(-half, half + 1):
        for b in range(-half, half + 1):
            x = _bilinear(img, base[0] + a * Pv[2, 0] + b * Pv[3, 0], base[1] + a * Pv[2, 1] + b * Pv[3, 1],
                          base[2] + a * Pv[2, 2] + b * Pv[3, 2], w, h)
            if not np.isfinite(x):
                return np.nan
            out[k] = x
            m += x
            k += 1
    return m / k


@njit(cache=True, inline="always")
def _project_frame(P, pos, nrm, t1, t2, spacing, v, out):
    """``out`` (4, 3): ``P`` applied to vertex ``v``'s position (homogeneous), its normal and its tangents times
    ``spacing[v]`` (directions)."""
    for q in range(3):
        out[0, q] = P[q, 0] * pos[v, 0] + P[q, 1] * pos[v, 1] + P[q, 2] * pos[v, 2] + P[q, 3]
        out[1, q] = P[q, 0] * nrm[v, 0] + P[q, 1] * nrm[v, 1] + P[q, 2] * nrm[v, 2]
        out[2, q] = (P[q, 0] * t1[v, 0] + P[q, 1] * t1[v, 1] + P[q, 2] * t1[v, 2]) * spacing[v]
        out[3, q] = (P[q, 0] * t2[v, 0] + P[q, 1] * t2[v, 1] + P[q, 2] * t2[v, 2]) * spacing[v]


@njit(cache=True, parallel=True)
def patch_scores(pos, nrm, t1, t2, spacing, step, offsets, sel, P, imgs, sizes, half, min_std):
    """Photo-consistency of candidate positions: (V, C) float32, NaN where not scored.

    Vertex ``v``'s candidate ``c`` is ``pos[v] + offsets[c] * step[v] * nrm[v]``; its patch is the
    ``(2 half + 1)^2`` grid ``a t1[v] + b t2[v]`` (a, b in -half..half, times ``spacing[v]``) around it. Its score
    is the mean over the views ``sel[v, 1:]`` (-1 = none) of max(0, ZNCC) with the reference view ``sel[v, 0]``;
    NaN when the reference patch leaves the image or its standard deviation is below ``min_std``, or no other
    view sees the whole patch. ``P``: (n_views, 3, 4) projections; ``imgs``: (n_views, H, W) grey float32, view
    ``i`` occupying ``[:sizes[i, 1], :sizes[i, 0]]``. A projection is linear in homogeneous coordinates, so each
    view projects the vertex's frame once and every sample of every candidate is a sum of those."""
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
        frames = np.empty((K, 4, 3))
        for j in range(K):
            if sel[v, j] >= 0:
                _project_frame(P[sel[v, j]], pos, nrm, t1, t2, spacing, v, frames[j])
        base = np.empty(3)
        ref = np.empty(S)
        oth = np.empty(S)
        for c in range(C):
            d = offsets[c] * step[v]
            mr = _patch_h(imgs[r], frames[0], base, d, half, sizes[r, 0], sizes[r, 1], ref)
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
                mo = _patch_h(imgs[o], frames[j], base, d, half, sizes[o, 0], sizes[o, 1], oth)
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
@njit(cache=True)
def _vertex_normal_sums(vertices, faces):
    """Per vertex, the sum of its faces' cross products (area-weighted normals, not yet unit)."""
    out = np.zeros_like(vertices)
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        # the cross product of two edges (twice the face's area along its normal), in scalars: no array per face
        e1x, e1y, e1z = vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1], vertices[b, 2] - vertices[a, 2]
        e2x, e2y, e2z = vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1], vertices[c, 2] - vertices[a, 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        for i in (a, b, c):
            out[i, 0] += nx
            out[i, 1] += ny
            out[i, 2] += nz
    return out


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (a vertex of no face gets +z)."""
    n = _vertex_normal_sums(np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(faces, np.int64))
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
        # the footprint in the most frontal view decides the splitting: occlusion can wait
        cos, depth = visibility(verts, faces, vertex_normals(verts, faces), views, fine, occlusion=False)
        ref = np.argmax(cos, axis=0)
        fp = depth[ref, np.arange(len(verts))] / fine.focal[ref]
        fp = np.where(fp > 0, fp, np.inf)  # a vertex no view sees: nothing to gain from splitting
        mesh = subdivide_long(trimesh.Trimesh(verts, faces, process=False, vertex_colors=mesh.visual.vertex_colors
                                              if mesh.visual.kind == "vertex" else None), MAX_EDGE * fp)
        faces, verts = np.asarray(mesh.faces, np.int64), np.asarray(mesh.vertices, float)
    start = verts.copy()
    indptr, nbr = adjacency(faces, len(verts))
    inner = ~border_vertices(faces, len(verts))  # a patch at the mesh's border reaches past it: no data term
    centres = np.array([v.center for v in views], float).reshape(-1, 3)
    moved = 0.0
    for level in range(cfg.refine_levels - 1, -1, -1):
        lvl = fine if level == 0 else _level(views, grey, 0.5 ** level)
        for it in range(cfg.refine_iterations):
            normals = vertex_normals(verts, faces)
            if it == 0:
                # occlusion is tested once per level: a round moves the vertices by less than the 2 footprints
                # its test allows; the facing test follows the normals every round
                cos, depth = visibility(verts, faces, normals, views, lvl)
                seen = cos > 0
            else:
                cos, depth = facing(verts, normals, centres, lvl.P, seen, MIN_COS)
            sel = select_views(cos, cfg.refine_views)
            rows = np.arange(len(verts))
            r = np.maximum(sel[:, 0], 0)
            footprint = np.where(sel[:, 0] >= 0, depth[r, rows] / lvl.focal[r], 0.0)
            step = footprint * RANGE * SHRINK ** it
            t1, t2 = tangents(normals)
            offsets = np.linspace(-1.0, 1.0, 2 * (STEPS if it == 0 else LATER_STEPS) + 1)
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
