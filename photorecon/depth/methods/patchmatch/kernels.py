"""Compiled PatchMatch kernels (numba, ``parallel=True, cache=True``): per-pixel work numpy cannot express.

A hypothesis at reference pixel ``p = (x, y)`` is a plane: a z-depth ``d`` and a unit normal ``n`` in the
reference camera frame (OpenCV axes), facing the camera (``n . ray < 0``). Its plane ``n^T X = c`` with
``c = d n^T K_r^-1 p`` induces, in source ``j`` (``X_j = R_j X + t_j``), the homography

    H_j = K_j R_j K_r^-1 + (K_j t_j) (K_r^-T n / c)^T = A_j + b_j m^T,

so a hypothesis costs 9 multiply-adds per source before its window is sampled. The matching cost is
``1 - NCC`` (0 = identical, 2 = opposite), the NCC weighted bilaterally (by distance and by grey difference
to the centre pixel of the reference window, as in Gipuma / ACMH) over a strided window. Pixels are updated
in a red-black checkerboard: a pass over one colour reads only the other colour's hypotheses, so the result
does not depend on thread scheduling; random numbers come from a hash of (seed, iteration, pixel).

The file has four parts, in this order: the window and sampling layouts (plain numpy), the NCC primitives
(``_ref_window``, ``_ncc`` and its helpers), the plane geometry (homographies, the geometric term, random
planes) and the passes (``init_random``, ``upsample_planes``, ``initial_cost``, ``pm_pass``), then ``ncc_at``
for the tests. It stays one file on purpose: numba's cache (``cache=True``) checks only the source file of the
kernel it loads, so a pass cached with a primitive compiled (inlined) into it from another file would keep
running the old primitive after that file changed. Every kernel here is rebuilt when this file changes.

Every kernel takes contiguous arrays and scalars, and the slow, obviously correct ``ncc_cost_reference`` in
``solver.py`` pins ``_ncc`` in the tests.
"""
from __future__ import annotations

import math

import numpy as np

from ...config import EDGE_TOL
from ....jit import njit, prange

N_REFINE = 6  # hypotheses of the refinement step: (perturbed | random) x (depth | normal | both)
# pm_pass's per-row counts: pixels computed, pixels left as converged, NCC evaluations (candidates, refinement)
COUNT_PIXELS, COUNT_SKIPPED, COUNT_CANDIDATE, COUNT_REFINE = 0, 1, 2, 3
N_COUNTS = 4
MAX_CARRIED_SOURCES = 31  # pm_pass' view selection bits per pixel: one int32


# --- the window and sampling layouts (numpy) ----------------------------------------------------------------
def sampling_regions(strip: int = 11) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 8 neighbourhood regions of ACMH's adaptive checkerboard sampling, as (dy, dx) offsets padded to a
    common length, and each region's sample count. Every offset has an odd |dy| + |dx|: the other colour."""
    regions: list[list[tuple[int, int]]] = []
    for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):  # far strips: distance 1, 3, 5, ...
        regions.append([(dy * (2 * k + 1), dx * (2 * k + 1)) for k in range(strip)])
    v = [(1, 2), (2, 1), (1, 4), (4, 1), (2, 3), (3, 2), (3, 4)]  # near V-shaped areas, one per quadrant
    for sy, sx in ((-1, -1), (-1, 1), (1, -1), (1, 1)):
        regions.append([(sy * a, sx * b) for a, b in v])
    n = max(len(r) for r in regions)
    rdy = np.zeros((len(regions), n), np.int32)
    rdx = np.zeros((len(regions), n), np.int32)
    rn = np.array([len(r) for r in regions], np.int32)
    for i, r in enumerate(regions):
        for k, (dy, dx) in enumerate(r):
            assert (abs(dy) + abs(dx)) % 2 == 1
            rdy[i, k], rdx[i, k] = dy, dx
    return rdy, rdx, rn


