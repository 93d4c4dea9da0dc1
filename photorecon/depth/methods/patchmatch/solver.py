"""PatchMatch multi-view stereo on the CPU (ACMH + ACMM's multi-scale geometric consistency), numba kernels.

Per reference view and per pyramid level, coarse to fine:

* **Hypotheses** are planes: a z-depth and a normal per pixel (reference camera frame, OpenCV axes).
* **Initialisation**: at the coarsest level, random planes (depth uniform in inverse depth over the view's
  range, normal uniform facing the camera), with the view's sparse SfM points seeded as fronto-parallel
  planes; at finer levels, each pixel takes the plane of its nearest coarse pixel (slants survive).
* **Red-black checkerboard propagation** (ACMH's adaptive sampling: 8 regions, best neighbour of each),
  **multi-hypothesis joint view selection** per pixel, and **refinement** by perturbed and random depths
  and normals (``kernels.pm_pass``).
* **Matching cost**: 1 - NCC, bilaterally weighted, over a strided window (``radius`` 5, ``stride`` 2: an
  11x11 window sampled every 2 pixels; ``--pm-radius 4``: 9x9, 25 samples instead of 36, 1.2x faster); on
  images of at least ``pm_sparse_min_size`` (1024) pixels, every other sample of that grid (a checkerboard:
  18 samples over the same 11x11 pixels).
* **Geometric consistency** (ACMM): at every level but the coarsest, the cost adds ``geom_weight`` x the
  forward-backward reprojection error (pixels, capped) through each source's depth map of the previous
  level, which pulls views together and fills weakly textured areas from their coarse estimates; a final
  round at full resolution uses the full-resolution depth maps of the other views, and leaves the pixels that
  ``pm_skip_consistent`` of them already confirm as they are.
* **Masks**: pixels outside a view's mask are never computed (their depth would be dropped anyway).
* **Sources carried between rounds** (``pm_carry_views``): after the coarsest level, a pixel matches only the
  sources that the view selection of the round before used there or at the neighbours it takes candidates
  from; a source that sees none of the pixel's surface stops costing evaluations.

Results are ``DepthResult``s at working resolution with a per-pixel normal; the caller (``mvs.run_mvs``)
filters them (confidence, geometric consistency between views) and writes them.
"""
from __future__ import annotations

import copy
import dataclasses
import logging
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from ....cameras import View, invert_rigid
from ...config import EDGE_TOL

log = logging.getLogger("photorecon")


@dataclass
class PMJob:
    """One reference view to compute: its working-resolution view, source names, depth range and the world
    points (SfM) it sees, used as seeds."""

    view: View
    sources: list[str]
    dmin: float
    dmax: float
    seeds: np.ndarray
    last_round: int | None = None  # its last round (``last_round``; None: every round of ``pm_rounds``)


def level_view(view: View, level: int) -> View:
    """``view`` with its image halved ``level`` times (sizes rounded, pixel centres kept consistent)."""
    if level == 0:
        return view
    W, H = view.intrinsics.size
    f = 0.5 ** level
    intr = view.intrinsics.scaled(max(8, int(round(W * f))), max(8, int(round(H * f))))
    return dataclasses.replace(view, intrinsics=intr)


def _kernels():
    from . import kernels

    return kernels


def _pinhole_K(view: View) -> np.ndarray:
    return np.ascontiguousarray(view.intrinsics.K, np.float64)


def _stack(arrays: list[np.ndarray]) -> np.ndarray:
    """Stack 2D float32 arrays, zero-padded to the largest (sources of mixed sizes)."""
    h = max(a.shape[0] for a in arrays)
    w = max(a.shape[1] for a in arrays)
    if all(a.shape == (h, w) for a in arrays):
        return np.ascontiguousarray(np.stack(arrays), np.float32)
    out = np.zeros((len(arrays), h, w), np.float32)
    for i, a in enumerate(arrays):
        out[i, : a.shape[0], : a.shape[1]] = a
    return out


