"""Fitting relative depth to SfM points: robust scale and shift in inverse-depth (disparity) space.

``fit_scale_shift(pred, target)`` fits ``target ~ s * pred + t`` by RANSAC on 2-point samples followed by a
least-squares refit on the inliers (and an IRLS polish with Huber weights). For a disparity-predicting model
``target = 1 / z_sfm``; for a relative-depth model ``target = z_sfm``; for a metric model only the scale is
fitted (``shift=False``).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..errors import BadArgumentError


@dataclass
class Fit:
    scale: float
    shift: float
    n_points: int
    n_inliers: int
    inlier_ratio: float
    median_rel_residual: float  # median |fit - target| / |target| on all points
    ok: bool
    reason: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


def fit_scale_shift(pred, target, shift: bool = True, rel_threshold: float = 0.05, iterations: int = 300,
                    min_points: int = 10, min_inlier_ratio: float = 0.5, max_median_residual: float = 0.05,
                    seed: int = 0) -> Fit:
    """Robust fit of ``target ~ scale * pred + shift`` (or ``scale * pred`` without shift).

    A point is an inlier when its residual is below ``rel_threshold`` of its target. The fit is marked not
    ``ok`` (with a reason) when there are fewer than ``min_points`` points, fewer than ``min_inlier_ratio``
    inliers, or a median relative residual above ``max_median_residual``.
    """
    x = np.asarray(pred, np.float64).ravel()
    y = np.asarray(target, np.float64).ravel()
    if x.shape != y.shape:
        raise BadArgumentError(f"alignment: prediction and target sizes differ ({x.size} vs {y.size})")
    good = np.isfinite(x) & np.isfinite(y) & (y != 0)
    x, y = x[good], y[good]
    n = len(x)
    if n < min_points:
        return Fit(float("nan"), float("nan"), n, 0, 0.0, float("nan"), False, f"{n} points (< {min_points})")
    rng = np.random.default_rng(seed)
    need = 2 if shift else 1
    best_inl, best = None, (1.0, 0.0)
    for _ in range(iterations):
        idx = rng.choice(n, need, replace=False)
        if shift:
            dx = x[idx[1]] - x[idx[0]]
            if abs(dx) < 1e-12:
                continue
            s = (y[idx[1]] - y[idx[0]]) / dx
            t = y[idx[0]] - s * x[idx[0]]
        else:
            if abs(x[idx[0]]) < 1e-12:
                continue
            s, t = y[idx[0]] / x[idx[0]], 0.0
        inl = np.abs(s * x + t - y) < rel_threshold * np.abs(y)
        if best_inl is None or inl.sum() > best_inl.sum():
            best_inl, best = inl, (s, t)
    if best_inl is None or best_inl.sum() < need:
        return Fit(float("nan"), float("nan"), n, 0, 0.0, float("nan"), False, "no consistent fit")
    s, t = best
    inl = best_inl
    for _ in range(10):  # least squares on the inliers, then Huber-weighted polish
        r = s * x + t - y
        scale_r = rel_threshold * np.abs(y)
        w = np.where(np.abs(r) <= scale_r, 1.0, scale_r / np.maximum(np.abs(r), 1e-30)) * inl
        # residuals relative to the target: weight by 1/|y|
        w = w / np.maximum(np.abs(y), 1e-30) ** 2
        if shift:
            A = np.stack([x, np.ones_like(x)], 1) * np.sqrt(w)[:, None]
            sol, *_ = np.linalg.lstsq(A, y * np.sqrt(w), rcond=None)
            s, t = float(sol[0]), float(sol[1])
        else:
            s, t = float((w * x * y).sum() / max((w * x * x).sum(), 1e-30)), 0.0
        inl = np.abs(s * x + t - y) < rel_threshold * np.abs(y)
    rel = np.abs(s * x + t - y) / np.abs(y)
    ratio = float(inl.mean())
    med = float(np.median(rel))
    ok, reason = True, ""
    if ratio < min_inlier_ratio:
        ok, reason = False, f"only {100 * ratio:.0f}% of {n} points agree with the fit"
    elif med > max_median_residual:
        ok, reason = False, f"median residual {100 * med:.1f}% (> {100 * max_median_residual:.0f}%)"
    return Fit(float(s), float(t), n, int(inl.sum()), ratio, med, ok, reason)
