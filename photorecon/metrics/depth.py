"""Depth maps against the truth: per-pixel errors, the pixels two views both see, and the depth and disparity
errors of a pair of views."""
from __future__ import annotations

import numpy as np

from ..errors import BadArgumentError


def depth_metrics(pred: np.ndarray, gt: np.ndarray, rel_threshold: float = 0.01) -> dict:
    """Depth errors on pixels valid in both: AbsRel, RMSE, fraction within ``rel_threshold`` of the truth,
    and coverage (fraction of true surface pixels with a prediction)."""
    pred, gt = np.asarray(pred, np.float64), np.asarray(gt, np.float64)
    if pred.shape != gt.shape:
        raise BadArgumentError(f"depth metrics: shapes differ, {pred.shape} vs {gt.shape}")
    both = (pred > 0) & (gt > 0) & np.isfinite(pred)
    if not both.any():
        return {"abs_rel": float("nan"), "rmse": float("nan"), "within": 0.0, "coverage": 0.0, "pixels": 0}
    rel = np.abs(pred[both] - gt[both]) / gt[both]
    return {"abs_rel": float(rel.mean()), "rmse": float(np.sqrt(((pred[both] - gt[both]) ** 2).mean())),
            "within": float((rel < rel_threshold).mean()), "coverage": float(both.sum() / max((gt > 0).sum(), 1)),
            "pixels": int(both.sum())}

# --- two views: co-visible pixels, disparity errors of a rectified pair ------------------------------------
def covisible(depth_a: np.ndarray, view_a, depth_b: np.ndarray, view_b, rel_tol: float = 0.01) -> np.ndarray:
    """(H, W) bool: the pixels of view a whose true surface point (``depth_a``, z-depth, 0 = none) view b also
    sees: it projects inside b, in front of it, within ``rel_tol`` of b's true depth at the nearest pixel (not
    hidden behind another surface there)."""
    from ..cameras import backproject_depth, project

    valid = depth_a > 0
    out = np.zeros(depth_a.shape, bool)
    if not valid.any():
        return out
    pts = backproject_depth(np.where(valid, depth_a, 0), view_a.intrinsics, view_a.cam_from_world)
    uv, z = project(pts, view_b.intrinsics, view_b.cam_from_world)
    W, H = view_b.intrinsics.size
    with np.errstate(invalid="ignore"):
        ij = np.round(np.nan_to_num(uv, nan=-1.0)).astype(np.int64)
        ok = (z > 0) & (ij[:, 0] >= 0) & (ij[:, 0] < W) & (ij[:, 1] >= 0) & (ij[:, 1] < H)
    zb = np.zeros(len(z))
    zb[ok] = depth_b[ij[ok, 1], ij[ok, 0]]
    ok &= (zb > 0) & (np.abs(zb - z) < rel_tol * np.maximum(z, 1e-12))
    out[valid] = ok
    return out

def two_view_depth_scores(depth: np.ndarray, gt: np.ndarray, covis: np.ndarray, rel: float = 0.01) -> dict:
    """A view's depth against the truth on its co-visible pixels ``covis``: ``within`` = the fraction of them
    with a depth within ``rel`` of the truth (a missing depth counts as wrong), ``coverage`` = the fraction with
    a depth, ``accuracy`` = within / coverage (how often a given depth is right)."""
    n = int(covis.sum())
    has = covis & (depth > 0) & np.isfinite(depth)
    good = has & (np.abs(depth - gt) < rel * np.maximum(gt, 1e-12))
    cov = has.sum() / max(n, 1)
    return {"pixels": n, "within": float(good.sum() / max(n, 1)), "coverage": float(cov),
            "accuracy": float(good.sum() / max(has.sum(), 1))}

def disparity_scores(disp: np.ndarray, gt_disp: np.ndarray, covis: np.ndarray, px: float = 2.0) -> dict:
    """Disparity (pixels; NaN or <= 0 = no answer) against the truth on ``covis`` pixels, as stereo benchmarks
    count it: ``within`` = the fraction of them within ``px`` pixels (no answer = wrong), ``completeness`` = the
    fraction answered, ``bad`` = the fraction of the answered ones off by more than ``px``."""
    n = int(covis.sum())
    has = covis & np.isfinite(disp) & (disp > 0)
    err = np.abs(np.where(has, disp, 0) - gt_disp)
    good = has & (err <= px)
    return {"pixels": n, "within": float(good.sum() / max(n, 1)), "completeness": float(has.sum() / max(n, 1)),
            "bad": float((has & (err > px)).sum() / max(has.sum(), 1))}
