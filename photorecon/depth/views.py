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
from dataclasses import dataclass, field, replace

import numpy as np

from ..cameras import backproject_pixels, depth_footprint
from ..io.dataset import MIN_DEPTH_SIDE
from ..layout import DEPTH_RESOLUTIONS

log = logging.getLogger("photorecon")

MAX_VIEW_ANGLE_DEG = 60.0  # a view sees a point well within this angle of the point's mean viewing direction
RESOLUTION_RATIO = 2.0  # ... and with a pixel footprint at most this many times the finest view's


@dataclass
class ViewChoice:
    """The views chosen for depth maps (in the model's order), of ``total``, and why."""

    chosen: list[str]
    total: int
    reason: str  # "all requested", "no sparse points", "no point seen well by two views", "coverage", ...
    uncovered_points: int = 0  # points seen well by fewer chosen views than needed (0 when the cover is complete)
    surface_samples: int | None = None  # --depth-views coarse: the coarse surface's samples that two views see well
    # per chosen view: (pyramid level of its depth map: 0 = the working resolution, 1 = half; the share of its
    # coarse surface that full-resolution views see as finely from a similar direction); empty: every view full
    resolution: dict = field(default_factory=dict)
    # the pixel footprint the fused mesh's voxel asks of the depth maps (``mesh_levels``), and the chosen views whose
    # map at a coarser level has it (view -> (that level: 1 half, 2 quarter, its footprint at the working
    # resolution)); None / empty: not planned
    mesh_footprint: float | None = None
    mesh_coarser: dict = field(default_factory=dict)

    def after(self, first: "ViewChoice") -> "ViewChoice":
        """This choice, made among the views ``first`` chose: counted against ``first``'s total, both reasons."""
        return replace(self, total=first.total, reason=f"{first.reason}, then {self.reason}")

    def to_dict(self) -> dict:
        d = {"chosen": len(self.chosen), "of": self.total, "reason": self.reason,
             "uncovered_points": self.uncovered_points}
        if self.resolution or self.mesh_coarser:
            levels = [self.level(n) for n in self.chosen]
            d["half_resolution"] = levels.count(1)
            if levels.count(2):
                d["quarter_resolution"] = levels.count(2)
        if self.mesh_footprint is not None:
            d["mesh_footprint"] = self.mesh_footprint
        return d if self.surface_samples is None else {**d, "surface_samples": self.surface_samples}

    def level(self, name: str) -> int:
        """The pyramid level of view ``name``'s depth map (0: the working resolution, 1: half of it, 2: a quarter)."""
        if name in self.mesh_coarser:
            return self.mesh_coarser[name][0]
        return self.resolution.get(name, (0, 0.0))[0]

    def resolution_reason(self, name: str) -> str | None:
        """Why view ``name``'s depth map has its resolution (for the report), or None when no choice was made."""
        if name in self.mesh_coarser:
            lvl, own = self.mesh_coarser[name]
            size = DEPTH_RESOLUTIONS[lvl]
            return (f"{size}: the fused mesh's voxel keeps detail down to a footprint of {self.mesh_footprint:.3g}, "
                    f"and this view's {size}-resolution map has {2 ** lvl * own:.3g}")
        if name not in self.resolution:
            return None
        lvl, seen = self.resolution[name]
        share = f"{100 * seen:.0f}% of its surface is seen by full-resolution views within {HALF_MAX_ANGLE_DEG:g} " \
                f"degrees and {HALF_FOOTPRINT_RATIO:g}x its pixel footprint"
        return f"half: {share}" if lvl else f"full: only {share}"


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


