#!/usr/bin/env python
"""What one NCC evaluation costs on this CPU, one thread: PatchMatch's ``_ncc`` (a window through a plane's
homography, bilinear samples, bilateral weights) beside the floor of its arithmetic, the same bilinear samples
and weighted sums over precomputed coordinates in a loop the compiler vectorises (no per-window set-up, no
branches).

    python tools/bench_ncc.py [--size 1280x1024] [--evals 2000000]

The evaluations walk the reference pixels in raster order, as a pass does, each through a homography close to
the identity (a plane slightly off the true one), so the source's cache lines are reused as in a real pass.
Prints ns per evaluation and per sample, for the 6x6 grid (36 samples) and its checkerboard (18 samples).
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from numba import njit

from photorecon.depth.methods.patchmatch import kernels as k


@njit(cache=True, fastmath=True)
def _evals(ref, src, sdy, sdx, sspat, inv2sc2, min_var, n, hs):
    """``n`` evaluations of ``_ncc`` at pixels in raster order (margin 8), homography ``hs[i % len(hs)]``."""
    H, W = ref.shape
    ns = sdy.shape[0]
    wrow = k._window_row(sdy, sdx)
    rv = np.empty(ns, np.float64)
    wk = np.empty(ns, np.float64)
    du = np.empty(ns, np.float64)
    dv = np.empty(ns, np.float64)
    acc = 0.0
    x, y = 8, 8
    sw, mr, vr, rad, grid = k._ref_window(ref, x, y, sdy, sdx, sspat, inv2sc2, min_var, rv, wk, du, dv, wrow)
    for i in range(n):
        if i % 8 == 0:  # a pixel's candidates share its reference window (8 sources x candidates)
            x += 1
            if x >= W - 8:
                x = 8
                y += 1
                if y >= H - 8:
                    y = 8
            sw, mr, vr, rad, grid = k._ref_window(ref, x, y, sdy, sdx, sspat, inv2sc2, min_var, rv, wk, du, dv, wrow)
        acc += k._ncc(src, x, y, du, dv, rv, wk, sw, mr, vr, rad, grid, hs[i % hs.shape[0]], min_var)
    return acc


@njit(cache=True, fastmath=True)
def _floor(src, sx, sy, w, r, out):
    """Bilinear samples at (sx, sy) and the three weighted sums of each window of ``w.shape[0]`` samples: the
    arithmetic of ``_ncc`` alone, in float32, over contiguous arrays (vectorisable)."""
    n = w.shape[0]
    for e in range(out.shape[0]):
        s1 = np.float32(0.0)
        s2 = np.float32(0.0)
        s12 = np.float32(0.0)
        b = e * n
        for q in range(n):
            x = sx[b + q]
            y = sy[b + q]
            ix = np.int64(x)
            iy = np.int64(y)
            fx = x - np.float32(ix)
            fy = y - np.float32(iy)
            a0 = src[iy, ix]
            a1 = src[iy, ix + 1]
            a2 = src[iy + 1, ix]
            a3 = src[iy + 1, ix + 1]
            v = a0 + fx * (a1 - a0) + fy * (a2 - a0 + fx * (a0 - a1 - a2 + a3))
            wv = w[q] * v
            s1 += wv
            s2 += wv * v
            s12 += wv * r[q]
        out[e] = s1 + s2 + s12


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1280x1024")
    ap.add_argument("--evals", type=int, default=2_000_000)
    args = ap.parse_args()
    W, H = (int(s) for s in args.size.split("x"))
    rng = np.random.default_rng(0)
    ref = rng.random((H, W), dtype=np.float32)
    src = np.ascontiguousarray(ref + 0.05 * rng.random((H, W), dtype=np.float32))
    hs = np.zeros((64, 9))
    for i in range(64):
        a = 0.02 * rng.standard_normal(6)
        hs[i] = [1 + a[0], a[1], 3 * a[2], a[3], 1 + a[4], 3 * a[5], 0, 0, 1]
    n = args.evals
    for checker, label in ((False, "grid 6x6 (36 samples)"), (True, "checkerboard (18 samples)")):
        sdy, sdx, sspat = k.window_samples(5, 2, 3.0, checker=checker)
        ns = len(sdy)
        _evals(ref, src, sdy, sdx, sspat, 50.0, 1e-5, 1000, hs)
        t0 = time.process_time()
        _evals(ref, src, sdy, sdx, sspat, 50.0, 1e-5, n, hs)
        t = time.process_time() - t0
        # the floor: the same number of samples, coordinates precomputed (a window's affine walk, as _ncc's)
        m = min(n, 400_000)
        cx = rng.uniform(8, W - 9, m).astype(np.float32)
        cy = rng.uniform(8, H - 9, m).astype(np.float32)
        cx.sort()  # raster-like locality
        sx = (cx[:, None] + sdx[None, :].astype(np.float32) * 1.01).ravel()
        sy = (cy[:, None] + sdy[None, :].astype(np.float32) * 0.99).ravel()
        out = np.empty(m, np.float32)
        _floor(src, sx, sy, sspat.astype(np.float32), sspat.astype(np.float32), out)
        t1 = time.process_time()
        for _ in range(3):
            _floor(src, sx, sy, sspat.astype(np.float32), sspat.astype(np.float32), out)
        tf = (time.process_time() - t1) / 3
        print(f"{label}: _ncc {t / n * 1e9:.1f} ns per evaluation ({t / n / ns * 1e9:.2f} ns per sample); "
              f"arithmetic floor {tf / m * 1e9:.1f} ns per evaluation ({tf / m / ns * 1e9:.2f} ns per sample)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
