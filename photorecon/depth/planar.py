"""Planar prior for PatchMatch (after ACMP, Xu & Tao 2020), as hypothesis injection between rounds.

Weakly textured planes (a grazing paved ground, a white wall) give PatchMatch no reliable photometric minimum:
their pixels keep a high cost and are dropped by the filters, while the textured pixels around them are found.
ACMP triangulates the confident pixels in the image and uses each triangle's plane as a prior. Here:

1. **Support points**: the pixels of the previous round whose cost is below ``SUPPORT_COST`` (in the rounds
   with ACMM's geometric term that cost includes the reprojection error through the other views, so a
   support point is photometrically *and* geometrically consistent); the cheapest one per ``cell`` x
   ``cell`` pixel cell, so the triangles are spread evenly.
2. **Triangles**: a Delaunay triangulation of the support points in the image (``scipy.spatial.Delaunay``).
   Each triangle's plane goes through its three vertices' 3D points (reference camera frame). A triangle is
   dropped when an edge is longer than ``MAX_EDGE`` of the image's long side (it would bridge separate
   surfaces) or when its plane's normal is more than ``MAX_ANGLE_DEG`` from any of its vertices' own
   PatchMatch normals (the vertices are not on one plane: a crease, a depth step).
3. **Injection** (``inject_prior``): at the pixels whose hypothesis is not confident, the prior plane (the
   triangle's depth at that pixel, its normal) is scored with the round's own cost
   (``methods.patchmatch.kernels.initial_cost``: the same photometric + geometric cost, the same sources) and replaces the current plane when its cost is
   below ``ACCEPT_COST`` and not more than ``MARGIN`` above the current one's. The round's propagation then
   spreads the injected planes and its refinement perturbs them, so a prior only has to be roughly right
   somewhere in a region. The same is done once more after the last round's iterations.
4. **Textureless fill** (after the last round only): where the reference window is flat (grey standard
   deviation below ``TEXTURELESS_STD``) NCC is 0 at any depth, so no photometric threshold can accept a
   plane; there the prior is kept when its cost (photometric, flat, plus ACMM's geometric term through the
   other views' depth maps) is not more than ``MARGIN`` above the current plane's, with cost ``FILL_COST``
   (confidence 0.25: a low TSDF weight, raised by the filter where other views confirm the fill). The multi-view filter
   after PatchMatch then keeps only the fills that ``min_consistent`` other views confirm.

Unlike ACMP, the prior is not a term of the matching cost (that would change the propagation kernel): on
textured pixels a prior plane is only kept where the photometric evidence accepts it, so it cannot paint
planes across a depth step that the images contradict; on flat pixels (the sky too) only the triangle checks
and the agreement of other views stand between a prior plane and the output.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

SUPPORT_COST = 0.3  # support points: cost below this
MAX_EDGE = 0.3  # drop triangles with an edge longer than this fraction of the image's long side
MAX_ANGLE_DEG = 30.0  # drop triangles whose plane is this far from a vertex's normal
CANDIDATE_COST = 0.3  # try the prior at pixels whose current cost is above this
SAME_DEPTH = 2e-3  # ... and whose depth differs from the prior's by more than this (relative)
ACCEPT_COST = 0.6  # keep a prior plane whose cost is below this ...
MARGIN = 0.05  # ... and at most this much above the current hypothesis's
TEXTURELESS_STD = 0.01  # a reference window (grey 0..1) whose standard deviation is below this has no texture ...
FILL_COST = 0.75  # ... and takes the prior with this cost (confidence 0.25) when it is not worse than the current


def _cell(shape: tuple[int, int]) -> int:
    """Support grid cell in pixels: about 100 cells along the long side, at least 3 px."""
    return max(3, int(round(max(shape) / 100)))


def _rays(xs: np.ndarray, ys: np.ndarray, Kinv: np.ndarray) -> np.ndarray:
    """Kinv [x, y, 1] per pixel, (N, 3); einsum rather than a BLAS product, whose idle threads would spin
    against numba's on a busy machine."""
    p = np.stack([xs, ys, np.ones_like(xs)], 1).astype(np.float64)
    return np.einsum("ij,nj->ni", Kinv, p)


