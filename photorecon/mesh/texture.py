"""UV-textured meshes from the photos: one view per face, exposure evened out, baked into one atlas.

The steps (``texture_mesh``):

1. **Which views see each face** (``face_view_quality``): a face counts as seen in a view when its centroid
   projects inside the image (and its mask), all three corners are in front of the camera and inside the image,
   it is not seen edge-on (``|cos| >= min_cos`` between its normal and the ray), and a ray from the camera
   centre to the centroid hits nothing before it (a depth test against the mesh itself, Open3D
   ``RaycastingScene``). The quality of a (face, view) pair is the face's projected area in pixels: it grows
   with image resolution, falls with distance and with the viewing angle, all in one number.
2. **Exposure** (``estimate_gains``): per-view, per-channel gains from the faces that several views see,
   least squares in log space (``log colour = log gain[view] + log albedo[face]``, geometric mean gain 1).
3. **Photo-consistency** (``photo_outliers``): a view whose (gain-corrected) colour of a face is far from the
   median over the face's views is not used for it: it shows something other than the face there (MVS-Texturing's
   outlier test, Waechter et al. 2014). Colours for 2 and 3 come from one pass (``sample_face_colors``).
4. **One view per face** (``select_views``): the best view, then a few rounds of label smoothing over the
   face adjacency (a Potts term: a face takes its neighbours' view unless its own is clearly better), so the
   texture changes source at few seams.
5. **Charts and atlas**: connected faces with the same view form a chart whose UVs are the faces' projections
   into that view's image (no distortion, texel density = the photo's, as in Waechter et al., ECCV 2014);
   overlapping charts of one view are merged, and the charts' rectangles are shelf-packed into a square
   atlas at the largest common scale (<= 1 texel per photo pixel) that fits. Baking copies each rectangle
   out of its (exposure-corrected) photo with ``padding`` texels of the photo's own pixels around it, so
   bilinear filtering at chart borders sees real image content, not black.
   Faces no view sees get a small flat-colour cell, its colour diffused from the seen faces around them.
6. **Seam levelling** (``seams.level_seams``, ``seam_levelling``, on by default): where neighbouring faces take
   different photos, the colours along the seam still differ a little (gains that do not fit exactly, light that
   changes with the viewing direction; a lot where ``exposure`` is off). As in Waechter et al. (ECCV 2014) and
   OpenMVS, every output vertex (one per mesh vertex and chart, so a seam vertex has one per photo meeting there)
   gets an RGB offset: least squares over the colour differences at the seam vertices (sampled along the seam
   edges in the baked atlas) plus a term that keeps the offsets of neighbouring vertices of one chart close,
   so each correction spreads smoothly over its chart. The offsets are added to the atlas, interpolated over
   each triangle, and carried into the padding from the nearest texel of a chart. Then a strip of 2 texels on
   each side of every seam is blended linearly towards the other photo's colour on the seam (what the offsets,
   one per vertex, leave along the seam).

Outputs (``export_textured``, written atomically into one folder): ``mesh.obj`` + ``mesh.mtl`` +
``texture.png`` and ``mesh.glb`` with the texture embedded (PBR base colour). UVs follow the OBJ / glTF
convention: ``u`` right, ``v`` up (row 0 of the PNG is ``v = 1``), texel centre ``i`` at ``(i + 0.5) / N``.
"""
from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import trimesh

from ..cameras import View, project
from ..errors import BadArgumentError, EmptyMeshError, InputDataError, TextureError
from ..io.images import sample_bilinear
from ..layout import Layout
from ..progress import bar
from ..resources import available_bytes
from .atlas import _Charts, _merge_boxes, _rect_layout, make_charts, pack_charts, shelf_pack
from .seams import level_seams
from .solve import harmonic_fill
from ..config_checks import check_config, expect_config

log = logging.getLogger("photorecon")


MAX_ATLAS = 65536

TEXTURED_FILES = ("mesh.obj", "mesh.mtl", "texture.png", "mesh.glb")