def _greedy_cover(vi: np.ndarray, pi: np.ndarray, u: np.ndarray, w: np.ndarray, n_pts: int, n_views: int,
                  need_k: int, min_angle_deg: float, enough: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The greedy cover of ``n_pts`` surface samples by views, from the observations (view ``vi``, sample ``pi``,
    unit direction sample -> camera ``u``, weight ``w``) of the views that see them well: one view at a time,
    the one whose observations fill the most still-needed places (weighted), until each sample is seen by
    ``need_k`` chosen views (by all that see it well, when fewer; none for a sample one view sees), a view
    counting for a sample only when its ray is ``min_angle_deg`` from the rays already counted there; with
    ``enough`` < 1, until that fraction of the samples that need views have them all. Returns (views taken
    (bool per view), chosen views counted per sample, views needed per sample)."""
    n_good = np.bincount(pi, minlength=n_pts)
    need = np.where(n_good >= 2, np.minimum(need_k, n_good), 0)  # a point one view sees cannot be matched
    cos_sep = np.cos(np.radians(max(min_angle_deg, 0.0)))
    counted = np.zeros((n_pts, need_k, 3))  # the rays of the chosen views counted for each point
    n_counted = np.zeros(n_pts, np.int64)
    taken = np.zeros(n_views, bool)
    n_need = max(1, int(np.count_nonzero(need)))
    while np.count_nonzero((n_counted >= need) & (need > 0)) < enough * n_need:
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
    return taken, n_counted, need


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
    taken, n_counted, need = _greedy_cover(vi, pi, u, w, n_pts, n_views, need_k, cfg.min_angle_deg)
    if taken.sum() < 2:  # no point that two views see well: nothing to cover, the depth stage judges every view
        return ViewChoice(names, n_views, "no point seen well by two views")
    # views that observe no sparse point are not the cover's to drop (the depth stage skips them, saying why)
    keep = taken | ~observed
    uncovered = int(np.count_nonzero(n_counted < need))
    return ViewChoice([names[k] for k in range(n_views) if keep[k]], n_views, "coverage", uncovered)


# --depth-resolution auto: a chosen view gets its depth map at half the working resolution when at least
# HALF_COVERED of the coarse surface it sees well is seen, by a view at full resolution, from within HALF_MAX_ANGLE_DEG
# of its own ray and at a pixel footprint at most HALF_FOOTPRINT_RATIO times its own: that view resolves the
# surface at least as finely, and the half-resolution map still confirms it (the geometric filter) and fills in
# what the full one misses. The views are judged in order of how much surface they see finest, so the finest view
# of each part stays full; a view that alone sees a part closely stays full; in a ring of 12 cameras (30 degrees
# apart) no view has a neighbour within 20 degrees, and all stay full
HALF_COVERED = 0.9
HALF_MAX_ANGLE_DEG = 20.0
HALF_FOOTPRINT_RATIO = 1.25


def half_resolution_views(vi: np.ndarray, pi: np.ndarray, u: np.ndarray, foot: np.ndarray, w: np.ndarray,
                          candidates: np.ndarray, n_pts: int) -> dict[int, tuple[int, float]]:
    """Per candidate view (index into the views of the observations: view ``vi`` sees sample ``pi`` well along the
    unit direction ``u`` at pixel footprint ``foot``, weight ``w`` = the finest footprint / its own): (level, the
    share of its observations that full-resolution views already see as finely from a similar direction). The views
    are judged one at a time, the one with the most weight first; level 1 (half) when that share is at least
    ``HALF_COVERED``, else 0 (full). Deterministic."""
    cand = np.flatnonzero(candidates)
    keep = candidates[vi]
    vi, pi, u, foot, w = vi[keep], pi[keep], u[keep], foot[keep], w[keep]
    out: dict[int, tuple[int, float]] = {}
    if not len(vi):
        return {int(k): (0, 0.0) for k in cand}
    order = np.argsort(-np.bincount(vi, weights=w, minlength=len(candidates))[cand], kind="stable")
    by_view = {int(k): np.flatnonzero(vi == k) for k in cand}
    # per sample, the full-resolution views' rays and footprints so far (a list per sample: few views each)
    full_rays: dict[int, list] = {}
    cos_max = np.cos(np.radians(HALF_MAX_ANGLE_DEG))
    for k in cand[order]:
        obs = by_view[int(k)]
        if not len(obs):
            out[int(k)] = (0, 0.0)
            continue
        seen = np.zeros(len(obs), bool)
        for j, o in enumerate(obs):
            for ray, f in full_rays.get(int(pi[o]), ()):
                if f <= HALF_FOOTPRINT_RATIO * foot[o] and float(ray @ u[o]) >= cos_max:
                    seen[j] = True
                    break
        share = float(seen.mean())
        half = share >= HALF_COVERED
        out[int(k)] = (1 if half else 0, share)
        if not half:
            for o in obs:
                full_rays.setdefault(int(pi[o]), []).append((u[o], foot[o]))
    return out


# --depth-resolution auto: a chosen view whose depth map at half (or a quarter of) the working resolution still has a
# pixel footprint at most the one the fused mesh's voxel asks for (``mesh_levels``: the voxel under the fusion's
# memory budget, over its voxel footprints) gets it at that resolution: a finer map resolves what the mesh does not
# keep (on 119 photos at 1600 px, the 2 GB default budget's mesh keeps a voxel of about 4 footprints of the full
# maps). At most MESH_LEVEL_MAX levels down, and at least one level finer than the coarse round, so that every
# chosen view gets a round with the geometric term
MESH_LEVEL_MAX = 2


def map_footprint(depth: np.ndarray, cost: np.ndarray, working) -> float | None:
    """A coarse depth map's pixel footprint at its view's working resolution (``working``), over the pixels with a
    cost below ``COARSE_MAX_COST``, as the fusion measures footprints (``cameras.depth_footprint``)."""
    return depth_footprint(np.where(_surface(depth, cost), depth, 0), working.intrinsics)


PLAN_SAMPLES_PER_VIEW = 20000  # pixels of each coarse map checked against its sources for the mesh's plan


def confirmed_surface(maps: dict, sources: dict, need: int) -> dict:
    """The coarse maps ``maps`` (view name -> (view at the coarse level, depth, normal, cost)) with depth kept only
    at about ``PLAN_SAMPLES_PER_VIEW`` pixels a view (a regular grid) whose cost is below ``COARSE_MAX_COST`` and
    whose depth at least ``need`` of the view's ``sources`` (view name -> source names; fewer when it has fewer)
    confirm within ``COARSE_DEPTH_TOL_PX`` of their pixel footprint: the surface the geometric filter will keep,
    without the unconfirmed depths of textureless background that would swell a plan of the mesh's size."""
    out = {}
    for name, (lv, depth, normal, cost) in maps.items():
        rows, cols, _ = _grid_pixels(_surface(depth, cost), PLAN_SAMPLES_PER_VIEW)
        P = backproject_pixels(np.stack([cols, rows], 1), depth[rows, cols], lv.intrinsics, lv.cam_from_world)
        srcs = [s for s in sources.get(name, ()) if s in maps]
        count = np.zeros(len(rows), np.int64)
        for src in srcs:
            sv = maps[src][0]
            idx, zs, d = _look_up(sv, maps[src][1], P)
            tol = COARSE_DEPTH_TOL_PX * zs / (0.5 * (sv.intrinsics.fx + sv.intrinsics.fy))
            count[idx[(d > 0) & (np.abs(d - zs) <= tol)]] += 1
        keep = count >= min(need, len(srcs))
        kept = np.zeros_like(depth)
        kept[rows[keep], cols[keep]] = depth[rows[keep], cols[keep]]
        out[name] = (lv, kept, normal, cost)
    return out


def coarse_level(coarse, working) -> int:
    """The pyramid level of a coarse map's view ``coarse`` below its view at the working resolution ``working``."""
    return max(0, int(round(np.log2(working.intrinsics.width / coarse.intrinsics.width))))


def mesh_levels(choice: ViewChoice, working: dict, maps: dict, need: float) -> ViewChoice:
    """``choice`` with each chosen view at the coarsest level (at most ``MESH_LEVEL_MAX``, finer than its coarse map's,
    and a map of at least ``MIN_DEPTH_SIDE`` px on its long side) whose depth map has a footprint of at most
    ``need``, the one the fused mesh's voxel asks for (``ViewChoice.mesh_coarser``); ``working``: view name -> the
    view at its working resolution, ``maps``: view name -> (view at the coarse level, depth, normal, cost)."""
    coarser = {}
    for name in choice.chosen:
        if name in maps and name in working:
            f0 = map_footprint(maps[name][1], maps[name][3], working[name])
            top = min(MESH_LEVEL_MAX, coarse_level(maps[name][0], working[name]) - 1)
            side = max(working[name].intrinsics.size)
            lvl = 0
            while (f0 is not None and lvl < top and 2 ** (lvl + 1) * f0 <= need
                   and side / 2 ** (lvl + 1) >= MIN_DEPTH_SIDE):
                lvl += 1
            if lvl:
                coarser[name] = (lvl, f0)
    return replace(choice, mesh_footprint=float(need), mesh_coarser=coarser)


# the first look (``run_mvs``'s ``on_coarse``) of a capture with at least FIRST_LOOK_SPLIT_MIN views comes from the
# coarse maps of a spread share of them (FIRST_LOOK_SHARE, at least FIRST_LOOK_MIN_VIEWS), computed before the others:
# on 119 photos the preview is there after a quarter of the coarse round instead of all of it
FIRST_LOOK_SPLIT_MIN = 40
FIRST_LOOK_SHARE = 0.25
FIRST_LOOK_MIN_VIEWS = 20


def spread_views(views: list, count: int) -> list[int]:
    """Indices (ascending) of ``count`` of ``views`` spread over the capture: farthest-point sampling over the
    camera centres (scaled by their spread) and viewing directions, from the view nearest the mean of both.
    Deterministic; all indices when ``count`` >= the number of views."""
    n = len(views)
    if count >= n:
        return list(range(n))
    C = np.array([v.center for v in views], np.float64)
    axis = np.array([v.cam_from_world[2, :3] for v in views], np.float64)  # the optical axis in the world
    spread = float(np.sqrt(((C - C.mean(0)) ** 2).sum(1).mean())) or 1.0
    F = np.hstack([C / spread, axis])
    picked = [int(np.argmin(((F - F.mean(0)) ** 2).sum(1)))]
    d = ((F - F[picked[0]]) ** 2).sum(1)
    while len(picked) < count:
        k = int(np.argmax(d))
        picked.append(k)
        d = np.minimum(d, ((F - F[k]) ** 2).sum(1))
    return sorted(picked)


def first_look_views(views: list) -> list[int]:
    """The views whose coarse maps make the first look, computed first (``spread_views``): a spread
    ``FIRST_LOOK_SHARE`` of a capture of at least ``FIRST_LOOK_SPLIT_MIN`` views (at least ``FIRST_LOOK_MIN_VIEWS``);
    every view of a smaller one."""
    n = len(views)
    if n < FIRST_LOOK_SPLIT_MIN:
        return list(range(n))
    return spread_views(views, max(FIRST_LOOK_MIN_VIEWS, int(round(FIRST_LOOK_SHARE * n))))


# --depth-views coarse: the surface from PatchMatch's coarsest round
COARSE_MAX_COST = 0.5  # a coarse pixel is a surface sample when its matching cost (1 - NCC) is below this
COARSE_SAMPLES_PER_VIEW = 1000  # about this many samples per view's coarse depth map, on a regular grid
COARSE_DEPTH_TOL_PX = 3.0  # a sample is visible in a view whose coarse depth there is within this many pixel footprints
COARSE_MAX_VIEW_ANGLE_DEG = 65.0  # ... and whose ray makes at most this angle with the sample's normal
COARSE_COVER_FRACTION = 0.98  # the cover stops when this fraction of the samples have all the views they need
# --depth-views auto: after the sparse points' cover, the coarse depth maps' cover too when at least this many views
# are left: a capture that large is redundant enough for its sparse tracks (a handheld set's are short) to
# understate what each photo sees, and the coarse round, reused by the views chosen, costs only where views are dropped
COARSE_MIN_VIEWS = 40


def wants_coarse_cover(sparse: ViewChoice | None, cfg) -> bool:
    """Whether the coarse depth maps' cover chooses the views: always for ``--depth-views coarse`` (``sparse``
    None: no sparse points' cover made), and for ``auto`` when the sparse points' cover kept at least
    ``COARSE_MIN_VIEWS`` views."""
    if sparse is None:
        return cfg.depth_views == "coarse"
    return cfg.depth_views == "auto" and len(sparse.chosen) >= COARSE_MIN_VIEWS


def _surface(depth: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """A coarse map's surface pixels: a finite positive depth matched at a cost below ``COARSE_MAX_COST``."""
    return (depth > 0) & np.isfinite(depth) & (cost < COARSE_MAX_COST)


def _grid_pixels(ok: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Rows and columns of about ``count`` of the ``ok`` pixels, on a regular grid, and the grid's step."""
    step = max(1, int(np.sqrt(ok.sum() / count)))
    grid = np.zeros_like(ok)
    grid[::step, ::step] = True
    rows, cols = np.nonzero(ok & grid)
    return rows, cols, step


def _look_up(lv, D: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of world points ``P``: the indices of those in front of view ``lv`` whose nearest pixel lies in its map
    ``D``, their depth in that view, and ``D`` at that pixel."""
    T, intr = lv.cam_from_world, lv.intrinsics
    Pc = P @ T[:3, :3].T + T[:3, 3]
    z = Pc[:, 2]
    front = np.flatnonzero(z > 1e-12)
    uu = np.floor(intr.fx * Pc[front, 0] / z[front] + intr.cx + 0.5).astype(np.int64)
    vv = np.floor(intr.fy * Pc[front, 1] / z[front] + intr.cy + 0.5).astype(np.int64)
    inside = (uu >= 0) & (vv >= 0) & (uu < intr.width) & (vv < intr.height)
    idx = front[inside]
    return idx, z[idx], D[vv[inside], uu[inside]]


def _coarse_samples(lv, depth: np.ndarray, normal: np.ndarray, cost: np.ndarray):
    """World points and unit normals (towards the camera) of about ``COARSE_SAMPLES_PER_VIEW`` pixels of a coarse
    depth map whose cost is below ``COARSE_MAX_COST``, and the spacing of those samples on the surface."""
    ok = _surface(depth, cost)
    if not ok.any():
        return np.zeros((0, 3)), np.zeros((0, 3)), np.inf
    rows, cols, step = _grid_pixels(ok, COARSE_SAMPLES_PER_VIEW)
    z = depth[rows, cols].astype(np.float64)
    ray = lv.intrinsics.pixel_rays(np.stack([cols, rows], 1).astype(np.float64))
    n = normal[rows, cols].astype(np.float64)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    n *= -np.sign(np.einsum("ij,ij->i", n, ray))[:, None]  # towards the camera
    R, t = lv.cam_from_world[:3, :3], lv.cam_from_world[:3, 3]
    spacing = step * float(np.median(z)) / (0.5 * (lv.intrinsics.fx + lv.intrinsics.fy))
    return (ray * z[:, None] - t) @ R, n @ R, spacing


def coarse_depth_views(views: list, maps: dict, cfg) -> ViewChoice:
    """The views to compute full depth maps for, chosen from every view's coarse depth map (``maps``: view name
    -> (view at the coarse level, depth, camera-frame normal, matching cost); ``views``: the views at their
    working resolution). The coarse maps are a dense sample of the surface: their pixels (cost below
    ``COARSE_MAX_COST``, about ``COARSE_SAMPLES_PER_VIEW`` per view, one per cell of the samples' spacing)
    are the points to cover. A view sees a sample well when the sample projects inside it, its own coarse depth
    there agrees within ``COARSE_DEPTH_TOL_PX`` pixel footprints (not hidden, not in front of another surface),
    its ray makes at most ``COARSE_MAX_VIEW_ANGLE_DEG`` with the sample's normal, and its pixel footprint is
    within ``RESOLUTION_RATIO`` of the finest view's; then the greedy cover of ``choose_depth_views`` (each
    sample by ``cfg.depth_view_coverage`` chosen views) until ``COARSE_COVER_FRACTION`` of the samples are
    covered, as CMVS's coverage ratio: the last few samples, seen well by two or three views at the edge of
    their angle or resolution, would each ask for a view of their own. A sample that fewer other views' coarse
    depths confirm than the geometric filter will ask of a depth (``cfg.min_consistent``, at least one) needs no
    cover: a coarse mismatch, or surface the filter would not keep. Views without a coarse map are kept (the
    depth stage judges them)."""
    names = [v.name for v in views]
    pts, nrm, spacing = [], [], []
    for name in names:
        if name in maps:
            p, n, s = _coarse_samples(*maps[name])
            pts.append(p)
            nrm.append(n)
            spacing.append(s)
    P = np.concatenate(pts) if pts else np.zeros((0, 3))
    if len(P) < 2:
        return ViewChoice(names, len(names), "no coarse depth")
    N = np.concatenate(nrm)
    # one sample per cell of the samples' spacing: the surface sampled about evenly, whatever the views' overlap
    cell = float(np.median([s for s in spacing if np.isfinite(s)]))
    _, first = np.unique(np.floor(P / cell).astype(np.int64), axis=0, return_index=True)
    first = np.sort(first)
    P, N = P[first], N[first]
    vi, pi, u, foot = [], [], [], []
    confirmed = np.zeros(len(P), np.int64)  # views whose coarse depth agrees with the sample (its own included)
    cos_max = np.cos(np.radians(COARSE_MAX_VIEW_ANGLE_DEG))
    for k, v in enumerate(views):
        if v.name not in maps:
            continue
        lv = maps[v.name][0]
        intr = lv.intrinsics
        idx, zf, d = _look_up(lv, maps[v.name][1], P)
        tol = COARSE_DEPTH_TOL_PX * zf / (0.5 * (intr.fx + intr.fy))
        confirmed += np.bincount(idx[(d > 0) & (np.abs(d - zf) <= tol)], minlength=len(P))
        seen = (d <= 0) | (zf <= d + tol)  # not behind the surface the view's own coarse depth shows there
        idx, zf = idx[seen], zf[seen]
        ray = v.center - P[idx]
        ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-30)
        good = np.einsum("ij,ij->i", ray, N[idx]) >= cos_max
        idx = idx[good]
        vi.append(np.full(len(idx), k, np.int64))
        pi.append(idx)
        u.append(ray[good])
        foot.append(zf[good] / (0.5 * (v.intrinsics.fx + v.intrinsics.fy)))
    vi, pi, u, foot = (np.concatenate(a) for a in (vi, pi, u, foot))
    # a sample fewer other views' coarse depths confirm than the geometric filter will ask of its depth (at least
    # one) is a coarse mismatch, or surface the filter would not keep: nothing to cover
    real = confirmed[pi] >= 1 + max(1, int(cfg.min_consistent))
    vi, pi, u, foot = vi[real], pi[real], u[real], foot[real]
    n_pts, n_views = len(P), len(views)
    finest = np.full(n_pts, np.inf)
    np.minimum.at(finest, pi, foot)
    good = foot <= RESOLUTION_RATIO * finest[pi]
    vi, pi, u, w = vi[good], pi[good], u[good], (finest[pi] / foot)[good]
    need_k = max(1, int(cfg.depth_view_coverage))
    taken, n_counted, need = _greedy_cover(vi, pi, u, w, n_pts, n_views, need_k, cfg.min_angle_deg,
                                           COARSE_COVER_FRACTION)
    if taken.sum() < 2:
        return ViewChoice(names, n_views, "no coarse surface seen well by two views")
    keep = taken | np.array([n not in maps for n in names])
    uncovered = int(np.count_nonzero(n_counted < need))
    resolution = {}
    if cfg.depth_resolution == "auto":
        levels = half_resolution_views(vi, pi, u, foot[good], w, taken, n_pts)
        resolution = {names[k]: levels.get(k, (0, 0.0)) for k in range(n_views) if keep[k]}
    return ViewChoice([names[k] for k in range(n_views) if keep[k]], n_views, "coarse depth coverage", uncovered,
                      surface_samples=int(np.count_nonzero(need)), resolution=resolution)