def support_points(depth: np.ndarray, cost: np.ndarray, cell: int, max_cost: float = SUPPORT_COST) -> tuple[np.ndarray, np.ndarray]:
    """The cheapest pixel with ``cost < max_cost`` (and a depth) in each ``cell`` x ``cell`` cell: (ys, xs)."""
    H, W = depth.shape
    ys, xs = np.nonzero((depth > 0) & (cost < max_cost) & np.isfinite(cost))
    if not len(ys):
        return ys, xs
    cid = (ys // cell) * ((W + cell - 1) // cell) + xs // cell
    order = np.lexsort((cost[ys, xs], cid))
    _, first = np.unique(cid[order], return_index=True)
    pick = order[first]
    return ys[pick], xs[pick]


def prior_planes(depth: np.ndarray, normal: np.ndarray, cost: np.ndarray, Kinv: np.ndarray,
                 want: np.ndarray | None = None, cell: int | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """The per-pixel prior plane from the confident pixels of (``depth``, ``normal``, ``cost``) (one view, one
    resolution, reference camera frame; ``Kinv`` its inverse intrinsics): (prior depth (H, W) float32, 0 where
    no triangle covers the pixel; prior normal (H, W, 3) float32; stats). ``want``: only these pixels (bool
    mask) are filled (the others stay 0), which saves the point location for confident pixels."""
    from scipy.spatial import Delaunay, QhullError

    H, W = depth.shape
    pd = np.zeros((H, W), np.float32)
    pn = np.zeros((H, W, 3), np.float32)
    cell = cell or _cell((H, W))
    ys, xs = support_points(depth, cost, cell)
    stats = {"support": int(len(ys)), "triangles": 0, "kept": 0, "pixels": 0}
    if len(ys) < 3:
        return pd, pn, stats
    uv = np.stack([xs, ys], 1).astype(np.float64)
    try:
        tri = Delaunay(uv)
    except QhullError:  # all support points on a line
        return pd, pn, stats
    S = tri.simplices
    stats["triangles"] = int(len(S))
    rays = _rays(xs, ys, Kinv)
    X = rays * depth[ys, xs][:, None]
    P = uv[S]  # (T, 3, 2) pixel corners
    edge = np.max(np.linalg.norm(P - np.roll(P, 1, axis=1), axis=2), axis=1)
    V = X[S]  # (T, 3, 3) 3D corners
    n = np.cross(V[:, 1] - V[:, 0], V[:, 2] - V[:, 0])
    nl = np.linalg.norm(n, axis=1)
    ok = (edge <= MAX_EDGE * max(H, W)) & (nl > 0)
    n = n / np.maximum(nl, 1e-30)[:, None]
    n *= -np.sign(np.einsum("ti,ti->t", n, V[:, 0]))[:, None]  # facing the camera: n . X < 0
    vn = normal[ys, xs].astype(np.float64)[S]  # (T, 3, 3) vertex normals
    cos = np.einsum("ti,tki->tk", n, vn).min(axis=1)
    ok &= cos >= np.cos(np.radians(MAX_ANGLE_DEG))
    stats["kept"] = int(ok.sum())
    if not ok.any():
        return pd, pn, stats
    qy, qx = np.nonzero(want) if want is not None else np.mgrid[0:H, 0:W].reshape(2, -1)
    t = tri.find_simplex(np.stack([qx, qy], 1).astype(np.float64))
    inside = t >= 0
    inside[inside] = ok[t[inside]]
    qy, qx, t = qy[inside], qx[inside], t[inside]
    r = _rays(qx, qy, Kinv)
    nt = n[t]
    den = np.einsum("pi,pi->p", nt, r)
    z = np.einsum("pi,pi->p", nt, V[t, 0]) / np.where(np.abs(den) > 1e-12, den, np.nan)
    good = np.isfinite(z) & (z > 0)
    pd[qy[good], qx[good]] = z[good]
    pn[qy[good], qx[good]] = nt[good]
    stats["pixels"] = int(good.sum())
    return pd, pn, stats


def window_std(img: np.ndarray, radius: int) -> np.ndarray:
    """Standard deviation of the grey image ``img`` over each pixel's (2 ``radius`` + 1)^2 window."""
    import cv2

    k = (2 * radius + 1, 2 * radius + 1)
    im = img.astype(np.float32)
    m = cv2.blur(im, k, borderType=cv2.BORDER_REFLECT)
    var = cv2.blur(im * im, k, borderType=cv2.BORDER_REFLECT) - m * m
    return np.sqrt(np.maximum(var, 0.0))


def textureless(img: np.ndarray, radius: int, max_std: float = TEXTURELESS_STD) -> np.ndarray:
    """Pixels whose (2 ``radius`` + 1)^2 window of the grey image ``img`` has a standard deviation below
    ``max_std``: photometric matching has no evidence there (NCC of a flat window is 0, cost 1, at any depth)."""
    return window_std(img, radius) < max_std


FLAT_STD = 1.0 / 255.0  # a window below one grey level of standard deviation: flat, whatever the image's contrast


def relative_texture(img: np.ndarray, radius: int, mask: np.ndarray | None = None) -> np.ndarray:
    """Each pixel's window standard deviation (``window_std``) divided by the image's typical one: the median
    over the windows that are not flat (at least ``FLAT_STD``; inside ``mask`` when given). A texture measure
    that does not depend on the photo's exposure or contrast: a dark, low-contrast object and a bright one
    score alike, 1 = as textured as the image's median window. All zeros for an image with no texture."""
    std = window_std(img, radius)
    vals = std if mask is None else std[mask]
    vals = vals[vals >= FLAT_STD]
    if vals.size == 0:
        return np.zeros_like(std)
    return std / float(np.median(vals))


def inject_prior(depth: np.ndarray, normal: np.ndarray, cost: np.ndarray, prev: tuple[np.ndarray, np.ndarray, np.ndarray],
                 Kinv: np.ndarray, dmin: float, dmax: float,
                 cost_of: Callable[[np.ndarray, np.ndarray, np.ndarray], None], flat: np.ndarray | None = None) -> dict:
    """Replace, in place, the non-confident hypotheses of (``depth``, ``normal``, ``cost``) by the planar prior
    where the round's cost accepts it. ``prev``: (depth, normal, cost) of the previous round at this
    resolution (the support points come from it); ``cost_of(depth, normal, out)`` fills ``out`` with the
    round's cost of each pixel's plane (pixels of depth 0 are skipped by the kernel). ``flat``: the textureless
    pixels (``textureless``), where the photometric cost cannot accept a plane: there the prior is kept when its
    cost (the geometric term through the other views decides, photometric being flat) is at most ``MARGIN``
    above the current one's, with cost ``FILL_COST``; None: no textureless fill. Returns stats."""
    d_prev, n_prev, c_prev = prev
    want = (c_prev > CANDIDATE_COST) | ~(d_prev > 0)
    pd, pn, stats = prior_planes(d_prev, n_prev, c_prev, Kinv, want=want)
    cand = (pd >= dmin) & (pd <= dmax)
    # pixels whose plane already agrees with the prior (depth within SAME_DEPTH) gain nothing
    cand &= ~(np.abs(depth - pd) <= SAME_DEPTH * pd)
    stats["candidates"] = int(cand.sum())
    stats["injected"] = 0
    if not cand.any():
        return stats
    c_prior = np.full(depth.shape, np.inf, np.float32)
    cost_of(np.where(cand, pd, 0).astype(np.float32), pn, c_prior)
    c_cur = np.full(depth.shape, np.inf, np.float32)
    cur_ok = cand & (depth > 0)
    cost_of(np.where(cur_ok, depth, 0).astype(np.float32), np.ascontiguousarray(normal, np.float32), c_cur)
    c_cur[~cur_ok] = np.inf
    not_worse = c_prior <= np.minimum(c_cur, 10.0) + MARGIN
    take = cand & (c_prior < ACCEPT_COST) & not_worse
    depth[take] = pd[take]
    normal[take] = pn[take]
    cost[take] = c_prior[take]
    stats["injected"] = int(take.sum())
    if flat is not None:
        fill = cand & ~take & flat & not_worse & (c_prior < 2.0)
        depth[fill] = pd[fill]
        normal[fill] = pn[fill]
        cost[fill] = np.minimum(c_prior[fill], FILL_COST)
        stats["filled"] = int(fill.sum())
    return stats