@dataclass
class TextureConfig:
    """Settings of the texturing stage (``reconstruct --texture``, ``photorecon texture``)."""

    atlas_size: int = field(default=4096, metadata={"help": "texture atlas width and height, texels", "range": (256, MAX_ATLAS)})
    texture_faces: int = field(default=0, metadata={"help": "simplify the mesh to about this many faces before texturing (0 = keep it)", "range": (4, 2_000_000_000), "also": (0,)})
    padding: int = field(default=2, metadata={"help": "texels of photo kept around every chart (against seams under filtering and mip-mapping)", "range": (0, 64)})
    min_cos: float = field(default=0.1, metadata={"help": "a view sees a face only if |cos(normal, ray)| >= this", "range": (0.0, 0.999)})
    smoothness: float = field(default=0.4, metadata={"help": "label smoothing: cost of a neighbour with another view, relative to a face's best-to-worst quality range", "range": (0.0, 1000.0)})
    smooth_rounds: int = field(default=6, metadata={"help": "rounds of label smoothing over the face adjacency (0 = best view per face)", "range": (0, 10_000)})
    exposure: bool = field(default=True, metadata={"help": "even out exposure between views (per-view gains)"})
    consistency: float = field(default=20.0, metadata={"help": "a view whose colour of a face is farther than this RGB distance (0-255) from the median is not used for it (0 = off)", "range": (0.0, 1000.0)})
    seam_levelling: bool = field(default=True, metadata={"help": "even out the colour steps where neighbouring faces take different photos (per-vertex colour offsets, least squares, spread smoothly over each chart)"})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.config_checks)


@dataclass
class Textured:
    mesh: trimesh.Trimesh  # with TextureVisuals (uv per vertex, material image = the atlas)
    atlas: np.ndarray  # (N, N, 3) uint8
    labels: np.ndarray  # (F,) view index per face of the input mesh, -1 = seen by no view
    gains: np.ndarray  # (V, 3) per-view, per-channel gains the photos were divided by
    info: dict


def check_atlas_memory(atlas_size: int) -> None:
    """Refuse an atlas that would not fit in memory: the atlas, its PNG encoding and the GLB's copy."""
    need = atlas_size * atlas_size * 3 * 4
    avail = available_bytes()
    if need > avail:
        raise TextureError(f"--atlas-size {atlas_size}: the atlas needs about {need / 2**30:.1f} GB of memory, "
                           f"{avail / 2**30:.1f} GB are available; use a smaller --atlas-size (e.g. 4096 or 8192)")


# --- 1. visibility and quality ----------------------------------------------------------------------------
def face_view_quality(mesh: trimesh.Trimesh, views: list[View], masks: Callable[[View], np.ndarray | None] | None = None,
                      min_cos: float = 0.1, scene=None) -> np.ndarray:
    """(F, V) float32: the projected area in pixels of face f in view v where v sees f (see the module
    docstring), else 0."""
    from .convert import raycasting_scene
    import open3d as o3d

    scene = scene or raycasting_scene(mesh)
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    cent = V[F].mean(1)
    normals = np.asarray(mesh.face_normals, np.float64)
    size = np.linalg.norm(V[F] - V[np.roll(F, 1, axis=1)], axis=2).max(1)  # longest edge
    q = np.zeros((len(F), len(views)), np.float32)
    for k, view in enumerate(bar(views, desc="texture: visibility")):
        W, H = view.intrinsics.size
        uv, z = project(V, view.intrinsics, view.cam_from_world)
        tri = uv[F]  # (F, 3, 2)
        with np.errstate(invalid="ignore"):
            ok = np.all(z[F] > 0, 1) & np.all((tri[..., 0] >= 0) & (tri[..., 0] <= W - 1)
                                              & (tri[..., 1] >= 0) & (tri[..., 1] <= H - 1), 1)
        ray = cent - view.center
        dist = np.linalg.norm(ray, axis=1)
        cos = np.abs(np.einsum("fc,fc->f", normals, ray)) / np.maximum(dist, 1e-300)
        ok &= cos >= min_cos
        mask = masks(view) if masks else None
        if mask is not None and ok.any():
            c_uv = tri[ok].mean(1)
            inside = mask[np.clip(np.round(c_uv[:, 1]).astype(int), 0, H - 1), np.clip(np.round(c_uv[:, 0]).astype(int), 0, W - 1)]
            ok[np.flatnonzero(ok)[~inside]] = False
        idx = np.flatnonzero(ok)
        if not len(idx):
            continue
        e1, e2 = tri[idx, 1] - tri[idx, 0], tri[idx, 2] - tri[idx, 0]
        area = np.maximum(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]), 1e-6)
        # the depth test at the centroid; faces larger than 64 px also at 6 more points (the fraction seen
        # scales their quality, so a big face partly hidden in every view still gets its best view)
        big = area > 64
        pts = [cent[idx]] + [V[F[idx[big], c]] * w + cent[idx[big]] * (1 - w) for w in (0.6,) for c in range(3)] \
            + [(V[F[idx[big], c]] + V[F[idx[big], (c + 1) % 3]]) * 0.3 + cent[idx[big]] * 0.4 for c in range(3)]
        which = np.concatenate([np.arange(len(idx))] + [np.flatnonzero(big)] * 6)
        d = np.concatenate(pts) - view.center
        rays = np.concatenate([np.broadcast_to(view.center, d.shape), d], 1).astype(np.float32)
        t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        # the first surface hit is the face itself, or lies within half the face's size of it (a neighbour
        # bulging over a face seen at a slant, a decimation fold: not an occluder)
        tol = np.maximum(1e-3, 0.5 * size[idx] / dist[idx])[which]
        hit = np.abs(t - 1.0) < tol
        frac = np.bincount(which, hit, minlength=len(idx)) / np.bincount(which, minlength=len(idx))
        q[idx, k] = np.where(frac > 0, area * frac, 0)
    return q


