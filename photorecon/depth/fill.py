"""Hole filling after the geometric filter: depth for the small gaps that the filter leaves between confirmed
pixels, only where other views' depth maps confirm it.

A pixel loses its depth in the filter when PatchMatch's plane at it is wrong: next to a depth edge its window
straddles the edge and the more textured surface wins (the edge "fattens"), and on weak texture the cost has no
clear minimum. In both cases a confirmed neighbour across the gap often carries the right plane; and where both
views' depth maps fattened an edge alike, the filter keeps the wrong plane, which the pixel's own neighbourhood
contradicts. ``fill_holes``
(the setting ``fill_gaps``):

1. **Holes**: the 8-connected components of pixels without depth, inside the view's mask, not touching the
   image border, of at most ``fill_max_gap`` pixels (a larger gap is a surface the views do not see, or the
   background); and the rim of every larger gap, inside the mask: its pixels next to a kept depth (the pixels
   a depth edge took from the surface beside it).
2. **Candidates**: for each hole pixel, the planes (depth and PatchMatch normal) of the nearest confirmed pixel
   in each of 8 directions, extended to the pixel (fronto-parallel where the plane is seen edge-on); only
   neighbours whose straight path to the pixel runs through the hole.
3. **Evidence**: each candidate goes through the same geometric test as PatchMatch's own depths
   (``filter.consistency_count``, against the same views, with the same tolerances): at least as many views must
   confirm it as the filter requires. Then the images: the mean absolute grey difference of the pixel's
   neighbourhood (the best 2x2 block of its 3x3 that holds it) and the matching sources' (the best source), each
   neighbour projected through the candidate's plane (a slanted surface the source sees foreshortened still
   matches), must be at most the ``PHOTO_QUANTILE`` quantile of the same error at the view's kept depths (their
   noise level: about 0.006 on the synthetic pairs, 0.04 on a real facade pair) and at most ``PHOTO_RATIO`` times
   the lowest of the pixel's candidates, confirmed or not. Next to a depth edge the other view's depth map is
   "fattened" like the reference's, so the near side's plane can be confirmed geometrically where the pixel shows
   the far side: the images tell them apart; and the same fattening hides the far side's plane from the geometric
   test where the pixel does show it. So a candidate the depth maps do not confirm is still taken on the images'
   word when the pixel is **distinct**: its neighbourhood's error at the candidate's plane below that at the
   planes moved along the ray so that its projection moves 2 to ``DISTINCT_PX`` pixels either way along the
   epipolar line, by a margin that follows the images' noise (``DISTINCT_NOISE`` times the kept depths' median
   error, at least ``DISTINCT_GREY``: on a noisy plain wall a depth matches better than its neighbours by chance),
   where no source's depth map sees a surface behind the point (it would hide what that view saw; ``FREE_TOL``),
   and its error at most the ``PHOTO_ONLY_QUANTILE`` quantile of the kept depths'. A rim pixel must be distinct in
   either case (on a plain background beside an object any depth matches as well: without that test the object's
   plane spilled onto it). And a pixel of a small hole (not a rim) whose neighbours in all 8 directions carry
   planes that agree within ``rel_depth`` is **enclosed** by one surface: where neither the depth maps nor the
   images can tell (weak texture: both views' PatchMatch depths wander, any nearby depth matches), that surface is
   the evidence.
4. **Decision**: a pixel takes the passing candidate with the lowest photometric error when all the passing
   candidates agree within ``rel_depth`` (two surfaces at one pixel: no depth); its normal with it, its
   confidence 1 - 1/k for k confirming views, at least ``FILL_CONFIDENCE``.
5. **Edges** (``settle_edges``, after the passes): a kept pixel within ``EDGE_REACH`` pixels of a depth step
   whose own plane the images contradict (its error above the ``PHOTO_QUANTILE`` quantile) takes the plane of
   the surface across the step when that plane matches by the distinct margin better, is itself distinct and
   hides nothing a source saw: the fattened edge that both views' depth maps agree on, so the geometric filter
   kept it.

A filled depth is supported by the other views' depth maps or by their images: a gap that the other views do
not see (an occlusion) or see otherwise stays a gap. On synthetic rectified pairs (``tools/bench_stereo.py``)
the fill puts about 2.4% more of the pixels both views see within 2 px of disparity (knot, room), almost all
next to depth edges, with fewer answers off by more than 2 px (the room: 262 against 621); on a real facade pair
it answers 4-6% more of the pixels, 86-87% of them within 1% of a multi-view depth and 1-2% more than 5% off
it (docs/benchmarks.md).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage as ndi

from ..cameras import backproject_pixels, project
from .config import EDGE_TOL, DepthResult, MVSConfig
from .filter import consistency_count

FILL_PASSES = 2  # passes of the fill, each from the last one's result: a rim grows by a pixel a pass
FILL_CONFIDENCE = 0.25  # a filled pixel's lowest confidence (its TSDF weight): a pair confirms with k = 1
PHOTO_QUANTILE = 0.95  # a candidate's photometric error at most this quantile of the kept depths' own errors ...
PHOTO_RATIO = 1.2  # ... and at most this factor above the lowest of the pixel's candidates (confirmed or not)
PHOTO_SAMPLES = 20000  # kept depths sampled for that quantile
EDGE_ON_COS = 0.1  # a neighbour's plane seen more edge-on than this (|cos| to the pixel's ray) -> fronto-parallel
MAX_DEPTH_RATIO = 1.5  # a plane extended to a pixel further than this factor from its own depth -> fronto-parallel
PHOTO_ONLY_QUANTILE = 0.9  # without the other views' depth: at most this quantile of the kept depths' errors
FREE_TOL = 0.01  # a distinct pixel's plane must not hide, by more than this relative depth, what a source saw
DISTINCT_PX = 4  # a candidate's plane must match the pixel better than the planes that shift it 2..this far ...
DISTINCT_GREY = 0.002  # ... by at least this grey difference (grey 0..1; half an 8-bit grey level) ...
DISTINCT_NOISE = 0.5  # ... and this factor times the median error at the kept depths (the images' noise)
QUADRANTS = ([0, 1, 3, 4], [1, 2, 4, 5], [3, 4, 6, 7], [4, 5, 7, 8])  # the 2x2 blocks of a 3x3 that hold its centre
EDGE_REACH = 3  # settle_edges: pixels this close to a depth step ...
EDGE_STEP = 0.05  # ... of at least this relative depth
DIRECTIONS = ((0, -1), (0, 1), (-1, 0), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1))  # (dy, dx)


def fill_on(cfg: MVSConfig, n_views: int) -> bool:
    """Whether a view checked against ``n_views`` other views gets the fill: ``fill_gaps`` on, or auto and one
    view (a stereo pair: there it puts about 2.4% more pixels within 2 px of disparity on the synthetic pairs of
    ``tools/bench_stereo.py``, with fewer wrong answers)."""
    return cfg.fill_gaps == "on" or (cfg.fill_gaps == "auto" and n_views == 1)


def fillable_holes(depth: np.ndarray, mask: np.ndarray | None, max_hole: int) -> np.ndarray:
    """(H, W) bool: the pixels without depth in 8-connected gaps of at most ``max_hole`` pixels that lie wholly
    inside ``mask`` (True = foreground; None = all) and do not touch the image border."""
    empty = ~(depth > 0)
    lab, n = ndi.label(empty, structure=np.ones((3, 3), bool))
    if n == 0:
        return np.zeros(depth.shape, bool)
    size = np.bincount(lab.ravel(), minlength=n + 1)
    ok = size <= max_hole
    border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    ok[border] = False
    if mask is not None:
        ok[np.unique(lab[empty & ~mask])] = False
    ok[0] = False
    return ok[lab]


def _nearest_in_direction(valid: np.ndarray, dy: int, dx: int) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel, the nearest ``valid`` pixel reached by stepping (dy, dx) from it (itself excluded):
    (row, column) arrays, -1 where the walk leaves the image first."""
    H, W = valid.shape
    ny = np.full((H, W), -1, np.int64)
    nx = np.full((H, W), -1, np.int64)
    # walk against the direction: the answer at p is p + step if that is valid, else the answer at p + step
    ys = range(H - 1, -1, -1) if dy > 0 else range(H) if dy < 0 else None
    xs = range(W - 1, -1, -1) if dx > 0 else range(W) if dx < 0 else None
    if dy == 0:  # along rows, all rows at once
        for x in xs:
            x1 = x + dx
            if not 0 <= x1 < W:
                continue
            hit = valid[:, x1]
            ny[:, x] = np.where(hit, np.arange(H), ny[:, x1])
            nx[:, x] = np.where(hit, x1, nx[:, x1])
        return ny, nx
    for y in ys:  # row by row, each row from the one after it
        y1 = y + dy
        if not 0 <= y1 < H:
            continue
        cols = np.arange(W) + dx
        inside = (cols >= 0) & (cols < W)
        c = np.clip(cols, 0, W - 1)
        hit = valid[y1, c] & inside
        ny[y] = np.where(hit, y1, np.where(inside, ny[y1, c], -1))
        nx[y] = np.where(hit, c, np.where(inside, nx[y1, c], -1))
    return ny, nx