def window_samples(radius: int, stride: int, sigma_space: float, checker: bool = False
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Offsets (dy, dx) of a strided square window, row by row, and their spatial weights
    exp(-r^2 / (2 sigma_s^2)). ``checker``: every other sample of that grid, as on a checkerboard (half the
    samples over the same extent; each row keeps every other sample, odd rows shifted by ``stride``)."""
    r = np.arange(-radius, radius + 1, stride)
    iy, ix = np.meshgrid(np.arange(len(r)), np.arange(len(r)), indexing="ij")
    keep = ((iy + ix) % 2 == 0) if checker else np.ones(iy.shape, bool)
    dy, dx = r[iy[keep]].astype(np.int32), r[ix[keep]].astype(np.int32)
    w = np.exp(-(dy.astype(np.float64) ** 2 + dx ** 2) / (2 * sigma_space ** 2)).astype(np.float32)
    return dy, dx, w


# --- random numbers, NCC primitives ---------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _rand(s):
    """xorshift32 step on an int64 holding 32 bits; returns (state, uniform in [0, 1))."""
    s ^= (s << 13) & 0xFFFFFFFF
    s ^= s >> 17
    s ^= (s << 5) & 0xFFFFFFFF
    return s, (s & 0xFFFFFF) / 16777216.0


@njit(cache=True, inline="always")
def _seed(seed, it, y, x):
    s = (seed * 73856093 + it * 19349663 + y * 83492791 + x * 2654435761 + 12345) & 0xFFFFFFFF
    for _ in range(3):
        s ^= (s << 13) & 0xFFFFFFFF
        s ^= s >> 17
        s ^= (s << 5) & 0xFFFFFFFF
    if s == 0:
        s = 1
    return s


@njit(cache=True)
def _window_row(sdy, sdx):
    """Samples per row when the window offsets are rows of that many samples at one constant x step
    (``window_samples``' grid and its checkerboard: ``_ncc`` walks them by constant steps), else 0."""
    n = sdy.shape[0]
    row = 1
    while row < n and sdy[row] == sdy[0]:
        row += 1
    if row < 2 or n % row != 0:
        return 0
    step = sdx[1] - sdx[0]
    for k in range(n):
        if k % row != 0 and (sdx[k] - sdx[k - 1] != step or sdy[k] != sdy[k - 1]):
            return 0
    return row


@njit(cache=True, fastmath=True)
def _ref_window(ref, x, y, sdy, sdx, sspat, inv2sc2, min_var, rv, wk, du, dv, row):
    """Fill the reference window's values ``rv``, bilateral weights ``wk`` and sample offsets ``du, dv``
    (clamped to the image); returns (sum w, mean, var, radius, row): the radius is the largest |offset| over all
    samples (not the first sample's: offsets are clamped at the image border), for ``_ncc``'s bounds shortcut;
    row: ``row`` (``_window_row``) when no offset was clamped, else 0."""
    H, W = ref.shape
    c = ref[y, x]
    sw = 0.0
    s1 = 0.0
    s2 = 0.0
    rad = 0.0
    n = sdy.shape[0]
    clamped = False
    for k in range(n):
        v = min(max(y + sdy[k], 0), H - 1)
        u = min(max(x + sdx[k], 0), W - 1)
        du[k] = u - x
        dv[k] = v - y
        if v != y + sdy[k] or u != x + sdx[k]:
            clamped = True
        rad = max(rad, abs(du[k]), abs(dv[k]))
        val = ref[v, u]
        dc = val - c
        w = sspat[k] * math.exp(-dc * dc * inv2sc2)
        rv[k] = val
        wk[k] = w
        sw += w
        s1 += w * val
        s2 += w * val * val
    mr = s1 / sw
    vr = s2 / sw - mr * mr
    if vr < min_var:
        vr = min_var
    return sw, mr, vr, rad, 0 if clamped else row


@njit(cache=True, fastmath=True, inline="always")
def _ncc(img, x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, h, min_var):
    """1 - bilaterally weighted NCC between the reference window at (x, y) (offsets ``du, dv``, values ``rv``,
    weights ``wk`` summing to ``sw``, weighted mean ``mr`` and variance ``vr``, largest |offset| ``rad``) and ``img`` sampled through the
    homography ``h`` (9 values, row-major), linearised at the window's centre (an affine map: over an
    11-pixel window the perspective term is far below a hundredth of a pixel); 2 when the centre falls
    outside the source image (beyond its first and last pixel centres by more than ``EDGE_TOL``: a rectified
    pair's border row lands on the last one give or take rounding) or behind it."""
    hs, ws = img.shape
    hz = h[6] * x + h[7] * y + h[8]
    if hz <= 1e-12:
        return 2.0
    iz = 1.0 / hz
    cx = (h[0] * x + h[1] * y + h[2]) * iz
    cy = (h[3] * x + h[4] * y + h[5]) * iz
    if cx < -EDGE_TOL or cy < -EDGE_TOL or cx > ws - 1.0 + EDGE_TOL or cy > hs - 1.0 + EDGE_TOL:
        return 2.0
    # Jacobian of the homography at the centre
    j00 = (h[0] - cx * h[6]) * iz
    j01 = (h[1] - cx * h[7]) * iz
    j10 = (h[3] - cy * h[6]) * iz
    j11 = (h[4] - cy * h[7]) * iz
    xmax = ws - 1.001
    ymax = hs - 1.001
    s1 = 0.0
    s2 = 0.0
    s12 = 0.0
    # the window's footprint in the source: when it lies inside the image, no sample needs clamping
    ex = (abs(j00) + abs(j01)) * rad
    ey = (abs(j10) + abs(j11)) * rad
    inside = cx - ex >= 0.0 and cx + ex <= xmax and cy - ey >= 0.0 and cy + ey <= ymax
    if inside and grid > 0:
        # an unclamped window of rows (``grid`` samples each, one x step) wholly inside the source: walk each
        # row by constant steps; the default windows (6 rows of 6, and their checkerboard, 6 rows of 3) with
        # constant loop bounds, which the compiler unrolls
        step = du[1] - du[0]
        stx = j00 * step
        sty = j10 * step
        n = du.shape[0]
        if grid == 6 and n == 36:
            s1, s2, s12 = _walk_rows(img, cx, cy, j00, j01, j10, j11, du, dv, rv, wk, stx, sty, 6, 6)
        elif grid == 3 and n == 18:
            s1, s2, s12 = _walk_rows(img, cx, cy, j00, j01, j10, j11, du, dv, rv, wk, stx, sty, 6, 3)
        else:
            s1, s2, s12 = _walk_rows(img, cx, cy, j00, j01, j10, j11, du, dv, rv, wk, stx, sty, n // grid, grid)
        return _ncc_finish(s1, s2, s12, sw, mr, vr, min_var)
    for k in range(du.shape[0]):
        sx = cx + j00 * du[k] + j01 * dv[k]
        sy = cy + j10 * du[k] + j11 * dv[k]
        if not inside:
            sx = min(max(sx, 0.0), xmax)
            sy = min(max(sy, 0.0), ymax)
        val = _bilerp(img, sx, sy)
        wv = wk[k] * val
        s1 += wv
        s2 += wv * val
        s12 += wv * rv[k]
    return _ncc_finish(s1, s2, s12, sw, mr, vr, min_var)


@njit(cache=True, fastmath=True, inline="always")
def _walk_rows(img, cx, cy, j00, j01, j10, j11, du, dv, rv, wk, stx, sty, nrows, ncols):
    """Weighted sums (s1, s2, s12) of ``img`` over a window of ``nrows`` rows of ``ncols`` samples each (one
    x step: (``stx``, ``sty``) in the source per sample), every sample inside the source image."""
    s1 = 0.0
    s2 = 0.0
    s12 = 0.0
    for r in range(nrows):
        k0 = r * ncols
        sx = cx + j00 * du[k0] + j01 * dv[k0]
        sy = cy + j10 * du[k0] + j11 * dv[k0]
        for c in range(ncols):
            k = k0 + c
            val = _bilerp(img, sx, sy)
            wv = wk[k] * val
            s1 += wv
            s2 += wv * val
            s12 += wv * rv[k]
            sx += stx
            sy += sty
    return s1, s2, s12


@njit(cache=True, fastmath=True, inline="always")
def _bilerp(img, sx, sy):
    """``img`` bilinearly at (sx, sy), which must lie in [0, w - 1) x [0, h - 1). Unsigned indices: no
    wrap-around test for negative ones."""
    ix = np.uintp(sx)
    iy = np.uintp(sy)
    fx = sx - np.float64(ix)
    fy = sy - np.float64(iy)
    ix1 = ix + np.uintp(1)
    iy1 = iy + np.uintp(1)
    a = img[iy, ix]
    b = img[iy, ix1]
    c = img[iy1, ix]
    d = img[iy1, ix1]
    return a + fx * (b - a) + fy * (c - a + fx * (a - b - c + d))


@njit(cache=True, fastmath=True, inline="always")
def _ncc_finish(s1, s2, s12, sw, mr, vr, min_var):
    ms = s1 / sw
    vs = s2 / sw - ms * ms
    if vs < min_var:
        vs = min_var
    cov = s12 / sw - mr * ms
    cost = 1.0 - cov / math.sqrt(vr * vs)
    if cost < 0.0:
        return 0.0
    if cost > 2.0:
        return 2.0
    return cost


# --- plane geometry ---------------------------------------------------------------------------------------------
@njit(cache=True)
def _homography(A, b, j, m, h):
    for r in range(3):
        for c in range(3):
            h[3 * r + c] = A[j, r, c] + b[j, r] * m[c]


@njit(cache=True)
def _plane_m(d, n0, n1, n2, r0, r1, r2, Kinv, m):
    """m = K_r^-T n / c with c = n . (d * ray): the hypothesis' term of every source homography.
    Returns False for a plane seen edge-on."""
    c = d * (n0 * r0 + n1 * r1 + n2 * r2)
    if abs(c) < 1e-12:
        return False
    for k in range(3):
        m[k] = (Kinv[0, k] * n0 + Kinv[1, k] * n1 + Kinv[2, k] * n2) / c
    return True


@njit(cache=True, inline="always")
def _geo_rays(GP, r0, r1, r2, q):
    """q[j] = Kd_j R_j ray: the reference pixel's ray in source ``j``'s depth-map pixels (homogeneous), once per
    pixel; a hypothesis at depth d then projects to d q[j] + Ge[j]."""
    for j in range(GP.shape[0]):
        for k in range(3):
            q[j, k] = GP[j, k, 0] * r0 + GP[j, k, 1] * r1 + GP[j, k, 2] * r2


@njit(cache=True, fastmath=True, inline="always")
def _geo(j, d, q, Ge, GM, Gg, sdepth, x, y, delta):
    """Forward-backward reprojection error (reference pixels, capped at ``delta``) of the point at depth ``d``
    on the pixel's ray through source ``j``'s depth map, as in ACMM. With Kd, R, t (source depth map's
    intrinsics, source from reference) and Kr: forward p = d q[j] + Ge[j] (Ge = Kd t), the source pixel
    (u, v) = p / p_2; backward, with the source's depth ds at the nearest pixel, the reference pixel of
    ds / p_2 GM[j] p - Gg[j] (GM = Kr R^T Kd^-1, Gg = Kr R^T t)."""
    hs, ws = sdepth.shape[1], sdepth.shape[2]
    p0 = d * q[j, 0] + Ge[j, 0]
    p1 = d * q[j, 1] + Ge[j, 1]
    p2 = d * q[j, 2] + Ge[j, 2]
    if p2 <= 1e-12:
        return delta
    u = p0 / p2
    v = p1 / p2
    if not (u > -0.5 and v > -0.5 and u < ws - 0.5 and v < hs - 0.5):
        return delta
    ds = sdepth[j, int(v + 0.5), int(u + 0.5)]
    if ds <= 0.0:
        return delta
    s = ds / p2
    B2 = s * (GM[j, 2, 0] * p0 + GM[j, 2, 1] * p1 + GM[j, 2, 2] * p2) - Gg[j, 2]
    if B2 <= 1e-12:
        return delta
    B0 = s * (GM[j, 0, 0] * p0 + GM[j, 0, 1] * p1 + GM[j, 0, 2] * p2) - Gg[j, 0]
    B1 = s * (GM[j, 1, 0] * p0 + GM[j, 1, 1] * p1 + GM[j, 1, 2] * p2) - Gg[j, 1]
    eu = B0 / B2 - x
    ev = B1 / B2 - y
    e2 = eu * eu + ev * ev
    if e2 >= delta * delta:
        return delta
    return math.sqrt(e2)


@njit(cache=True)
def _random_normal(s, r0, r1, r2):
    s, u1 = _rand(s)
    s, u2 = _rand(s)
    z = 2.0 * u1 - 1.0
    rr = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    n0, n1, n2 = rr * math.cos(phi), rr * math.sin(phi), z
    if n0 * r0 + n1 * r1 + n2 * r2 > 0:
        n0, n1, n2 = -n0, -n1, -n2
    return s, n0, n1, n2


@njit(cache=True)
def _facing(n0, n1, n2, r0, r1, r2):
    """Normalise n and make it face the camera along the ray r."""
    nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if nn < 1e-12:
        rn = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        return -r0 / rn, -r1 / rn, -r2 / rn
    n0, n1, n2 = n0 / nn, n1 / nn, n2 / nn
    if n0 * r0 + n1 * r1 + n2 * r2 > 0:
        return -n0, -n1, -n2
    return n0, n1, n2


# --- the passes -------------------------------------------------------------------------------------------------
@njit(parallel=True, cache=True)
def init_random(depth, normal, Kinv, dmin, dmax, seed, only_invalid):
    """Random hypotheses (depth uniform in inverse depth over [dmin, dmax], normal uniform on the hemisphere
    facing the camera) for every pixel, or for those with depth 0 when ``only_invalid`` (a negative depth marks a
    pixel outside the mask: left alone)."""
    H, W = depth.shape
    for y in prange(H):
        for x in range(W):
            if only_invalid and depth[y, x] != 0:
                continue
            s = _seed(seed, 7777, y, x)
            s, u = _rand(s)
            depth[y, x] = 1.0 / (1.0 / dmax + u * (1.0 / dmin - 1.0 / dmax))
            r0 = Kinv[0, 0] * x + Kinv[0, 1] * y + Kinv[0, 2]
            r1 = Kinv[1, 0] * x + Kinv[1, 1] * y + Kinv[1, 2]
            r2 = Kinv[2, 0] * x + Kinv[2, 1] * y + Kinv[2, 2]
            s, n0, n1, n2 = _random_normal(s, r0, r1, r2)
            normal[y, x, 0] = n0
            normal[y, x, 1] = n1
            normal[y, x, 2] = n2


@njit(parallel=True, cache=True)
def upsample_planes(depth_c, normal_c, Kinv_c, Kinv_f, depth_f, normal_f):
    """Fine hypotheses from the coarse level: each fine pixel takes the plane of its nearest coarse pixel
    (so slanted surfaces stay slanted, not staircased)."""
    Hc, Wc = depth_c.shape
    H, W = depth_f.shape
    sy = Hc / H
    sx = Wc / W
    for y in prange(H):
        yc = min(max(int((y + 0.5) * sy), 0), Hc - 1)
        for x in range(W):
            xc = min(max(int((x + 0.5) * sx), 0), Wc - 1)
            dc = depth_c[yc, xc]
            n0, n1, n2 = normal_c[yc, xc, 0], normal_c[yc, xc, 1], normal_c[yc, xc, 2]
            normal_f[y, x, 0] = n0
            normal_f[y, x, 1] = n1
            normal_f[y, x, 2] = n2
            if dc <= 0:
                depth_f[y, x] = 0.0
                continue
            q0 = dc * (Kinv_c[0, 0] * xc + Kinv_c[0, 1] * yc + Kinv_c[0, 2])
            q1 = dc * (Kinv_c[1, 0] * xc + Kinv_c[1, 1] * yc + Kinv_c[1, 2])
            q2 = dc
            r0 = Kinv_f[0, 0] * x + Kinv_f[0, 1] * y + Kinv_f[0, 2]
            r1 = Kinv_f[1, 0] * x + Kinv_f[1, 1] * y + Kinv_f[1, 2]
            r2 = Kinv_f[2, 0] * x + Kinv_f[2, 1] * y + Kinv_f[2, 2]
            den = n0 * r0 + n1 * r1 + n2 * r2
            d = dc
            if den < -1e-6:
                d = (n0 * q0 + n1 * q1 + n2 * q2) / den
                if not (d > 0.5 * dc and d < 2.0 * dc):
                    d = dc
            depth_f[y, x] = d


@njit(parallel=True, cache=True, fastmath=True)
def initial_cost(ref, srcs, A, b, Kinv, GP, Ge, GM, Gg, sdepth, use_geo, lam_geo, delta_geo,
                 sdy, sdx, sspat, sigma_c, min_var, best_k, depth, normal, cost):
    """Cost of each pixel's current hypothesis: the mean of its ``best_k`` lowest source costs (photometric
    plus ``lam_geo`` x the geometric term when ``use_geo``)."""
    H, W = ref.shape
    S = srcs.shape[0]
    ns = sdy.shape[0]
    wrow = _window_row(sdy, sdx)
    inv2sc2 = 1.0 / (2.0 * sigma_c * sigma_c)
    for y in prange(H):
        rv = np.empty(ns, np.float64)
        wk = np.empty(ns, np.float64)
        du = np.empty(ns, np.float64)
        dv = np.empty(ns, np.float64)
        h = np.empty(9, np.float64)
        m = np.empty(3, np.float64)
        cj = np.empty(S, np.float64)
        gq = np.empty((S, 3), np.float64)
        for x in range(W):
            d = depth[y, x]
            r0 = Kinv[0, 0] * x + Kinv[0, 1] * y + Kinv[0, 2]
            r1 = Kinv[1, 0] * x + Kinv[1, 1] * y + Kinv[1, 2]
            r2 = Kinv[2, 0] * x + Kinv[2, 1] * y + Kinv[2, 2]
            n0, n1, n2 = normal[y, x, 0], normal[y, x, 1], normal[y, x, 2]
            if d <= 0 or not _plane_m(d, n0, n1, n2, r0, r1, r2, Kinv, m):
                cost[y, x] = 2.0 + lam_geo * delta_geo
                continue
            sw, mr, vr, rad, grid = _ref_window(ref, x, y, sdy, sdx, sspat, inv2sc2, min_var, rv, wk, du, dv, wrow)
            if use_geo:
                _geo_rays(GP, r0, r1, r2, gq)
            for j in range(S):
                _homography(A, b, j, m, h)
                c = _ncc(srcs[j], x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, h, min_var)
                if use_geo:
                    c += lam_geo * _geo(j, d, gq, Ge, GM, Gg, sdepth, x, y, delta_geo)
                cj[j] = c
            cj.sort()
            k = min(best_k, S)
            acc = 0.0
            for j in range(k):
                acc += cj[j]
            cost[y, x] = acc / k


@njit(cache=True, fastmath=True)
def _current_views(srcs, x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, min_var, A, b, Kinv, r0, r1, r2, m, h, cd, cn,
                   nc, ok, cm, wv, order, use_geo, lam_geo, gq, Ge, GM, Gg, sdepth, delta_geo, tau_good, inv2conf,
                   same_depth, same_cos, counts, row):
    """``pm_pass``'s steps 2-4 when the pixel's current hypothesis (candidate 0) is already good (finer levels):
    the current hypothesis in every source gives the view weights (exp(-c^2 / (2 sigma_conf^2)) where its cost c is
    below ``tau_good``, else the two sources that match it best), then each other candidate in the weighted sources
    only, heaviest first, until it cannot win any more. Returns (best candidate, its cost, sum of weights), or
    (-1, 0, 0) when the current hypothesis is not a valid plane (the caller then builds the full matrix)."""
    S = srcs.shape[0]
    d = cd[0]
    if not (d > 0 and _plane_m(d, cn[0, 0], cn[0, 1], cn[0, 2], r0, r1, r2, Kinv, m)):
        return -1, 0.0, 0.0
    ok[0] = True
    for j in range(S):
        _homography(A, b, j, m, h)
        c = _ncc(srcs[j], x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, h, min_var)
        if use_geo:
            c += lam_geo * _geo(j, d, gq, Ge, GM, Gg, sdepth, x, y, delta_geo)
        cm[0, j] = c
    counts[row, COUNT_CANDIDATE] += S
    wsum = 0.0
    for j in range(S):
        c = cm[0, j]
        wv[j] = math.exp(-c * c * inv2conf) if c < tau_good else 0.0
        wsum += wv[j]
    if wsum <= 0.0:
        for _ in range(min(2, S)):
            jb = 0
            mn = 1e30
            for j in range(S):
                if wv[j] == 0.0 and cm[0, j] < mn:
                    mn = cm[0, j]
                    jb = j
            wv[jb] = 1.0
            wsum += 1.0
    nw = 0  # the weighted sources, heaviest first
    for j in range(S):
        if wv[j] > 0:
            q = nw
            while q > 0 and wv[order[q - 1]] < wv[j]:
                order[q] = order[q - 1]
                q -= 1
            order[q] = j
            nw += 1
    bc = 0.0
    for q in range(nw):
        bc += wv[order[q]] * cm[0, order[q]]
    bi = 0
    for i in range(1, nc):
        d = cd[i]
        ok[i] = d > 0 and _plane_m(d, cn[i, 0], cn[i, 1], cn[i, 2], r0, r1, r2, Kinv, m)
        if not ok[i]:
            continue
        same = False
        for q in range(i):  # the same plane as an earlier candidate cannot do better
            if (ok[q] and abs(cd[q] - d) <= same_depth * d and cn[q, 0] * cn[i, 0] + cn[q, 1] * cn[i, 1]
                    + cn[q, 2] * cn[i, 2] > same_cos):
                same = True
                break
        if same:
            continue
        acc = 0.0
        for q in range(nw):
            j = order[q]
            _homography(A, b, j, m, h)
            c = _ncc(srcs[j], x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, h, min_var)
            counts[row, COUNT_CANDIDATE] += 1
            if use_geo:
                c += lam_geo * _geo(j, d, gq, Ge, GM, Gg, sdepth, x, y, delta_geo)
            acc += wv[j] * c
            if acc >= bc:  # cannot win any more
                break
        if acc < bc:
            bc = acc
            bi = i
    return bi, bc / wsum, wsum


@njit(parallel=True, cache=True, fastmath=True)
def pm_pass(color, it, ref, srcs, A, b, Kinv, GP, Ge, GM, Gg, sdepth, use_geo, lam_geo, delta_geo,
            sdy, sdx, sspat, sigma_c, min_var, rdy, rdx, rn, dmin, dmax,
            tau_good, tau_bad, n_good, n_bad, sigma_conf, pert, seed, n_refine, same_depth, same_cos, skip_px, skip_n,
            select_current, depth, normal, cost, counts, views, views_read):
    """One red or black half-iteration of ACMH: for every pixel of ``color`` ((x + y) % 2 == color),

    1. candidates: the current hypothesis and, from each of the 8 regions around it (other colour), the
       neighbour hypothesis with the lowest cost, propagated as a plane to this pixel;
    2. multi-hypothesis joint view selection: the (candidates x sources) cost matrix decides each source's
       weight: selected when more than ``n_good`` candidates match it better than ``tau_good`` and fewer than
       ``n_bad`` worse than ``tau_bad``; its weight is the mean of exp(-c^2 / (2 sigma_conf^2)) over its good
       candidates (without any selected source: the two sources that match best);
    3. the candidate with the lowest weighted cost (photometric + ``lam_geo`` x geometric when ``use_geo``)
       becomes the pixel's hypothesis;
    4. refinement: ``n_refine`` hypotheses, with the same view weights: 3 = perturbed depth, normal and both
       (for an upsampled, already converged surface), 6 = those and random depth, normal and both (0 = none).

    Candidates within ``same_depth`` (relative) and whose normals' cosine exceeds ``same_cos`` of an earlier
    candidate share its costs (neighbours of a converged surface propagate nearly the same plane). With the
    geometric term and ``skip_n`` > 0, a pixel whose hypothesis at least ``skip_n`` sources' depth maps confirm
    (forward-backward reprojection error below ``skip_px``) is left as it is (converged), and so are pixels of
    negative depth (outside the view's mask: never computed, never a candidate).

    ``counts`` (H, N_COUNTS) int64 gets, per row, what the pass did (``COUNT_*``: pixels computed, pixels left as
    converged, NCC evaluations of the candidates and of the refinement): the work it did, free of the clock.

    ``views`` (H, W) int32, or (1, 1) for none: each computed pixel's view selection as bits (bit j: source j got a
    weight). With ``views_read``, a pixel matches only the sources that its own earlier selection or that of a
    neighbour it takes a candidate from used (all of them when none says): sources no view selection around it
    used cost no evaluations; the others' costs are as without it.
    """
    H, W = ref.shape
    S = srcs.shape[0]
    ns = sdy.shape[0]
    wrow = _window_row(sdy, sdx)
    NR = rdy.shape[0]
    NC = 1 + NR
    inv2sc2 = 1.0 / (2.0 * sigma_c * sigma_c)
    use_views = views.shape[0] == H and views.shape[1] == W and S <= MAX_CARRIED_SOURCES
    carry = use_views and views_read
    all_views = (1 << S) - 1
    inv2conf = 1.0 / (2.0 * sigma_conf * sigma_conf)
    for y in prange(H):
        rv = np.empty(ns, np.float64)
        wk = np.empty(ns, np.float64)
        du = np.empty(ns, np.float64)
        dv = np.empty(ns, np.float64)
        h = np.empty(9, np.float64)
        m = np.empty(3, np.float64)
        cd = np.empty(NC, np.float64)
        cn = np.empty((NC, 3), np.float64)
        ok = np.empty(NC, np.bool_)
        cm = np.empty((NC, S), np.float64)
        wv = np.empty(S, np.float64)
        bestj = np.empty(S, np.float64)
        gq = np.empty((S, 3), np.float64)
        order = np.empty(S, np.int64)
        for x in range((y + color) % 2, W, 2):
            if depth[y, x] < 0:  # outside the mask
                continue
            counts[y, COUNT_PIXELS] += 1
            r0 = Kinv[0, 0] * x + Kinv[0, 1] * y + Kinv[0, 2]
            r1 = Kinv[1, 0] * x + Kinv[1, 1] * y + Kinv[1, 2]
            r2 = Kinv[2, 0] * x + Kinv[2, 1] * y + Kinv[2, 2]
            if use_geo:
                _geo_rays(GP, r0, r1, r2, gq)
                if skip_n > 0 and depth[y, x] > 0:
                    n_ok = 0
                    for j in range(S):
                        if _geo(j, depth[y, x], gq, Ge, GM, Gg, sdepth, x, y, delta_geo) < skip_px:
                            n_ok += 1
                    if n_ok >= skip_n:  # converged: the other views' depth maps confirm it
                        counts[y, COUNT_SKIPPED] += 1
                        continue
            sw, mr, vr, rad, grid = _ref_window(ref, x, y, sdy, sdx, sspat, inv2sc2, min_var, rv, wk, du, dv, wrow)
            # 1. candidates
            cd[0] = depth[y, x]
            cn[0, 0], cn[0, 1], cn[0, 2] = normal[y, x, 0], normal[y, x, 1], normal[y, x, 2]
            nc = 1
            allowed = views[y, x] if carry else 0
            for reg in range(NR):
                best = 1e30
                by = -1
                bx = -1
                for k in range(rn[reg]):
                    yy = y + rdy[reg, k]
                    xx = x + rdx[reg, k]
                    if yy < 0 or yy >= H or xx < 0 or xx >= W:
                        continue
                    if cost[yy, xx] < best and depth[yy, xx] > 0:
                        best = cost[yy, xx]
                        by = yy
                        bx = xx
                if by < 0:
                    continue
                if carry:
                    allowed |= views[by, bx]
                dq = depth[by, bx]
                n0, n1, n2 = normal[by, bx, 0], normal[by, bx, 1], normal[by, bx, 2]
                q0 = dq * (Kinv[0, 0] * bx + Kinv[0, 1] * by + Kinv[0, 2])
                q1 = dq * (Kinv[1, 0] * bx + Kinv[1, 1] * by + Kinv[1, 2])
                q2 = dq
                den = n0 * r0 + n1 * r1 + n2 * r2
                d = dq
                if den < -1e-6:
                    d = (n0 * q0 + n1 * q1 + n2 * q2) / den
                    if not (d >= dmin * 0.5 and d <= dmax * 2.0):
                        d = dq
                cd[nc] = d
                cn[nc, 0], cn[nc, 1], cn[nc, 2] = n0, n1, n2
                nc += 1
            allowed &= all_views  # bits of sources this round does not match (fewer sources) say nothing
            if allowed == 0:
                allowed = all_views
            bi = -1
            bc = 1e30
            wsum = 0.0
            if select_current:  # view weights from the current hypothesis, candidates with early termination
                bi, bc, wsum = _current_views(srcs, x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, min_var, A, b, Kinv,
                                              r0, r1, r2, m, h, cd, cn, nc, ok, cm, wv, order, use_geo, lam_geo, gq,
                                              Ge, GM, Gg, sdepth, delta_geo, tau_good, inv2conf, same_depth, same_cos,
                                              counts, y)
            if bi < 0:
                # 2. cost matrix
                for i in range(nc):
                    d = cd[i]
                    ok[i] = d > 0 and _plane_m(d, cn[i, 0], cn[i, 1], cn[i, 2], r0, r1, r2, Kinv, m)
                    same = -1
                    for q in range(i):  # converged neighbours often propagate the very same plane
                        if (abs(cd[q] - d) <= same_depth * d and cn[q, 0] * cn[i, 0] + cn[q, 1] * cn[i, 1]
                                + cn[q, 2] * cn[i, 2] > same_cos):
                            same = q
                            break
                    if same >= 0:
                        for j in range(S):
                            cm[i, j] = cm[same, j]
                        continue
                    for j in range(S):
                        if not ok[i] or not (allowed >> j) & 1:
                            cm[i, j] = 2.0 + lam_geo * delta_geo
                            continue
                        _homography(A, b, j, m, h)
                        c = _ncc(srcs[j], x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, h, min_var)
                        counts[y, COUNT_CANDIDATE] += 1
                        if use_geo:
                            c += lam_geo * _geo(j, d, gq, Ge, GM, Gg, sdepth, x, y, delta_geo)
                        cm[i, j] = c
                # 3. view weights
                wsum = 0.0
                for j in range(S):
                    ng = 0
                    nb = 0
                    acc = 0.0
                    mn = 1e30
                    for i in range(nc):
                        c = cm[i, j]
                        if c < mn:
                            mn = c
                        if c < tau_good:
                            ng += 1
                            acc += math.exp(-c * c * inv2conf)
                        elif c > tau_bad:
                            nb += 1
                    bestj[j] = mn
                    if ng > n_good and nb < n_bad:
                        wv[j] = acc / ng
                    else:
                        wv[j] = 0.0
                    wsum += wv[j]
                if wsum <= 0.0:
                    # fall back to the two sources that match some candidate best
                    for _ in range(min(2, S)):
                        jb = 0
                        mn = 1e30
                        for j in range(S):
                            if wv[j] == 0.0 and bestj[j] < mn:
                                mn = bestj[j]
                                jb = j
                        wv[jb] = 1.0
                        wsum += 1.0
                # 4. best candidate by weighted cost
                bi = 0
                bc = 1e30
                for i in range(nc):
                    acc = 0.0
                    for j in range(S):
                        if wv[j] > 0:
                            acc += wv[j] * cm[i, j]
                    acc /= wsum
                    if acc < bc:
                        bc = acc
                        bi = i
            if use_views:
                used = 0
                for j in range(S):
                    if wv[j] > 0:
                        used |= 1 << j
                views[y, x] = used
            d0 = cd[bi]
            n0, n1, n2 = cn[bi, 0], cn[bi, 1], cn[bi, 2]
            if not ok[bi]:
                continue
            # 5. refinement
            if n_refine > 0:
                s = _seed(seed, it * 2 + color, y, x)
                s, u = _rand(s)
                dr = 1.0 / (1.0 / dmax + u * (1.0 / dmin - 1.0 / dmax))
                s, nr0, nr1, nr2 = _random_normal(s, r0, r1, r2)
                s, u = _rand(s)
                dp = d0 * (1.0 + pert * (2.0 * u - 1.0))
                s, u1 = _rand(s)
                s, u2 = _rand(s)
                s, u3 = _rand(s)
                np0, np1, np2 = _facing(n0 + pert * 4.0 * (2.0 * u1 - 1.0), n1 + pert * 4.0 * (2.0 * u2 - 1.0),
                                        n2 + pert * 4.0 * (2.0 * u3 - 1.0), r0, r1, r2)
                for q in range(min(n_refine, N_REFINE)):
                    if q == 0:
                        d, a0, a1, a2 = dp, n0, n1, n2
                    elif q == 1:
                        d, a0, a1, a2 = d0, np0, np1, np2
                    elif q == 2:
                        d, a0, a1, a2 = dp, np0, np1, np2
                    elif q == 3:
                        d, a0, a1, a2 = dr, n0, n1, n2
                    elif q == 4:
                        d, a0, a1, a2 = d0, nr0, nr1, nr2
                    else:
                        d, a0, a1, a2 = dr, nr0, nr1, nr2
                    if not (d >= dmin and d <= dmax):
                        continue
                    if not _plane_m(d, a0, a1, a2, r0, r1, r2, Kinv, m):
                        continue
                    acc = 0.0
                    for j in range(S):
                        if wv[j] <= 0:
                            continue
                        _homography(A, b, j, m, h)
                        c = _ncc(srcs[j], x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, h, min_var)
                        counts[y, COUNT_REFINE] += 1
                        if use_geo:
                            c += lam_geo * _geo(j, d, gq, Ge, GM, Gg, sdepth, x, y, delta_geo)
                        acc += wv[j] * c
                        if acc >= bc * wsum:  # cannot win any more
                            break
                    acc /= wsum
                    if acc < bc:
                        bc = acc
                        d0, n0, n1, n2 = d, a0, a1, a2
            depth[y, x] = d0
            normal[y, x, 0] = n0
            normal[y, x, 1] = n1
            normal[y, x, 2] = n2
            cost[y, x] = bc


# --- for the tests ----------------------------------------------------------------------------------------------
@njit(cache=True)
def ncc_at(ref, src, x, y, h, sdy, sdx, sspat, sigma_c, min_var):
    """The kernel's cost of one reference pixel through the homography ``h`` (for tests against the slow
    reference ``solver.ncc_cost_reference``)."""
    ns = sdy.shape[0]
    wrow = _window_row(sdy, sdx)
    rv = np.empty(ns, np.float64)
    wk = np.empty(ns, np.float64)
    du = np.empty(ns, np.float64)
    dv = np.empty(ns, np.float64)
    sw, mr, vr, rad, grid = _ref_window(ref, x, y, sdy, sdx, sspat, 1.0 / (2.0 * sigma_c * sigma_c), min_var, rv, wk, du, dv, wrow)
    return _ncc(src, x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, h, min_var)