# --- 2. one view per face ---------------------------------------------------------------------------------
def select_views(quality: np.ndarray, adjacency: np.ndarray, smoothness: float = 0.4, rounds: int = 6,
                 seed: int = 0) -> np.ndarray:
    """(F,) view index per face (-1 where no view sees it): the best quality, smoothed over ``adjacency``
    ((E, 2) face pairs) by iterated conditional modes on ``1 - q / max q`` + ``smoothness`` x (neighbours with
    another view); half the faces, drawn at random, move per round (no two-face oscillation)."""
    F, V = quality.shape
    best = quality.max(1)
    seen = best > 0
    labels = np.where(seen, quality.argmax(1), -1)
    if rounds <= 0 or not len(adjacency) or V < 2:
        return labels
    with np.errstate(divide="ignore", invalid="ignore"):
        unary = np.where(quality > 0, 1.0 - quality / best[:, None], np.inf).astype(np.float32)
    a, b = np.asarray(adjacency, np.int64).T
    deg = np.bincount(np.r_[a, b], minlength=F).astype(np.float32)
    rng = np.random.default_rng(seed)
    for _ in range(rounds):
        same = np.zeros(F * V, np.float32)
        for x, y in ((a, b), (b, a)):
            ly = labels[y]
            m = ly >= 0
            same += np.bincount(x[m] * V + ly[m], minlength=F * V).astype(np.float32)
        cost = unary + smoothness * (deg[:, None] - same.reshape(F, V))
        new = np.where(seen, cost.argmin(1), -1)
        move = rng.random(F) < 0.5
        labels = np.where(move, new, labels)
    return labels


# --- 3. exposure --------------------------------------------------------------------------------------------
def solve_gains(face: np.ndarray, view: np.ndarray, colors: np.ndarray, n_views: int, iterations: int = 50) -> np.ndarray:
    """Per-view, per-channel gains (V, 3) from observations ``colors`` (N, 3) of faces ``face`` (N,) in
    views ``view`` (N,): least squares on ``log c = log g[view] + log a[face]`` (alternating, then once
    more without observations whose residual exceeds 3 MADs), with the mean of log g = 0 over views that
    have observations; views without any get 1."""
    gains = np.ones((n_views, 3))
    if not len(face):
        return gains
    _, f = np.unique(face, return_inverse=True)
    nf = f.max() + 1
    for c in range(3):
        L = np.log(np.clip(colors[:, c], 1.0, None) / 255.0)
        keep = (colors[:, c] > 4) & (colors[:, c] < 251)  # no dark noise, no clipped highlights
        for trim in range(2):
            ff, vv, LL = f[keep], view[keep], L[keep]
            nv_obs = np.bincount(vv, minlength=n_views)
            nf_obs = np.maximum(np.bincount(ff, minlength=nf), 1)
            g = np.zeros(n_views)
            for _ in range(iterations):
                a = np.bincount(ff, LL - g[vv], minlength=nf) / nf_obs
                g = np.bincount(vv, LL - a[ff], minlength=n_views) / np.maximum(nv_obs, 1)
                g[nv_obs > 0] -= g[nv_obs > 0].mean()
            if trim == 0:
                r = L - g[view] - a[f]
                resid = r[keep]
                mad = np.median(np.abs(resid - np.median(resid))) + 1e-6
                keep = keep & (np.abs(r) < 3 * 1.4826 * mad + 0.02)
        gains[:, c] = np.exp(g)
    return gains


