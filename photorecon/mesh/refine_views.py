"""Which views see which vertices of a mesh being refined (``mesh.refine``): the views at each image pyramid
level, visibility (in the image, facing the camera, not occluded by the mesh) and each vertex's most frontal
views. ``facing`` and ``_top_views`` are numba kernels."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..cameras import View
from ..jit import njit, prange
from .convert import raycasting_scene

MIN_COS = 0.2  # a view sees a vertex under at most ~78 degrees from its normal


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
               lvl: _Level, occlusion: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Which views see which vertices: (cos (n_views, V) float32, 0 where not seen; depth (n_views, V)).
    Seen: inside the image, facing the camera (cosine >= ``MIN_COS``: ``facing``), and (``occlusion``) no
    surface of the mesh more than 2 pixel footprints in front of the vertex along the camera's ray."""
    import open3d as o3d

    inside = np.zeros((len(views), len(vertices)), bool)
    for i, P in enumerate(lvl.P):
        z = vertices @ P[2, :3] + P[2, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (vertices @ P[0, :3] + P[0, 3]) / z
            w = (vertices @ P[1, :3] + P[1, 3]) / z
        W, H = lvl.sizes[i]
        inside[i] = (z > 0) & (u >= 0) & (w >= 0) & (u <= W - 1) & (w <= H - 1)
    cos, depth = facing(vertices, normals, np.array([v.center for v in views], float).reshape(-1, 3), lvl.P,
                        inside, MIN_COS)
    if not occlusion:
        return cos, depth
    scene = raycasting_scene(trimesh.Trimesh(vertices, faces, process=False))
    for i, v in enumerate(views):
        cand = np.flatnonzero(cos[i] > 0)
        if not len(cand):
            continue
        d = vertices[cand] - v.center
        dist = np.linalg.norm(d, axis=1)
        rays = np.concatenate([np.broadcast_to(v.center, (len(cand), 3)), d], axis=1).astype(np.float32)
        t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        tol = 2.0 * depth[i, cand] / lvl.focal[i]  # two pixel footprints
        hidden = np.isfinite(t) & ((1.0 - t) * dist > tol)  # a miss: the ray slipped past its own vertex
        cos[i, cand[hidden]] = 0
        depth[i, cand[hidden]] = 0
    return cos, depth


@njit(cache=True, parallel=True)
def facing(vertices, normals, centres, P, seen, min_cos):
    """The facing test of ``visibility`` on the pairs ``seen`` (n_views, V): the cosine of each view's ray (from
    ``centres``) with the vertex normal, 0 below ``min_cos``, and the vertex's depth (the projections ``P``),
    both (n_views, V). Later rounds of a level run it alone on the pairs its first round found unoccluded."""
    n, V = seen.shape
    cos = np.zeros((n, V), np.float32)
    depth = np.zeros((n, V), np.float32)
    for v in prange(V):
        for i in range(n):
            if not seen[i, v]:
                continue
            dx = vertices[v, 0] - centres[i, 0]
            dy = vertices[v, 1] - centres[i, 1]
            dz = vertices[v, 2] - centres[i, 2]
            dist = np.sqrt(dx * dx + dy * dy + dz * dz)
            cs = -(normals[v, 0] * dx + normals[v, 1] * dy + normals[v, 2] * dz) / max(dist, 1e-12)
            if cs >= min_cos:
                cos[i, v] = cs
                depth[i, v] = (P[i, 2, 0] * vertices[v, 0] + P[i, 2, 1] * vertices[v, 1]
                               + P[i, 2, 2] * vertices[v, 2] + P[i, 2, 3])
    return cos, depth


@njit(cache=True, parallel=True)
def _top_views(cos, k):
    n, V = cos.shape
    out = np.full((V, k), -1, np.int32)
    for v in prange(V):
        best = np.full(k, -1.0)
        for i in range(n):
            c = cos[i, v]
            if c <= 0 or c <= best[k - 1]:
                continue
            j = k - 1  # insertion: ties keep the lower view index first, as a stable sort does
            while j > 0 and best[j - 1] < c:
                best[j] = best[j - 1]
                out[v, j] = out[v, j - 1]
                j -= 1
            best[j] = c
            out[v, j] = i
    return out


def select_views(cos: np.ndarray, k: int) -> np.ndarray:
    """Per vertex, the ``k`` views with the largest cosines (seen ones only; -1 pads), most frontal first:
    (V, k) int32."""
    return _top_views(np.ascontiguousarray(cos, np.float32), min(k, cos.shape[0]))
