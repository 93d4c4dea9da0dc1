"""Which views get a depth map: the views that cover the surface, in the spirit of CMVS's view clustering
(Furukawa et al., "Towards Internet-scale multi-view stereo", CVPR 2010): a redundant capture (hundreds of
photos of one object) needs depth maps only from enough views to see every part of the surface well, so the
depth stage grows with the surface, not with the photo count.

The sparse points, with the views that observe them, are the surface sample. A view sees a point *well* when
it looks at it within ``MAX_VIEW_ANGLE_DEG`` of the point's mean viewing direction (a stand-in for its normal)
and at a resolution (pixel footprint at the working resolution) within ``RESOLUTION_RATIO`` of the finest
view of that point. Greedy set cover then picks, one at a time, the view that covers the most still-needed
points (each weighted by its resolution relative to the finest), until every point is seen well by
``depth_view_coverage`` chosen views (or by all the views that see it well, when fewer). A view counts for a
point only when its ray to the point is at least ``min_angle_deg`` away from the rays of the views already
counted: a second photo from nearly the same place adds no triangulation angle and no new surface.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger("photorecon")

MAX_VIEW_ANGLE_DEG = 60.0  # a view sees a point well within this angle of the point's mean viewing direction
RESOLUTION_RATIO = 2.0  # ... and with a pixel footprint at most this many times the finest view's


@dataclass
class ViewChoice:
    """The views chosen for depth maps (in the model's order), of ``total``, and why."""

    chosen: list[str]
    total: int
    reason: str  # "all requested", "no sparse points", "no point seen well by two views", "coverage"
    uncovered_points: int = 0  # points seen well by fewer chosen views than needed (0 when the cover is complete)

    def to_dict(self) -> dict:
        return {"chosen": len(self.chosen), "of": self.total, "reason": self.reason,
                "uncovered_points": self.uncovered_points}


def _observations(model, views, max_size: int):
    """Per observation of a sparse point by a view: (view index, point row, unit direction point -> camera,
    pixel footprint at the working resolution)."""
    index = model.point_index()
    vi, pi, dirs, foot = [], [], [], []
    for k, v in enumerate(views):
        obs = model.observations.get(v.name)
        if obs is None:
            continue
        rows = np.array([index[int(i)] for i in obs[1] if i >= 0 and int(i) in index], np.int64)
        if not len(rows):
            continue
        P = model.points[rows]
        T = v.cam_from_world
        z = P @ T[2, :3] + T[2, 3]
        ok = z > 0
        rows, P, z = rows[ok], P[ok], z[ok]
        d = v.center - P
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
        W, H = v.intrinsics.size
        s = min(1.0, max_size / max(W, H)) if max_size > 0 else 1.0
        f = 0.5 * (v.intrinsics.fx + v.intrinsics.fy) * s
        vi.append(np.full(len(rows), k, np.int64))
        pi.append(rows)
        dirs.append(d)
        foot.append(z / f)
    if not vi:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)
    return np.concatenate(vi), np.concatenate(pi), np.concatenate(dirs), np.concatenate(foot)


def choose_depth_views(model, cfg) -> ViewChoice:
    """The views to compute depth maps for (``cfg.depth_views``: ``"all"``, or ``"auto"``: the greedy
    coverage described in this module, ``cfg.depth_view_coverage`` views per sparse point). Views that see no
    sparse point are left to the depth stage's own checks (kept). Deterministic for a model."""
    views = list(model.views)
    names = [v.name for v in views]
    if cfg.depth_views == "all":
        return ViewChoice(names, len(names), "all requested")
    if not len(model.points) or not model.observations:
        return ViewChoice(names, len(names), "no sparse points")
    vi, pi, u, foot = _observations(model, views, cfg.max_size)
    n_pts, n_views, need_k = len(model.points), len(views), max(1, int(cfg.depth_view_coverage))
    observed = np.zeros(n_views, bool)
    observed[vi] = True
    # the point's mean viewing direction (its normal's stand-in), then the views that see it well
    mean = np.zeros((n_pts, 3))
    np.add.at(mean, pi, u)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-30)
    good = np.einsum("ij,ij->i", u, mean[pi]) >= np.cos(np.radians(MAX_VIEW_ANGLE_DEG))
    finest = np.full(n_pts, np.inf)
    np.minimum.at(finest, pi[good], foot[good])
    good &= foot <= RESOLUTION_RATIO * finest[pi]
    vi, pi, u, w = vi[good], pi[good], u[good], (finest[pi] / foot)[good]
    n_good = np.bincount(pi, minlength=n_pts)
    need = np.where(n_good >= 2, np.minimum(need_k, n_good), 0)  # a point one view sees cannot be matched
    cos_sep = np.cos(np.radians(max(cfg.min_angle_deg, 0.0)))
    counted = np.zeros((n_pts, need_k, 3))  # the rays of the chosen views counted for each point
    n_counted = np.zeros(n_pts, np.int64)
    chosen: list[int] = []
    taken = np.zeros(n_views, bool)
    while True:
        fills = (n_counted[pi] < need[pi]) & ~taken[vi]
        # a view counts for a point only when its ray is at least min_angle_deg from every ray counted there
        e = np.flatnonzero(fills)
        dots = np.einsum("ij,ikj->ik", u[e], counted[pi[e]])
        fills[e] = ~np.any((dots > cos_sep) & (np.arange(need_k)[None] < n_counted[pi[e]][:, None]), axis=1)
        gain = np.bincount(vi[fills], weights=w[fills], minlength=n_views)
        best = int(np.argmax(gain))
        if gain[best] <= 0:
            break
        sel = fills & (vi == best)
        p = pi[sel]
        counted[p, n_counted[p]] = u[sel]
        n_counted[p] += 1
        taken[best] = True
        chosen.append(best)
    if taken.sum() < 2:  # no point that two views see well: nothing to cover, the depth stage judges every view
        return ViewChoice(names, n_views, "no point seen well by two views")
    # views that observe no sparse point are not the cover's to drop (the depth stage skips them, saying why)
    keep = taken | ~observed
    uncovered = int(np.count_nonzero(n_counted < need))
    return ViewChoice([names[k] for k in range(n_views) if keep[k]], n_views, "coverage", uncovered)