def sample_face_colors(images: Callable[[int], np.ndarray], views: list[View], mesh: trimesh.Trimesh,
                       quality: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The colour of each face in ``faces`` in every view that sees it (``quality > 0``), sampled at its
    centroid in a lightly blurred photo (so views at other resolutions agree): (face, view, colour (N, 3))."""
    cent = np.asarray(mesh.vertices)[np.asarray(mesh.faces)[faces]].mean(1)
    fs, vs, cs = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, 3), np.float32)]
    for k, view in enumerate(bar(views, desc="texture: colours")):
        sel = quality[faces, k] > 0
        if not sel.any():
            continue
        img = cv2.GaussianBlur(images(k), (0, 0), 1.5)
        uv, _ = project(cent[sel], view.intrinsics, view.cam_from_world)
        fs.append(faces[sel])
        vs.append(np.full(int(sel.sum()), k))
        cs.append(sample_bilinear(img, uv).astype(np.float32))
    return np.concatenate(fs), np.concatenate(vs), np.concatenate(cs)


def estimate_gains(images: Callable[[int], np.ndarray], views: list[View], mesh: trimesh.Trimesh,
                   quality: np.ndarray, max_faces: int = 20000, seed: int = 0, samples=None) -> np.ndarray:
    """Per-view gains (V, 3) from the colours of faces that >= 2 views see (at most ``max_faces`` of them).
    ``samples``: (face, view, colour) from ``sample_face_colors`` (else sampled here)."""
    multi = np.flatnonzero((quality > 0).sum(1) >= 2)
    if not len(multi):
        return np.ones((len(views), 3))
    rng = np.random.default_rng(seed)
    if len(multi) > max_faces:
        multi = np.sort(rng.choice(multi, max_faces, replace=False))
    if samples is None:
        f, v, c = sample_face_colors(images, views, mesh, quality, multi)
    else:
        f, v, c = samples
        keep = np.isin(f, multi)
        f, v, c = f[keep], v[keep], c[keep]
    if not len(f):
        return np.ones((len(views), 3))
    return solve_gains(f, v, c.astype(np.float64), len(views))


def photo_outliers(face: np.ndarray, view: np.ndarray, colors: np.ndarray,
                   threshold: float = 20.0, min_views: int = 3) -> np.ndarray:
    """(N,) bool: observations (``face``, ``view``, exposure-corrected ``colors`` (N, 3), 0-255) whose colour
    differs from the median colour of their face over all its views by more than ``threshold`` (RGB distance)
    and by more than 3 times the face's median distance, for faces that at least ``min_views`` views see. Such
    a view shows something else where the mesh puts the face (an occluder the mesh lacks, background past a
    rounded edge, a surface the decimated mesh misplaces): the photo-consistency check of MVS-Texturing
    (Waechter et al., ECCV 2014), with the median in place of its mean shift."""
    out = np.zeros(len(face), bool)
    if not len(face):
        return out
    order = np.argsort(face, kind="stable")
    f = face[order]
    starts = np.flatnonzero(np.r_[True, f[1:] != f[:-1]])
    counts = np.diff(np.r_[starts, len(f)])
    c = colors[order].astype(np.float32)

    def group_median(x):  # per face (a run of ``order``), one vectorised median per run length
        out_ = np.empty_like(x)
        for n in np.unique(counts):
            idx = (starts[counts == n][:, None] + np.arange(n)[None]).reshape(-1)
            out_[idx] = np.repeat(np.median(x[idx].reshape(-1, n, *x.shape[1:]), axis=1), n, axis=0)
        return out_

    d = np.linalg.norm(c - group_median(c), axis=1)
    dmed = group_median(d)
    bad = (d > threshold) & (d > 3 * dmed) & (np.repeat(counts, counts) >= min_views)
    out[order] = bad
    return out


def texture_mesh(mesh: trimesh.Trimesh, views: list[View], images: Callable[[int], np.ndarray],
                 cfg: TextureConfig | None = None, masks: Callable[[View], np.ndarray | None] | None = None,
                 blind: np.ndarray | None = None) -> Textured:
    """Texture ``mesh`` from ``views`` (``images(k)``: the k-th view's photo, (H, W, 3) uint8, at its camera's
    size). ``blind``: (F,) bool, faces no photo textures nor hides anything behind (a closed model's invented
    fill; ``cfg.texture_faces`` 0): coloured as unseen faces are. Raises ``EmptyMeshError`` for a mesh without
    faces, ``TextureError`` when no view sees the mesh."""
    cfg = expect_config(cfg, TextureConfig, "cfg")
    check_config(cfg)  # also after changes made to it since it was built
    if mesh is None or not len(mesh.faces):
        raise EmptyMeshError("the mesh has no faces: nothing to texture")
    if not views:
        raise TextureError("no cameras: texturing needs the views the mesh was made from")
    check_atlas_memory(cfg.atlas_size)
    faces_in = len(mesh.faces)
    if cfg.texture_faces and faces_in > cfg.texture_faces:
        from .clean import simplify

        mesh = simplify(mesh, cfg.texture_faces)
        log.info("texture: mesh simplified from %d to %d faces", faces_in, len(mesh.faces))
    mesh = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
    adjacency = np.asarray(mesh.face_adjacency, np.int64).reshape(-1, 2)
    blind, scene = np.zeros(len(mesh.faces), bool) if blind is None else np.asarray(blind, bool), None
    if blind.any():  # no occluders either: a cup's lid would hide its inside, which the photos show
        from .convert import raycasting_scene

        scene = raycasting_scene(trimesh.Trimesh(mesh.vertices, mesh.faces[~blind], process=False))
    q = face_view_quality(mesh, views, masks, cfg.min_cos, scene)
    q[blind] = 0  # a mask of another length than the faces' raises
    per_view = (q > 0).sum(0)
    if not per_view.any():
        raise TextureError(f"none of the {len(views)} views sees the mesh (faces {len(mesh.faces)}): check that the "
                           "cameras and the mesh are in the same frame (same reconstruction)")
    blind = [views[k].name for k in np.flatnonzero(per_view == 0)]
    if blind:
        log.warning("texture: %d view(s) see none of the mesh: %s", len(blind), ", ".join(blind[:10]))
    samples = None
    if cfg.exposure or cfg.consistency > 0:
        samples = sample_face_colors(images, views, mesh, q, np.flatnonzero((q > 0).sum(1) >= 2))
    gains = estimate_gains(images, views, mesh, q, samples=samples) if cfg.exposure else np.ones((len(views), 3))
    dropped = 0
    if cfg.consistency > 0:
        f, v, c = samples
        bad = photo_outliers(f, v, c / gains[v], cfg.consistency)
        q[f[bad], v[bad]] = 0
        dropped = int(bad.sum())
        log.info("texture: photo-consistency dropped %d of %d (face, view) pairs", dropped, len(f))
    labels = select_views(q, adjacency, cfg.smoothness, cfg.smooth_rounds)
    charts = make_charts(mesh, views, labels, adjacency)
    unseen = np.flatnonzero(labels < 0)
    cell = 4
    n_cols = int(np.ceil(np.sqrt(len(unseen)))) if len(unseen) else 0
    extra = (n_cols * cell, int(np.ceil(len(unseen) / max(n_cols, 1))) * cell) if len(unseen) else None
    N, pad = cfg.atlas_size, cfg.padding
    scale, pos, origin, size = pack_charts(charts, N, pad, extra)
    if scale < 0.3:
        log.warning("texture: the atlas holds the photos at %.2f texels per pixel; a larger --atlas-size or fewer "
                    "faces (--texture-faces) keep more detail", scale)

    atlas = np.zeros((N, N, 3), np.uint8)
    face_color = np.full((len(mesh.faces), 3), np.nan, np.float32)
    F = np.asarray(mesh.faces)
    cent = np.asarray(mesh.vertices)[F].mean(1)
    for k, view in enumerate(bar(views, desc="texture: bake")):
        rects = np.flatnonzero(charts.rect_view == k)
        if not len(rects):
            continue
        img = images(k)
        src = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else img
        g = (1.0 / gains[k]).astype(np.float32)
        for r in rects:
            (x, y), (ox, oy), (w, h) = pos[r], origin[r], size[r]
            M = np.array([[1.0, 0, ox], [0, 1.0, oy]])
            patch = cv2.warpAffine(src, M, (int(w), int(h)), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_REPLICATE)
            atlas[y:y + h, x:x + w] = np.clip(patch.astype(np.float32) * g + 0.5, 0, 255).astype(np.uint8)
        sel = np.flatnonzero(labels == k)
        uv, _ = project(cent[sel], view.intrinsics, view.cam_from_world)
        face_color[sel] = sample_bilinear(img, uv) * g

    # UVs: seen corners from their photo position; unseen faces: a flat cell each
    fr = charts.face_rect
    seen = fr >= 0
    uv_corner = np.zeros((len(F), 3, 2))
    if seen.any():
        r = fr[seen][:, None]
        tex = (charts.corner_px[seen] + 0.5) * scale - 0.5 - origin[r] + pos[r]  # atlas texel coordinates
        uv_corner[seen] = tex
    if len(unseen):
        # the seen faces' colours diffused over the face adjacency (harmonic: an unseen area blends the colours
        # around it); grey where a component has no seen face
        known = np.flatnonzero(~np.isnan(face_color[:, 0]))
        face_color[unseen] = harmonic_fill(len(F), adjacency, known, face_color[known])[unseen] if len(known) else 128.0
        ex, ey = pos[-1]
        i = np.arange(len(unseen))
        cx, cy = ex + (i % n_cols) * cell + cell / 2 - 0.5, ey + (i // n_cols) * cell + cell / 2 - 0.5
        for dx, dy, c in ((-0.5, -0.5, 0), (0.5, -0.5, 1), (0.0, 0.5, 2)):
            uv_corner[unseen, c] = np.stack([cx + dx, cy + dy], 1)
        for k, fidx in enumerate(unseen):
            x0, y0 = ex + (k % n_cols) * cell, ey + (k // n_cols) * cell
            atlas[y0:y0 + cell, x0:x0 + cell] = np.clip(face_color[fidx] + 0.5, 0, 255).astype(np.uint8)
    # one output vertex per (vertex, rectangle); unseen faces get their own three
    key_rect = np.where(seen[:, None], fr[:, None], -2 - np.arange(len(F))[:, None])
    keys = np.stack([F, np.broadcast_to(key_rect, F.shape)], -1).reshape(-1, 2)
    _, first, inv = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    new_faces = inv.reshape(-1, 3)
    levelling = None
    if cfg.seam_levelling and seen.any():
        levelling = level_seams(atlas, F, new_faces, len(first), labels, adjacency,
                                np.asarray(mesh.face_adjacency_edges, np.int64).reshape(-1, 2), uv_corner, fr, pos, size)
        log.info("texture: seam levelling at %d seam vertices: mean step %.1f -> %.1f (RGB 0-255)",
                 levelling["seam_vertices"], levelling["seam_step_before"], levelling["seam_step_after"])
    new_vertices = np.asarray(mesh.vertices)[F.reshape(-1)[first]]
    tex = uv_corner.reshape(-1, 2)[first]
    uv = np.stack([(tex[:, 0] + 0.5) / N, 1.0 - (tex[:, 1] + 0.5) / N], 1)
    from PIL import Image

    material = trimesh.visual.material.PBRMaterial(name="photorecon_texture", baseColorTexture=Image.fromarray(atlas),
                                                   metallicFactor=0.0, roughnessFactor=1.0)
    out = trimesh.Trimesh(new_vertices, new_faces, visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
                          process=False)
    info = {"faces": int(len(mesh.faces)), "faces_in": int(faces_in), "vertices": int(len(new_vertices)),
            "views_used": int(len(np.unique(labels[labels >= 0]))), "views_blind": blind,
            "unseen_faces": int(len(unseen)), "inconsistent_views_dropped": dropped, "charts": int(len(charts.rect_box)), "atlas_size": N,
            "texels_per_pixel": round(float(scale), 4),
            **({"seam_levelling": levelling} if levelling is not None else {}),
            "gains": {views[k].name: [round(float(x), 4) for x in gains[k]] for k in range(len(views))}}
    return Textured(out, atlas, labels, gains, info)


# --- export ---------------------------------------------------------------------------------------------------
def export_textured(mesh: trimesh.Trimesh, folder: str | Path) -> Path:
    """Write ``folder``/mesh.obj + mesh.mtl + texture.png and mesh.glb (texture embedded), all or nothing
    (a temporary folder renamed onto ``folder``)."""
    from PIL import Image

    from ..stages import atomic_dir

    folder = Path(folder)
    img = mesh.visual.material.baseColorTexture
    simple = trimesh.visual.material.SimpleMaterial(image=img, name="photorecon_texture", diffuse=(255, 255, 255, 255))
    obj_mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False,
                               visual=trimesh.visual.TextureVisuals(uv=mesh.visual.uv, material=simple))
    with atomic_dir(folder) as tmp:
        text, files = trimesh.exchange.obj.export_obj(obj_mesh, include_normals=False, include_texture=True,
                                                      return_texture=True, mtl_name="mesh.mtl")
        # one texture named texture.png, whatever trimesh called it
        pngs = [n for n in files if n.lower().endswith((".png", ".jpg", ".jpeg"))]
        mtl = files["mesh.mtl"].decode()
        for n in pngs:
            mtl = mtl.replace(n, "texture.png")
        (tmp / "mesh.obj").write_text(text)
        (tmp / "mesh.mtl").write_text(mtl)
        Image.fromarray(np.asarray(img.convert("RGB"))).save(tmp / "texture.png", optimize=False, compress_level=3)
        (tmp / "mesh.glb").write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh)))
    return folder


# --- the stage on a reconstruct output folder -------------------------------------------------------------------
def texture_output(out: str | Path, cfg: TextureConfig | None = None, mesh_path: str | Path | None = None,
                   dest: str | Path | None = None, mesh: trimesh.Trimesh | None = None) -> dict:
    """Texture a reconstruct output folder ``out`` (its cameras in sparse/0 or transforms.json, photos in
    images/, masks in masks/): the mesh ``mesh_path`` (default ``out``/mesh.ply) or ``mesh`` -> ``dest``
    (default ``out``/textured/) with mesh.obj, mesh.mtl, texture.png, mesh.glb and preview.png. Returns facts
    for the report."""
    from ..io.dataset import Dataset
    from ..io.output import mark
    from .export import load_mesh

    cfg = expect_config(cfg, TextureConfig, "cfg")
    check_config(cfg)  # also after changes made to it since it was built
    out = Path(out)
    ds = Dataset.open(out)
    if mesh is None:
        default = Layout(out).mesh("ply")
        if not mesh_path and not default.is_file():
            raise InputDataError(f"{out}: no mesh.ply; expected the output folder of 'photorecon reconstruct' or "
                                 "'fuse', or give the mesh to texture with --mesh")
        mesh = load_mesh(Path(mesh_path) if mesh_path else default)
    views = ds.views

    def images(k):
        return ds.image(views[k])

    def masks(view):
        return ds.mask(view)

    res = texture_mesh(mesh, views, images, cfg, masks)
    dest = Path(dest) if dest else Layout(out).textured
    from ..report.preview import render_preview

    # written beside ``dest`` first, then moved in file by file: what else ``dest`` holds stays as it was
    tmp = dest.with_name(f".{dest.name}.texture.partial")
    try:
        export_textured(res.mesh, tmp)
        render_preview(res.mesh, tmp / "preview.png", cameras=views)
        dest.mkdir(parents=True, exist_ok=True)
        for f in sorted(tmp.iterdir()):
            f.replace(dest / f.name)
        mark(dest, "texture")  # texture may replace these files later (also in reconstruct's textured/)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    log.info("texture: %d faces, %d charts, %d views used, %.2f texels per pixel -> %s", res.info["faces"],
             res.info["charts"], res.info["views_used"], res.info["texels_per_pixel"], dest)
    return {**res.info, "folder": str(dest)}