def _plane_depth(zq: np.ndarray, n: np.ndarray, rq: np.ndarray, rp: np.ndarray) -> np.ndarray:
    """The depth along the rays ``rp`` (N, 3; z = 1) of the planes through the points ``zq * rq`` with normals
    ``n`` (camera frame); ``zq`` itself where a plane is seen edge-on from ``rp`` or would put the point more
    than ``MAX_DEPTH_RATIO`` away from ``zq`` (fronto-parallel then)."""
    num = np.einsum("ij,ij->i", n, rq) * zq
    den = np.einsum("ij,ij->i", n, rp)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = num / den
    edge_on = np.abs(den) < EDGE_ON_COS * np.linalg.norm(rp, axis=1)
    bad = ~np.isfinite(z) | edge_on | (z <= 0) | (z > zq * MAX_DEPTH_RATIO) | (z < zq / MAX_DEPTH_RATIO)
    return np.where(bad, zq, z)


def _extend_plane(depth: np.ndarray, normal: np.ndarray | None, intr, py: np.ndarray, px: np.ndarray,
                  qy: np.ndarray, qx: np.ndarray) -> np.ndarray:
    """The depth at pixels (py, px) of the planes of pixels (qy, qx) (their depth and normal, camera frame, in
    the view of ``intr``); the neighbour's own depth where its plane is seen edge-on or has no normal."""
    zq = depth[qy, qx].astype(np.float64)
    if normal is None:
        return zq
    return _plane_depth(zq, normal[qy, qx].astype(np.float64), intr.pixel_rays(np.stack([qx, qy], 1)),
                        intr.pixel_rays(np.stack([px, py], 1)))


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``img`` at the sub-pixel positions (x, y), bilinear, clamped at the border."""
    h, w = img.shape
    x = np.clip(x, 0, w - 1)
    y = np.clip(y, 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2) if w > 1 else np.zeros(len(x), np.int64)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2) if h > 1 else np.zeros(len(y), np.int64)
    fx, fy = x - x0, y - y0
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def photometric_error(grey: np.ndarray, r: DepthResult, images: dict[str, tuple[np.ndarray, object]],
                      py: np.ndarray, px: np.ndarray, z: np.ndarray, radius: int = 1,
                      normal: np.ndarray | None = None) -> np.ndarray:
    """Per pixel (py, px) at depth z of view ``r`` (grey image ``grey``): the mean absolute grey difference of its
    neighbourhood and the source images' (``images``: name -> (grey, view)) around its projection, the lowest
    over the sources (occlusion-robust); +inf where it projects into none. The neighbourhood: the best of the
    four 2x2 blocks of its 3x3 that hold the pixel (shiftable windows: next to a depth edge one of them lies on
    the pixel's own side); ``radius`` 0: the pixel alone. ``normal`` (N, 3), camera frame: the neighbourhood
    lies on the plane through the point with that normal (each neighbour projected at the plane's depth there,
    so a slanted surface that the source sees foreshortened still matches); without it, or where the plane is
    seen edge-on, at the pixel's depth."""
    z = np.asarray(z, np.float64)
    normal = None if normal is None else np.asarray(normal, np.float64)
    H, W = grey.shape
    offs = [(oy, ox) for oy in range(-radius, radius + 1) for ox in range(-radius, radius + 1)]
    ref = np.stack([grey[np.clip(py + oy, 0, H - 1), np.clip(px + ox, 0, W - 1)] for oy, ox in offs], 1)
    intr, T_ref = r.view.intrinsics, r.view.cam_from_world
    ray_c = None if normal is None else intr.pixel_rays(np.stack([px, py], 1))
    # the neighbourhood's projection: the pixel's, and how it moves per pixel right and down on the plane (its
    # local affine map; exact for the 1-pixel offsets of a 3x3 up to the plane's perspective, far below a pixel)
    points = []
    for ox, oy in ((0, 0), (1, 0), (0, 1)):
        uv = np.stack([px + ox, py + oy], 1)
        # the plane's depth at the neighbour, unless it is seen edge-on
        zo = z if normal is None or not (ox or oy) else _plane_depth(z, normal, ray_c, intr.pixel_rays(uv))
        points.append(backproject_pixels(uv, zo, intr, T_ref))
    best = np.full(len(py), np.inf)
    for img, view in images.values():
        hs, ws = img.shape
        (c, zs), (cx, _), (cy, _) = (project(X, view.intrinsics, view.cam_from_world) for X in points)
        u, v = c[:, 0], c[:, 1]
        with np.errstate(invalid="ignore"):
            ok = (zs > 0) & (u >= -EDGE_TOL) & (v >= -EDGE_TOL) & (u <= ws - 1 + EDGE_TOL) & (v <= hs - 1 + EDGE_TOL)
        c, cx, cy = np.nan_to_num(c), np.nan_to_num(cx), np.nan_to_num(cy)
        step_x, step_y = cx - c, cy - c  # per pixel right, per pixel down
        src = np.stack([_bilinear(img, *(c + ox * step_x + oy * step_y).T) for oy, ox in offs], 1)
        a = np.abs(src - ref)
        if radius == 1:  # the best of the four 2x2 quadrants that hold the pixel (shiftable windows)
            e = np.min(np.stack([a[:, q].mean(1) for q in QUADRANTS], 1), axis=1)
        else:
            e = a.mean(1)
        best = np.where(ok, np.minimum(best, e), best)
    return best


def _not_seen_through(r: DepthResult, sources: dict[str, DepthResult], py, px, z, tol: float) -> np.ndarray:
    """Per pixel (py, px) of ``r`` at depth z: True unless a source's depth map sees a surface behind the point
    (its depth at the point's projection more than ``tol`` (relative) beyond the point's own depth there: the
    point would hide what that view saw)."""
    Xw = backproject_pixels(np.stack([px, py], 1), z, r.view.intrinsics, r.view.cam_from_world)
    ok = np.ones(len(py), bool)
    for s in sources.values():
        uv, zs = project(Xw, s.view.intrinsics, s.view.cam_from_world)
        h, w = s.depth.shape
        with np.errstate(invalid="ignore"):
            u, v = np.round(uv[:, 0]), np.round(uv[:, 1])
            inside = (zs > 0) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
        ds = np.zeros(len(py))
        ds[inside] = s.depth[v[inside].astype(np.int64), u[inside].astype(np.int64)]
        ok &= ~(inside & (ds > zs * (1 + tol)))
    return ok


def _epipolar_motion(r: DepthResult, view, py: np.ndarray, px: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Per pixel (py, px) of ``r`` at depth z: how many pixels its projection into ``view`` moves when the depth
    grows by 1%; a depth change that moves it ``n`` pixels is then about ``0.01 * n / motion`` of the depth."""
    uv0, uv1 = (project(backproject_pixels(np.stack([px, py], 1), z * f, r.view.intrinsics, r.view.cam_from_world),
                        view.intrinsics, view.cam_from_world)[0] for f in (1.0, 1.01))
    return np.linalg.norm(uv1 - uv0, axis=1)


def fill_holes(r: DepthResult, sources: dict[str, DepthResult], cfg: MVSConfig, need: int, grey: np.ndarray,
               images: dict[str, tuple[np.ndarray, object]], mask: np.ndarray | None = None,
               passes: int = FILL_PASSES, enclosed: bool = True) -> tuple[np.ndarray, dict]:
    """Fill the small holes of ``r`` (its depth after the geometric filter; its normals PatchMatch's) with
    neighbours' planes that at least ``need`` of ``sources`` confirm (``consistency_count`` with ``cfg``, the
    filter's settings) or the images alone do, and the images accept (``photometric_error`` of ``grey``, the
    view's image, against ``images``, name -> (grey image, view) of its matching sources); up to ``passes``
    times, each from what the one before filled (a rim grows by a pixel a pass); then ``settle_edges``. Changes
    ``r.depth``, ``r.normal`` and ``r.confidence`` in place; returns the filled pixels (bool) and stats
    (``hole_pixels``: the first pass's; ``settled``: the edge pixels given the plane across the edge).
    ``enclosed``: a small hole's pixel enclosed by one plane in all 8 directions takes it (step 3)."""
    filled = np.zeros(r.depth.shape, bool)
    stats: dict = {}
    for p in range(max(1, passes)):
        got, st = _fill_pass(r, sources, cfg, need, grey, images, mask, enclosed)
        filled |= got
        stats = st if p == 0 else {**stats, "filled": stats["filled"] + st["filled"],
                                   "conflicting": stats.get("conflicting", 0) + st.get("conflicting", 0)}
        if not st["filled"]:
            break
    stats["settled"] = int(settle_edges(r, sources, grey, images).sum())
    return filled, stats


def _noise_levels(r: DepthResult, grey: np.ndarray, images: dict) -> tuple[float, float, float]:
    """The photometric error at the view's kept depths (a sample of ``PHOTO_SAMPLES``), as the thresholds the
    fill uses: the distinct margin, the ``PHOTO_QUANTILE`` and the ``PHOTO_ONLY_QUANTILE`` quantiles."""
    d = r.depth
    vy, vx = np.nonzero(d > 0)
    step = max(1, len(vy) // PHOTO_SAMPLES)
    e = photometric_error(grey, r, images, vy[::step], vx[::step], d[vy[::step], vx[::step]].astype(np.float64))
    e = e[np.isfinite(e)]
    if not len(e):
        return DISTINCT_GREY, 0.0, 0.0
    return (max(DISTINCT_GREY, DISTINCT_NOISE * float(np.median(e))), float(np.quantile(e, PHOTO_QUANTILE)),
            float(np.quantile(e, PHOTO_ONLY_QUANTILE)))


def _distinct(r: DepthResult, grey: np.ndarray, images: dict, py: np.ndarray, px: np.ndarray, z: np.ndarray,
              normal: np.ndarray | None, e0: np.ndarray, margin: float) -> np.ndarray:
    """Per pixel (py, px) of ``r`` with a plane (depth z, ``normal``) whose photometric error is ``e0``: True where
    the planes moved along the ray so that the projection into the first of ``images`` moves 2 to ``DISTINCT_PX``
    pixels either way along the epipolar line all match worse by at least ``margin``. A pixel leaves at the first
    shift that matches as well."""
    motion = _epipolar_motion(r, next(iter(images.values()))[1], py, px, z)
    alive = np.ones(len(py), bool)  # still distinct after the shifts so far
    for shift in range(2, int(DISTINCT_PX) + 1):
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.nan_to_num(np.minimum(0.01 * shift / motion, 0.5), nan=0.0, posinf=0.0)
        for sign in (-1, 1):
            a = np.flatnonzero(alive)
            e_alt = photometric_error(grey, r, images, py[a], px[a], z[a] * (1 + sign * f[a]),
                                      normal=None if normal is None else normal[a])
            alive[a] = e_alt >= e0[a] + margin
    return alive


def settle_edges(r: DepthResult, sources: dict[str, DepthResult], grey: np.ndarray,
                 images: dict[str, tuple[np.ndarray, object]], reach: int = EDGE_REACH) -> np.ndarray:
    """Next to a depth edge, give a kept pixel the plane of the surface across the edge where its own
    neighbourhood shows that surface: PatchMatch's window straddles the edge and the more textured side wins
    (the edge "fattens"), and both views' depth maps fatten alike, so the geometric filter keeps it. For each
    kept pixel within ``reach`` pixels of a depth step (``EDGE_STEP``), the planes of the nearest pixels across
    it in 8 directions are tried with the fill's photometric test (the best 2x2 block through the plane). The
    best replaces the pixel's own plane when the images contradict the own plane (its error above the
    ``PHOTO_QUANTILE`` quantile of the kept depths'), the new one's error is below the own plane's by the
    distinct margin and within that quantile, it is distinct itself (``_distinct``) and it does not hide what a
    source saw (``FREE_TOL``). Without the first and the fourth conditions the swaps on a real facade pair
    moved away from a multi-view depth. Changes ``r.depth`` and ``r.normal`` in place; returns the changed
    pixels (bool)."""
    d = r.depth
    valid = d > 0
    changed = np.zeros(d.shape, bool)
    if r.normal is None or not valid.any():
        return changed
    margin, e_max, _ = _noise_levels(r, grey, images)
    size = 2 * reach + 1
    hi = ndi.maximum_filter(np.where(valid, d, 0), size=size)
    lo = ndi.minimum_filter(np.where(valid, d, np.inf), size=size)
    near_edge = valid & ((hi > d * (1 + EDGE_STEP)) | (lo < d / (1 + EDGE_STEP)))
    py, px = np.nonzero(near_edge)
    if not len(py):
        return changed
    H, W = d.shape
    z0 = d[py, px].astype(np.float64)
    e_own = photometric_error(grey, r, images, py, px, z0, normal=r.normal[py, px])
    best_e = np.full(len(py), np.inf)
    best_z = np.zeros(len(py))
    best_q = np.zeros((len(py), 2), np.int64)
    for dy, dx in DIRECTIONS:
        qy = np.full(len(py), -1, np.int64)
        qx = np.full(len(py), -1, np.int64)
        for k in range(reach, 0, -1):  # the nearest pixel across the step in this direction wins
            y, x = py + k * dy, px + k * dx
            inside = (y >= 0) & (y < H) & (x >= 0) & (x < W)
            yc, xc = np.clip(y, 0, H - 1), np.clip(x, 0, W - 1)
            dq = d[yc, xc]
            across = inside & (dq > 0) & ((dq > z0 * (1 + EDGE_STEP)) | (dq < z0 / (1 + EDGE_STEP)))
            qy = np.where(across, yc, qy)
            qx = np.where(across, xc, qx)
        ok = np.flatnonzero(qy >= 0)
        if not len(ok):
            continue
        z = _extend_plane(d, r.normal, r.view.intrinsics, py[ok], px[ok], qy[ok], qx[ok])
        e = photometric_error(grey, r, images, py[ok], px[ok], z, normal=r.normal[qy[ok], qx[ok]])
        better = e < best_e[ok]
        i = ok[better]
        best_e[i], best_z[i] = e[better], z[better]
        best_q[i] = np.stack([qy[ok][better], qx[ok][better]], 1)
    swap = np.flatnonzero((e_own > e_max) & (best_e + margin <= e_own) & (best_e <= e_max))
    if len(swap):
        qn = r.normal[best_q[swap, 0], best_q[swap, 1]]
        swap = swap[_distinct(r, grey, images, py[swap], px[swap], best_z[swap], qn, best_e[swap], margin)]
    if len(swap):
        swap = swap[_not_seen_through(r, sources, py[swap], px[swap], best_z[swap], FREE_TOL)]
    sy, sx = py[swap], px[swap]
    d[sy, sx] = best_z[swap]
    r.normal[sy, sx] = r.normal[best_q[swap, 0], best_q[swap, 1]]
    changed[sy, sx] = True
    return changed


def _fill_pass(r: DepthResult, sources: dict[str, DepthResult], cfg: MVSConfig, need: int, grey: np.ndarray,
               images: dict[str, tuple[np.ndarray, object]], mask: np.ndarray | None,
               enclosed: bool) -> tuple[np.ndarray, dict]:
    """One pass of ``fill_holes``."""
    d = r.depth
    valid = d > 0
    holes = fillable_holes(d, mask, cfg.fill_max_gap)
    rim = ~valid & ~holes & ndi.binary_dilation(valid, np.ones((3, 3), bool))  # the larger gaps' edge pixels
    if mask is not None:
        rim &= mask
    holes = holes | rim
    stats = {"hole_pixels": int(holes.sum()), "filled": 0}
    if not holes.any() or need < 1:
        return np.zeros(d.shape, bool), stats
    py, px = np.nonzero(holes)
    on_rim = rim[py, px]
    margin, e_max, e_only = _noise_levels(r, grey, images)
    n_dir = len(DIRECTIONS)
    z_c = np.zeros((n_dir, len(py)))
    cnt_c = np.zeros((n_dir, len(py)), np.int32)
    e_c = np.full((n_dir, len(py)), np.inf)
    q_c = np.full((n_dir, len(py), 2), -1, np.int64)
    distinct = np.zeros((n_dir, len(py)), bool)
    for k, (dy, dx) in enumerate(DIRECTIONS):
        ny, nx = _nearest_in_direction(valid, dy, dx)
        qy, qx = ny[py, px], nx[py, px]
        ok = qy >= 0
        # the path to the neighbour runs through hole pixels only (walks stop at the first valid pixel, so
        # only the pixel before it has to be checked to be in a fillable hole, not a masked or large gap)
        steps = np.maximum(np.abs(qy - py), np.abs(qx - px))
        by, bx = qy - dy, qx - dx
        ok &= (steps <= 1) | holes[np.clip(by, 0, d.shape[0] - 1), np.clip(bx, 0, d.shape[1] - 1)]
        if not ok.any():
            continue
        cand = np.zeros(d.shape, np.float32)
        z = _extend_plane(d, r.normal, r.view.intrinsics, py[ok], px[ok], qy[ok], qx[ok])
        cand[py[ok], px[ok]] = z
        cn = None
        if r.normal is not None:
            cn = np.zeros(r.normal.shape, np.float32)
            cn[py[ok], px[ok]] = r.normal[qy[ok], qx[ok]]
        cnt, _, _ = consistency_count(dataclasses.replace(r, depth=cand, normal=cn), sources, cfg)
        z_c[k, ok] = z
        cnt_c[k, ok] = cnt[py[ok], px[ok]]
        q_c[k, ok] = np.stack([qy[ok], qx[ok]], 1)
        e_c[k, ok] = photometric_error(grey, r, images, py[ok], px[ok], z,
                                       normal=None if r.normal is None else r.normal[qy[ok], qx[ok]])
        # distinct: the neighbourhood at the candidate's plane and at the planes 2..DISTINCT_PX pixels along the
        # epipolar line; only where it can decide (a rim pixel, or one the depth maps do not confirm), and the
        # error passes the test it would take part in
        e_k = e_c[k]
        kk = np.flatnonzero(ok & (e_k <= e_max) & (on_rim | ((cnt_c[k] < need) & (e_k <= e_only))))
        nk = None if r.normal is None else r.normal[q_c[k, kk, 0], q_c[k, kk, 1]]
        alive = _distinct(r, grey, images, py[kk], px[kk], z_c[k, kk], nk, e_k[kk], margin)
        distinct[k, kk] = alive
        distinct[k, kk[alive]] &= _not_seen_through(r, sources, py[kk[alive]], px[kk[alive]], z_c[k, kk[alive]],
                                                    FREE_TOL)
        e_c[k, on_rim & ~distinct[k]] = np.inf
    e_min = np.min(np.where(z_c > 0, e_c, np.inf), axis=0)
    # a hole pixel whose neighbours in all 8 directions carry planes that agree lies inside one surface
    z_lo = np.min(np.where(z_c > 0, z_c, np.inf), axis=0)
    inside = enclosed & ~on_rim & (z_c > 0).all(0) & (np.max(z_c, axis=0) - z_lo <= cfg.rel_depth * z_lo)
    # the other views' depth maps, or the images alone, or the surface all around
    seen = (cnt_c >= need) | (distinct & (e_c <= e_only)) | inside[None, :]
    confirmed = seen & (z_c > 0) & (e_c <= e_max) & (e_c <= e_min * PHOTO_RATIO + 1e-6)
    has = confirmed.any(0)
    lo = np.min(np.where(confirmed, z_c, np.inf), axis=0)
    hi = np.max(np.where(confirmed, z_c, -np.inf), axis=0)
    agree = has & (hi - lo <= cfg.rel_depth * lo)
    best = np.argmin(np.where(confirmed, e_c, np.inf), axis=0)
    sel = np.flatnonzero(agree)
    fy, fx = py[sel], px[sel]
    k = best[sel]
    d[fy, fx] = z_c[k, sel]
    qy, qx = q_c[k, sel, 0], q_c[k, sel, 1]
    if r.normal is not None:
        r.normal[fy, fx] = r.normal[qy, qx]
    if r.confidence is not None:
        kk = cnt_c[k, sel].astype(np.float32)
        r.confidence[fy, fx] = np.maximum(FILL_CONFIDENCE, 1.0 - 1.0 / np.maximum(kk, 1))
    filled = np.zeros(d.shape, bool)
    filled[fy, fx] = True
    stats["filled"] = int(len(sel))
    stats["conflicting"] = int((has & ~agree).sum())
    stats["photo_max"] = e_max
    return filled, stats
