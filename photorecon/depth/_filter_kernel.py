"""The multi-view geometric filter's compiled kernel (numba): one reference depth map checked against one source's
(``filter._consistency_count_pinhole``). Self-contained: it calls no other compiled function (numba's cache
checks only this file)."""
from __future__ import annotations

import math

import numpy as np

from ..jit import njit, prange


@njit(parallel=True, cache=True)
def consistency_source(depth, Kr, Krinv, R, t, Ks, Ksinv, sdepth, reproj_px, rel_depth, cnt, err_rows, n_rows,
                       normal, snormal, plane_px, cos_max):
    """The multi-view filter's test of every depth of the reference map ``depth`` against one source's depth map
    ``sdepth`` (pinhole cameras; ``R, t``: source from reference): the point goes into the source, takes the
    source's depth at the nearest pixel and comes back; ``cnt`` += 1 where the reprojection error is below
    ``reproj_px`` pixels and the relative depth difference below ``rel_depth``; ``err_rows`` / ``n_rows`` get
    each row's sum and number of the agreeing errors (summed by the caller: deterministic).

    Plane test (``plane_px`` > 0; ``normal`` (H, W, 3) and ``snormal`` (hs, ws, 3): each view's normals in its
    camera frame): a pair that fails the point test also agrees when the reprojection error is below
    ``plane_px``, each point lies within ``reproj_px`` pixel footprints (depth / Kr[0, 0]) of the other's tangent
    plane and the normals' cosine is above ``cos_max`` (``filter.consistency_count``)."""
    H, W = depth.shape
    hs, ws = sdepth.shape
    plane = plane_px > 0 and normal.shape[0] == H and normal.shape[1] == W and snormal.shape[0] == hs and snormal.shape[1] == ws
    for y in prange(H):
        es = 0.0
        en = 0
        for x in range(W):
            d = depth[y, x]
            if not d > 0:
                continue
            X0 = d * (Krinv[0, 0] * x + Krinv[0, 1] * y + Krinv[0, 2])
            X1 = d * (Krinv[1, 0] * x + Krinv[1, 1] * y + Krinv[1, 2])
            X2 = d * (Krinv[2, 0] * x + Krinv[2, 1] * y + Krinv[2, 2])
            S0 = R[0, 0] * X0 + R[0, 1] * X1 + R[0, 2] * X2 + t[0]
            S1 = R[1, 0] * X0 + R[1, 1] * X1 + R[1, 2] * X2 + t[1]
            S2 = R[2, 0] * X0 + R[2, 1] * X1 + R[2, 2] * X2 + t[2]
            if not S2 > 0:
                continue
            u = (Ks[0, 0] * S0 + Ks[0, 1] * S1 + Ks[0, 2] * S2) / S2
            v = (Ks[1, 0] * S0 + Ks[1, 1] * S1 + Ks[1, 2] * S2) / S2
            if not (u > -0.5 and v > -0.5 and u < ws - 0.5 and v < hs - 0.5):
                continue
            i = int(math.floor(u + 0.5))
            j = int(math.floor(v + 0.5))
            ds = sdepth[j, i]
            if not ds > 0:
                continue
            P0 = ds * (Ksinv[0, 0] * i + Ksinv[0, 1] * j + Ksinv[0, 2]) - t[0]
            P1 = ds * (Ksinv[1, 0] * i + Ksinv[1, 1] * j + Ksinv[1, 2]) - t[1]
            P2 = ds * (Ksinv[2, 0] * i + Ksinv[2, 1] * j + Ksinv[2, 2]) - t[2]
            B0 = R[0, 0] * P0 + R[1, 0] * P1 + R[2, 0] * P2  # R^T (P - t): back in the reference frame
            B1 = R[0, 1] * P0 + R[1, 1] * P1 + R[2, 1] * P2
            B2 = R[0, 2] * P0 + R[1, 2] * P1 + R[2, 2] * P2
            if not B2 > 0:
                continue
            ur = (Kr[0, 0] * B0 + Kr[0, 1] * B1 + Kr[0, 2] * B2) / B2
            vr = (Kr[1, 0] * B0 + Kr[1, 1] * B1 + Kr[1, 2] * B2) / B2
            e = math.sqrt((ur - x) ** 2 + (vr - y) ** 2)
            if e < reproj_px and abs(B2 - d) / d < rel_depth:
                cnt[y, x] += 1
                es += e
                en += 1
            elif plane and e < plane_px:
                n0 = np.float64(normal[y, x, 0])
                n1 = np.float64(normal[y, x, 1])
                n2 = np.float64(normal[y, x, 2])
                m0 = np.float64(snormal[j, i, 0])  # the source's normal, into the reference frame: R^T m
                m1 = np.float64(snormal[j, i, 1])
                m2 = np.float64(snormal[j, i, 2])
                s0 = R[0, 0] * m0 + R[1, 0] * m1 + R[2, 0] * m2
                s1 = R[0, 1] * m0 + R[1, 1] * m1 + R[2, 1] * m2
                s2 = R[0, 2] * m0 + R[1, 2] * m1 + R[2, 2] * m2
                D0, D1, D2 = B0 - X0, B1 - X1, B2 - X2
                tol = reproj_px * d / Kr[0, 0]
                if (abs(D0 * n0 + D1 * n1 + D2 * n2) < tol and abs(D0 * s0 + D1 * s1 + D2 * s2) < tol
                        and n0 * s0 + n1 * s1 + n2 * s2 > cos_max):
                    cnt[y, x] += 1
        err_rows[y] += es
        n_rows[y] += en
