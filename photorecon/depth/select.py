"""View selection for MVS: the source views of each reference view (shared sparse points weighted by their
triangulation angle, or camera geometry without points), and the depth range to search (from the sparse points
the view sees, or where the cameras' optical axes converge).
"""
from __future__ import annotations

import numpy as np

from ..cameras import View
from .config import MVSConfig


def select_sources(model, ref: View, cfg: MVSConfig) -> list[View]:
    """Rank the other views for ``ref``: shared sparse points weighted by triangulation angle; without
    points, by viewing-direction similarity and distance. When every view sharing points with ``ref`` sees them
    at less than ``min_angle_deg`` (a narrow stereo pair), those views are its sources."""
    c_ref = ref.center
    scores = []
    ref_pts = model.points_seen_by(ref.name) if len(model.points) else np.zeros((0, 3))
    ref_ids = set()
    if ref.name in model.observations:
        ref_ids = {int(i) for i in model.observations[ref.name][1] if i >= 0}
    index = model.point_index() if len(model.points) else {}
    for v in model.views:
        if v.name == ref.name:
            continue
        c = v.center
        if np.linalg.norm(c - c_ref) < 1e-9:
            continue
        if ref_ids and v.name in model.observations:
            shared = [index[int(i)] for i in model.observations[v.name][1] if i >= 0 and int(i) in ref_ids and int(i) in index]
            if not shared:
                continue
            P = model.points[shared]
            a, b = P - c_ref, P - c
            cos = np.einsum("nc,nc->n", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
            ang = np.degrees(np.arccos(np.clip(cos, -1, 1)))
            w = np.where(ang < cfg.min_angle_deg, 0.0, np.exp(-((ang - 15.0) ** 2) / (2 * 10.0 ** 2)))
            scores.append((float(w.sum()), v))
        elif not len(ref_pts):
            d_ref = ref.cam_from_world[2, :3]
            d_v = v.cam_from_world[2, :3]
            ang = np.degrees(np.arccos(np.clip(d_ref @ d_v, -1, 1)))
            if ang < cfg.min_angle_deg or ang > 60:
                continue
            scores.append((float(np.exp(-((ang - 15.0) ** 2) / (2 * 10.0 ** 2))), v))
    scores.sort(key=lambda s: -s[0])
    chosen = [v for s, v in scores[: cfg.n_sources] if s > 0]
    if not chosen and ref_ids:  # only views sharing points at a narrow angle (a short stereo baseline): those
        chosen = [v for _, v in scores[: cfg.n_sources]]
    return chosen


def depth_range(model, view: View, near: float = 0.6, far: float = 1.25) -> tuple[float, float] | None:
    """Depth range of the sparse points seen in ``view``: their 1st percentile x ``near`` to their 99th x ``far``
    (each depth method has its factors, ``DEPTH_RANGE``; the defaults are PatchMatch's); None without points. The near side is widened most: a surface seen at a grazing angle close to the camera
    (the ground in front of a facade) yields few SIFT matches, so the points stop well short of it (Herz-Jesu-P8:
    points from 9.7 m, ground from 6 m)."""
    pts = model.points_seen_by(view.name)
    if len(pts) < 5:
        return None
    z = (pts @ view.cam_from_world[:3, :3].T + view.cam_from_world[:3, 3])[:, 2]
    z = z[z > 0]
    if len(z) < 5:
        return None
    lo, hi = np.percentile(z, 1) * near, np.percentile(z, 99) * far
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo * 1.001:
        return None
    return float(lo), float(hi)


def camera_depth_range(views: list[View], view: View) -> tuple[float, float] | None:
    """Without sparse points: the point nearest to every optical axis is taken as the scene centre, and the
    depth range is [0.4, 1.6] x its depth in ``view`` (cameras looking at a common object)."""
    if len(views) < 2:
        return None
    A, b = np.zeros((3, 3)), np.zeros(3)
    for v in views:
        d = v.cam_from_world[2, :3]
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ v.center
    try:
        c = np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return None
    z = (view.cam_from_world[:3, :3] @ c + view.cam_from_world[:3, 3])[2]
    if not z > 0:
        return None
    return 0.4 * float(z), 1.6 * float(z)
