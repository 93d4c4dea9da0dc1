"""The texture atlas layout: faces grouped into charts (connected faces textured from the same view, projected
into that view's image), and the charts packed into one square atlas (shelf packing).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..cameras import View, project
from ..errors import TextureError


# --- 4. charts, packing, baking -----------------------------------------------------------------------------
def _merge_boxes(boxes: np.ndarray, margin: float) -> np.ndarray:
    """Group index per box: boxes (n, 4) ``x0 y0 x1 y1`` that overlap (within ``margin``) share a group,
    transitively, also through the union boxes of groups (repeated until nothing changes)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    group = np.arange(len(boxes))
    cur = boxes.copy()
    while len(cur) > 1:
        lo, hi = cur[:, :2] - margin, cur[:, 2:] + margin
        ov = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)
        i, j = np.nonzero(np.triu(ov, 1))
        if not len(i):
            break
        n, comp = connected_components(coo_matrix((np.ones(len(i)), (i, j)), shape=(len(cur), len(cur))), directed=False)
        new = np.empty((n, 4))
        new[:, :2] = np.inf
        new[:, 2:] = -np.inf
        np.minimum.at(new[:, 0], comp, cur[:, 0])
        np.minimum.at(new[:, 1], comp, cur[:, 1])
        np.maximum.at(new[:, 2], comp, cur[:, 2])
        np.maximum.at(new[:, 3], comp, cur[:, 3])
        group = comp[group]
        cur = new
    return group


def shelf_pack(sizes: np.ndarray, width: int) -> tuple[np.ndarray, int]:
    """Place rectangles ``sizes`` (n, 2) = (w, h) in rows ("shelves") of ``width``, tallest first.
    Returns their top-left corners (n, 2) and the total height used."""
    order = np.argsort(-sizes[:, 1], kind="stable")
    pos = np.zeros((len(sizes), 2), np.int64)
    x = y = row_h = 0
    for i in order:
        w, h = int(sizes[i, 0]), int(sizes[i, 1])
        if w > width:
            return pos, np.iinfo(np.int64).max
        if x + w > width:
            y += row_h
            x = row_h = 0
        pos[i] = (x, y)
        x += w
        row_h = max(row_h, h)
    return pos, y + row_h


@dataclass
class _Charts:
    rect_view: np.ndarray  # (R,) view of each rectangle
    rect_box: np.ndarray  # (R, 4) x0 y0 x1 y1 in the view's photo pixels
    face_rect: np.ndarray  # (F,) rectangle of each face, -1 = unseen
    corner_px: np.ndarray  # (F, 3, 2) face corners in their view's photo pixels (NaN for unseen faces)


def make_charts(mesh: trimesh.Trimesh, views: list[View], labels: np.ndarray, adjacency: np.ndarray,
                merge_margin: float = 3.0) -> _Charts:
    """Charts: connected faces with one view; their projections' boxes in that view, overlapping boxes of a
    view merged into one rectangle."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    F = np.asarray(mesh.faces, np.int64)
    V = np.asarray(mesh.vertices, np.float64)
    corner = np.full((len(F), 3, 2), np.nan)
    for k, view in enumerate(views):
        sel = np.flatnonzero(labels == k)
        if len(sel):
            used, inv = np.unique(F[sel], return_inverse=True)
            uv, _ = project(V[used], view.intrinsics, view.cam_from_world)
            corner[sel] = uv[inv.reshape(-1, 3)]
    a, b = np.asarray(adjacency, np.int64).reshape(-1, 2).T
    same = (labels[a] == labels[b]) & (labels[a] >= 0)
    n, comp = connected_components(coo_matrix((np.ones(int(same.sum())), (a[same], b[same])),
                                              shape=(len(F), len(F))), directed=False)
    seen = labels >= 0
    comp_view = np.full(n, -1)
    comp_view[comp[seen]] = labels[seen]
    box = np.empty((n, 4))
    box[:, :2] = np.inf
    box[:, 2:] = -np.inf
    cs = comp[seen]
    np.minimum.at(box[:, 0], cs, corner[seen, :, 0].min(1))
    np.minimum.at(box[:, 1], cs, corner[seen, :, 1].min(1))
    np.maximum.at(box[:, 2], cs, corner[seen, :, 0].max(1))
    np.maximum.at(box[:, 3], cs, corner[seen, :, 1].max(1))
    rect_of_comp = np.full(n, -1)
    rect_view, rect_box = [], []
    for k in range(len(views)):
        cids = np.flatnonzero(comp_view == k)
        if not len(cids):
            continue
        g = _merge_boxes(box[cids], merge_margin)
        ng = g.max() + 1
        gb = np.empty((ng, 4))
        gb[:, :2] = np.inf
        gb[:, 2:] = -np.inf
        np.minimum.at(gb[:, 0], g, box[cids, 0])
        np.minimum.at(gb[:, 1], g, box[cids, 1])
        np.maximum.at(gb[:, 2], g, box[cids, 2])
        np.maximum.at(gb[:, 3], g, box[cids, 3])
        rect_of_comp[cids] = len(rect_view) + g
        rect_view.extend([k] * ng)
        rect_box.extend(gb)
    face_rect = np.where(seen, rect_of_comp[comp], -1)
    return _Charts(np.array(rect_view, np.int64), np.array(rect_box).reshape(-1, 4), face_rect, corner)


def _rect_layout(box: np.ndarray, scale: float, pad: int) -> tuple[np.ndarray, np.ndarray]:
    """Per rectangle: the scaled photo's first texel it copies (ox, oy) and its size (w, h) in texels."""
    lo = np.floor((box[:, :2] + 0.5) * scale - 0.5) - pad
    hi = np.ceil((box[:, 2:] + 0.5) * scale - 0.5) + pad
    return lo, (hi - lo + 1).astype(np.int64)


def pack_charts(charts: _Charts, atlas_size: int, pad: int, extra: tuple[int, int] | None = None):
    """The largest scale (<= 1 atlas texel per photo pixel) at which every rectangle (plus an ``extra``
    fixed-size one, for unseen faces) fits in the atlas. Returns (scale, corners (R[+1], 2), origins, sizes)."""
    def attempt(s):
        o, sz = _rect_layout(charts.rect_box, s, pad)
        if extra is not None:
            sz = np.vstack([sz, [extra]])
        pos, h = shelf_pack(sz, atlas_size)
        return pos, o, sz, h <= atlas_size

    pos, o, sz, fits = attempt(1.0)
    if fits:
        return 1.0, pos, o, sz
    lo, hi = 0.0, 1.0
    best = None
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        res = attempt(mid)
        if res[3]:
            lo, best = mid, (mid,) + res[:3]
        else:
            hi = mid
    if best is None or best[0] < 1e-3:
        raise TextureError(f"the mesh's {len(charts.rect_box)} texture charts do not fit in a {atlas_size}x{atlas_size} "
                           "atlas; use a larger --atlas-size or fewer faces (--texture-faces)")
    return best