class _Geometry:
    """Per (reference, sources) pair, at one level: the homography terms A_j = K_j R_j K_r^-1, b_j = K_j t_j,
    and the relative poses (source from reference) for the geometric term."""

    def __init__(self, ref: View, sources: list[View]):
        Kr = _pinhole_K(ref)
        Krinv = np.linalg.inv(Kr)
        world_from_ref = invert_rigid(ref.cam_from_world)
        S = len(sources)
        self.Kr, self.Kinv = Kr, Krinv
        self.A = np.zeros((S, 3, 3))
        self.b = np.zeros((S, 3))
        self.R = np.zeros((S, 3, 3))
        self.t = np.zeros((S, 3))
        for j, s in enumerate(sources):
            rel = s.cam_from_world @ world_from_ref
            Ks = _pinhole_K(s)
            self.R[j], self.t[j] = rel[:3, :3], rel[:3, 3]
            self.A[j] = Ks @ rel[:3, :3] @ Krinv
            self.b[j] = Ks @ rel[:3, 3]

    def reprojection(self, Kd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The geometric term's per-source terms for depth maps with intrinsics ``Kd`` (S, 3, 3): forward
        GP = Kd R, Ge = Kd t; backward GM = Kr R^T Kd^-1, Gg = Kr R^T t (see ``kernels._geo``)."""
        RT = self.R.transpose(0, 2, 1)
        GP = np.ascontiguousarray(Kd @ self.R)
        Ge = np.ascontiguousarray(np.einsum("sij,sj->si", Kd, self.t))
        GM = np.ascontiguousarray(self.Kr @ RT @ np.linalg.inv(Kd))
        Gg = np.ascontiguousarray(np.einsum("ij,sjk,sk->si", self.Kr, RT, self.t))
        return GP, Ge, GM, Gg


class PatchMatchParams:
    """The kernel settings derived from an ``MVSConfig`` (window samples, regions, thresholds)."""

    def __init__(self, cfg):
        k = _kernels()
        sigma_s = max(cfg.pm_radius * 0.6, 1.0)
        self.sdy, self.sdx, self.sspat = k.window_samples(cfg.pm_radius, cfg.pm_stride, sigma_s)
        self.sparse = k.window_samples(cfg.pm_radius, cfg.pm_stride, sigma_s, checker=True)
        self.rdy, self.rdx, self.rn = k.sampling_regions()
        self.sigma_c = float(cfg.pm_sigma_color)
        self.min_var = 1e-5
        self.cfg = cfg

    def at_size(self, view: View) -> "PatchMatchParams":
        """These settings for an image of ``view``'s size: the checkerboard window (``sparse``) when its long side
        has at least ``pm_sparse_min_size`` pixels (there neighbouring samples carry nearly the same grey levels),
        else the full grid."""
        m = self.cfg.pm_sparse_min_size
        if m <= 0 or max(view.intrinsics.size) < m:
            return self
        p = copy.copy(self)
        p.sdy, p.sdx, p.sspat = self.sparse
        return p


def seed_planes(depth: np.ndarray, normal: np.ndarray, view: View, points: np.ndarray, dmin: float, dmax: float) -> int:
    """Set fronto-parallel planes at the pixels where ``view`` sees the world ``points``; returns how many."""
    if not len(points):
        return 0
    T = view.cam_from_world
    Xc = points @ T[:3, :3].T + T[:3, 3]
    z = Xc[:, 2]
    ok = (z >= dmin) & (z <= dmax)
    Xc, z = Xc[ok], z[ok]
    intr = view.intrinsics
    u = np.round(intr.fx * Xc[:, 0] / z + intr.cx).astype(np.int64)
    v = np.round(intr.fy * Xc[:, 1] / z + intr.cy).astype(np.int64)
    ok = (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
    u, v, z, Xc = u[ok], v[ok], z[ok], Xc[ok]
    depth[v, u] = z
    n = -Xc / np.linalg.norm(Xc, axis=1, keepdims=True)
    normal[v, u] = n
    return int(len(u))


def patchmatch_view(ref_img: np.ndarray, ref: View, src_imgs: list[np.ndarray], sources: list[View],
                    dmin: float, dmax: float, params: PatchMatchParams, iterations: int,
                    init: tuple[np.ndarray, np.ndarray] | None = None, seeds: np.ndarray | None = None,
                    geo: tuple[list[np.ndarray], list[View]] | None = None, seed: int = 0,
                    init_cost: np.ndarray | None = None, n_refine: int = 6,
                    prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None, prior_after: bool = False,
                    skip_consistent: int = 0, active: np.ndarray | None = None, counts: dict | None = None,
                    select_current: bool = False, views: np.ndarray | None = None, views_read: bool = False):
    """PatchMatch on one reference image at one resolution. ``init``: (depth, normal) to start from (0 depth =
    random), else random planes and the ``seeds`` (world points). ``geo``: the sources' depth maps and their
    views, for the geometric-consistency term. ``init_cost``: the hypotheses' costs when known (the coarser
    level's, upsampled: they only rank neighbours until each pixel's own cost is recomputed in the first
    half-pass), else computed. ``n_refine``: refinement hypotheses per pixel (6: perturbed and random; 3:
    perturbed only). ``prior``: the previous round's (depth, normal, cost) at this resolution, for the planar
    prior (``planar.inject_prior``), else None; ``prior_after``: once more after the iterations, from their
    result (the last round). ``skip_consistent``: with ``geo``, pixels whose hypothesis at least this many sources'
    depth maps confirm within 1 pixel (forward-backward) are left as they are (0 = none).
    ``active``: (H, W) bool, the pixels to compute (the view's mask), else all; the others get depth 0.
    ``select_current``: view weights from each pixel's current hypothesis, the other candidates evaluated in
    the weighted sources only (for hypotheses that start good: finer levels), else ACMH's joint view selection.
    ``views``: (H, W) int32, updated: each computed pixel's view selection as bits (bit j: source j weighted);
    with ``views_read`` its values on entry (an earlier round's, upsampled) restrict each pixel to the sources that
    it or the neighbours it takes candidates from used (``kernels.pm_pass``).
    ``counts``: a dict that gets the work done, as the number of NCC evaluations: ``"initial"`` (the starting
    costs) and ``"iterations"``, per iteration a dict (pixels computed, pixels skipped as converged, evaluations
    of the candidates and of the refinement) (``count_work``).
    Returns (depth, normal, cost) at ``ref``'s resolution."""
    k = _kernels()
    cfg = params.cfg
    H, W = ref_img.shape
    if init is None:
        depth = np.zeros((H, W), np.float32)
        normal = np.zeros((H, W, 3), np.float32)
        if seeds is not None:
            seed_planes(depth, normal, ref, seeds, dmin, dmax)
    else:
        depth, normal = np.ascontiguousarray(init[0], np.float32), np.ascontiguousarray(init[1], np.float32)
    if active is not None:
        depth[~active] = -1.0  # never computed, never propagated
    g = _Geometry(ref, sources)
    k.init_random(depth, normal, g.Kinv, float(dmin), float(dmax), int(seed), True)
    ref_img = np.ascontiguousarray(ref_img, np.float32)
    srcs = _stack(src_imgs)
    if geo is not None:
        sdepth = _stack(geo[0])
        GP, Ge, GM, Gg = g.reprojection(np.stack([_pinhole_K(v) for v in geo[1]]))
        use_geo, lam = True, float(cfg.geom_weight)
    else:
        sdepth = np.zeros((len(sources), 1, 1), np.float32)
        GP, GM = np.zeros((len(sources), 3, 3)), np.zeros((len(sources), 3, 3))
        Ge, Gg = np.zeros((len(sources), 3)), np.zeros((len(sources), 3))
        use_geo, lam = False, 0.0
    delta = 3.0
    best_k = max(1, min(len(sources), (len(sources) + 1) // 2))  # the cost aggregates the best half of the sources
    if init_cost is not None and init_cost.shape == (H, W):
        cost = np.array(init_cost, np.float32)  # a copy: the kernel updates it
        cost[depth <= 0] = 2.0 + lam * delta
    else:
        cost = np.empty((H, W), np.float32)
        if counts is not None:
            counts["initial"] = counts.get("initial", 0) + int((depth > 0).sum()) * len(sources)
        k.initial_cost(ref_img, srcs, g.A, g.b, g.Kinv, GP, Ge, GM, Gg, sdepth, use_geo, lam, delta,
                       params.sdy, params.sdx, params.sspat, params.sigma_c, params.min_var, best_k, depth, normal, cost)
    if prior is not None:  # planar prior (ACMP-style): hypotheses from triangulated confident pixels
        from ...planar import inject_prior

        def cost_of(d, n, out):
            k.initial_cost(ref_img, srcs, g.A, g.b, g.Kinv, GP, Ge, GM, Gg, sdepth, use_geo, lam, delta, params.sdy,
                           params.sdx, params.sspat, params.sigma_c, params.min_var, best_k, d, n, out)

        st = inject_prior(depth, normal, cost, prior, g.Kinv, dmin, dmax, cost_of)
        log.debug("planar prior: %s", st)
    if active is not None:
        depth[~active] = -1.0
    work = np.zeros((H, k.N_COUNTS), np.int64)
    if views is None:
        views = np.zeros((1, 1), np.int32)  # none: the kernel neither reads nor writes bits
    for it in range(iterations):
        work[:] = 0
        tau_good = 0.8 * np.exp(-(it ** 2) / 90.0)
        pert = max(0.02 * 0.5 ** it, 0.002)
        for color in (0, 1):
            k.pm_pass(color, it, ref_img, srcs, g.A, g.b, g.Kinv, GP, Ge, GM, Gg, sdepth, use_geo, lam, delta,
                      params.sdy, params.sdx, params.sspat, params.sigma_c, params.min_var,
                      params.rdy, params.rdx, params.rn, float(dmin), float(dmax),
                      float(tau_good), 1.2, 2, 3, 0.3, float(pert), int(seed), int(n_refine),
                      float(cfg.pm_same_depth), float(np.cos(np.radians(cfg.pm_same_normal_deg))), 1.0, int(skip_consistent),
                      bool(select_current), depth, normal, cost, work, views, bool(views_read))
        if counts is not None:
            counts.setdefault("iterations", []).append(count_work(work))
    if prior is not None and prior_after:
        from ...planar import textureless

        st = inject_prior(depth, normal, cost, (depth.copy(), normal.copy(), cost.copy()), g.Kinv, dmin, dmax, cost_of,
                          flat=textureless(ref_img, cfg.pm_radius))
        log.debug("planar prior, after the last iteration: %s", st)
    if active is not None:
        depth[depth < 0] = 0.0
    return depth, normal, cost


def count_work(work: np.ndarray) -> dict[str, int]:
    """``pm_pass``'s per-row counts, summed: pixels computed, pixels skipped as converged, NCC evaluations of
    the candidates and of the refinement."""
    k = _kernels()
    t = work.sum(axis=0)
    return {"pixels": int(t[k.COUNT_PIXELS]), "skipped": int(t[k.COUNT_SKIPPED]),
            "candidate_evals": int(t[k.COUNT_CANDIDATE]), "refine_evals": int(t[k.COUNT_REFINE])}


def pm_rounds(cfg) -> list[tuple[int, bool, int]]:
    """The rounds of multi-scale PatchMatch, coarse to fine: (pyramid level, geometric term, iterations); ACMM's
    extra geometric round at level ``pm_final_level`` (0: full resolution, last), right after that level's own
    (without ``pm_final_own_round``: that level's one round)."""
    return _rounds(cfg)[0]


def _rounds(cfg) -> tuple[list[tuple[int, bool, int]], int]:
    """``pm_rounds`` and the index of the extra geometric round (-1: none), the round that leaves the pixels the
    other views already confirm as they are (``pm_skip_consistent``)."""
    levels = max(1, int(cfg.pm_levels))
    final = cfg.geom_consistency and cfg.pm_final_iterations > 0
    final_level = min(max(0, int(cfg.pm_final_level)), levels - 2) if levels > 1 else 0
    rounds = [(levels - 1, False, cfg.pm_iterations)]
    index = -1
    for lvl in reversed(range(levels - 1)):
        if cfg.pm_final_own_round or not (final and lvl == final_level):
            rounds.append((lvl, cfg.geom_consistency, cfg.pm_fine_iterations))
        if final and lvl == final_level:
            index = len(rounds)
            rounds.append((lvl, True, cfg.pm_final_iterations))
    if final and levels == 1:
        index = len(rounds)
        rounds.append((0, True, cfg.pm_final_iterations))
    return rounds, index


def last_round(cfg, level: int = 0) -> int:
    """The last round of a view whose depth map stops at pyramid level ``level`` (0: the working resolution, every
    round; 1: the last round at half of it, ...): the last of ``pm_rounds`` at a level of at least ``level``, and
    at least the first round."""
    rounds = pm_rounds(cfg)
    return max([r for r, (lvl, _, _) in enumerate(rounds) if lvl >= level], default=0)


def job_last_round(job: PMJob, cfg) -> int:
    return len(pm_rounds(cfg)) - 1 if job.last_round is None else job.last_round


def round_sources(job: PMJob, r: int, by_name: dict[str, PMJob], cfg) -> list[str]:
    """The source views ``job`` matches in round ``r`` (all of them in the first, the best
    ``pm_fine_sources`` after), among the views being computed."""
    names = job.sources if r == 0 or cfg.pm_fine_sources <= 0 else job.sources[: cfg.pm_fine_sources]
    return [s for s in names if s in by_name]


def round_dependencies(job: PMJob, r: int, by_name: dict[str, PMJob], cfg) -> list[str]:
    """The views whose round ``r - 1`` (or their last, when that comes earlier: ``read_round``) round ``r`` of
    ``job`` reads: itself (its starting planes), and with the geometric term its sources (their depth maps)."""
    if r == 0:
        return []
    geometric = pm_rounds(cfg)[r][1]
    return [job.view.name] + (round_sources(job, r, by_name, cfg) if geometric else [])


def read_round(source: PMJob, r: int, cfg) -> int:
    """The round of ``source`` whose maps round ``r`` of another view reads: ``r - 1``, or the source's last round
    when it stops earlier (a depth map at a coarser level)."""
    return min(r - 1, job_last_round(source, cfg))


def pm_view_round(job: PMJob, r: int, by_name: dict[str, PMJob], image: Callable[[str, View], np.ndarray],
                  params: PatchMatchParams, load: Callable[[str, int, str], np.ndarray],
                  mask: Callable[[str, View], np.ndarray | None] | None = None):
    """Round ``r`` (of ``pm_rounds``) of PatchMatch for one reference view. ``image(name, view)``: the grey
    float32 image of view ``name`` at ``view``'s resolution; ``load(name, round, what)``: the ``"depth"``,
    ``"normal"`` or ``"cost"`` map of a view after an earlier round (``round_dependencies`` says which are
    read; with ``pm_carry_views`` also ``"views"``). ``mask(name, view)``: the view's foreground at ``view``'s
    resolution, or None: pixels outside it are not computed (their depth would be dropped anyway). Returns (depth,
    normal, cost, view at this round's resolution, view selection bits or None: ``patchmatch_view``'s ``views``)."""
    cfg = params.cfg
    rounds, final_round = _rounds(cfg)
    lvl, geometric, iters = rounds[r]
    first = r == 0
    name = job.view.name
    ref = level_view(job.view, lvl)
    src_names = round_sources(job, r, by_name, cfg)
    srcs = [level_view(by_name[s].view, lvl) for s in src_names]
    init = c_init = geo = prior = None
    carry = cfg.pm_carry_views and len(src_names) <= _kernels().MAX_CARRIED_SOURCES
    views = np.zeros((ref.intrinsics.height, ref.intrinsics.width), np.int32) if carry else None
    active = mask(name, ref) if mask is not None else None
    if not first:
        prev_lvl = rounds[r - 1][0]
        v_prev = level_view(job.view, prev_lvl)
        d_prev, n_prev, cost_prev = (load(name, r - 1, what) for what in ("depth", "normal", "cost"))
        c_up = cv2.resize(cost_prev, ref.intrinsics.size, interpolation=cv2.INTER_NEAREST)
        if cfg.pm_reuse_cost:
            c_init = c_up
        if v_prev.intrinsics.size == ref.intrinsics.size:
            init = (d_prev.copy(), n_prev)
        else:
            d = np.zeros((ref.intrinsics.height, ref.intrinsics.width), np.float32)
            n = np.zeros(d.shape + (3,), np.float32)
            _kernels().upsample_planes(d_prev, n_prev, np.linalg.inv(_pinhole_K(v_prev)),
                                       np.linalg.inv(_pinhole_K(ref)), d, n)
            init = (d, n)
        if views is not None:
            try:
                views = cv2.resize(load(name, r - 1, "views"), ref.intrinsics.size, interpolation=cv2.INTER_NEAREST)
            except (KeyError, OSError):  # a round written without them: every source, this round
                pass
        if cfg.planar_prior:
            prior = (init[0].copy(), np.array(init[1], np.float32), c_up)
        if geometric and src_names:
            read = [read_round(by_name[s], r, cfg) for s in src_names]
            geo = ([load(s, rr, "depth") for s, rr in zip(src_names, read)],
                   [level_view(by_name[s].view, rounds[rr][0]) for s, rr in zip(src_names, read)])
        if cfg.pm_prune_cost > 0:
            keep = pruned_active(d_prev, cost_prev, cfg.pm_prune_cost, ref)
            active = keep if active is None else active & keep
    depth, normal, cost = patchmatch_view(
        image(name, ref), ref, [image(s, v) for s, v in zip(src_names, srcs)], srcs, job.dmin, job.dmax,
        params.at_size(ref), iters, init=init, seeds=job.seeds if first else None, geo=geo, seed=cfg.pm_seed,
        init_cost=c_init, n_refine=6 if first else cfg.pm_fine_refine, prior=prior, prior_after=r == job_last_round(job, cfg),
        skip_consistent=cfg.pm_skip_consistent if r == final_round else 0,
        active=active, select_current=not first and cfg.pm_fine_views == "current", views=views, views_read=not first)
    return depth, normal, cost, ref, views


def pruned_active(depth: np.ndarray, cost: np.ndarray, max_cost: float, ref: View, grow: int = 2) -> np.ndarray:
    """The pixels of ``ref`` worth computing after a round that gave (``depth``, ``cost``): those within ``grow``
    of that round's pixels of a valid depth matched at a cost of at most ``max_cost`` (at that round's
    resolution), as a (H, W) bool at ``ref``'s."""
    good = ((depth > 0) & (cost <= max_cost)).astype(np.uint8)
    if grow > 0:
        good = cv2.dilate(good, np.ones((2 * grow + 1, 2 * grow + 1), np.uint8))
    W, H = ref.intrinsics.size
    if good.shape != (H, W):
        good = cv2.resize(good, (W, H), interpolation=cv2.INTER_NEAREST)
    return good > 0


def ncc_cost_reference(ref: np.ndarray, src: np.ndarray, x: int, y: int, Hm: np.ndarray, radius: int, stride: int,
                       sigma_space: float, sigma_color: float, min_var: float = 1e-5, checker: bool = False) -> float:
    """Slow, obviously correct 1 - bilateral NCC of one pixel's window through the homography ``Hm`` (ref
    pixel -> source pixel): the test oracle for the compiled ``_ncc``. ``checker``: only the window's samples
    whose grid row and column add up to an even number (``window_samples(..., checker=True)``)."""
    Hh, Ww = ref.shape
    hs, ws = src.shape
    c = np.array([x, y, 1.0]) @ Hm.T
    if c[2] <= 1e-12:
        return 2.0
    cx, cy = c[0] / c[2], c[1] / c[2]
    if not (-EDGE_TOL <= cx <= ws - 1 + EDGE_TOL and -EDGE_TOL <= cy <= hs - 1 + EDGE_TOL):
        return 2.0
    rs, ss, ws_ = [], [], []
    for iy, dy in enumerate(range(-radius, radius + 1, stride)):
        for ix, dx in enumerate(range(-radius, radius + 1, stride)):
            if checker and (iy + ix) % 2:
                continue
            u, v = min(max(x + dx, 0), Ww - 1), min(max(y + dy, 0), Hh - 1)
            r = float(ref[v, u])
            w = np.exp(-(dx * dx + dy * dy) / (2 * sigma_space ** 2)) * np.exp(-(r - ref[y, x]) ** 2 / (2 * sigma_color ** 2))
            p = np.array([u, v, 1.0]) @ Hm.T
            sx = min(max(p[0] / p[2], 0.0), ws - 1.001)
            sy = min(max(p[1] / p[2], 0.0), hs - 1.001)
            s = cv2.getRectSubPix(src.astype(np.float32), (1, 1), (sx, sy))[0, 0]  # bilinear
            rs.append(r)
            ss.append(float(s))
            ws_.append(w)
    r, s, w = np.array(rs), np.array(ss), np.array(ws_)
    w = w / w.sum()
    mr, ms = (w * r).sum(), (w * s).sum()
    vr = max((w * r * r).sum() - mr * mr, min_var)
    vs = max((w * s * s).sum() - ms * ms, min_var)
    cov = (w * r * s).sum() - mr * ms
    return float(np.clip(1 - cov / np.sqrt(vr * vs), 0, 2))
