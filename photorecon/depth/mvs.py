"""Multi-view stereo on the CPU (numpy + OpenCV), no weights and no GPU.

For each reference view:

1. **View selection**: K source views ranked by shared sparse points weighted by their triangulation angle
   (best near 15 degrees, none below 2), or by camera geometry when the model has no points.
2. **Depth range** from the sparse points seen in the view (PatchMatch: 1st percentile x 0.6 to 99th x 1.25;
   the sweep, whose planes get coarser as the range grows: 1st / 1.1 to 99th x 1.1); for a model
   without any sparse point, from where the cameras' optical axes converge.
3. **Plane sweep** over ``n_depths`` fronto-parallel planes uniform in inverse depth: each source image is
   warped onto the reference with the plane's homography (``cv2.warpPerspective``); the matching cost is
   ZNCC over a ``window`` box (box filters), aggregated as the mean of the best ``best_k`` sources
   (occlusion-robust); winner-take-all, then a parabola through the neighbouring scores for sub-plane depth.
   Confidence = the aggregated ZNCC of the winner (TSDF fusion uses it as the pixel's weight). Work happens
   at most ``max_size`` pixels wide.
4. **Filtering**: confidence threshold, then geometric consistency: each depth is re-projected into every
   source view's depth map and back; it is kept when at least ``min_consistent`` views agree within
   ``reproj_px`` pixels and ``rel_depth`` relative depth.

Outputs, in the synth layout: ``depth/NAME.npy`` (float32 z-depth, 0 = none), ``depth/NAME.conf.npy``
(float32 confidence in [0, 1]) and ``depth/NAME.png`` (preview).
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from ..cameras import View, backproject_depth, invert_rigid, project, transform_points
from ..errors import NoDepthError
from ..io.atomic import atomic_path, atomic_write_json
from ..io.images import write_depth
from ..progress import bar

log = logging.getLogger("photorecon")


@dataclass
class MVSConfig:
    """Settings of the multi-view stereo stage (``photorecon mvs``)."""

    method: Literal["patchmatch", "sweep"] = field(default="patchmatch", metadata={"flag": "--mvs", "help": "patchmatch: per-pixel depth and normal (ACMH/ACMM, the default); sweep: fronto-parallel plane sweep (a fast preview)"})
    n_sources: int = field(default=8, metadata={"help": "source views per reference view"})
    max_size: int = field(default=1600, metadata={"help": "working resolution: longest image side in pixels (0 = full resolution)"})
    min_confidence: float = field(default=0.2, metadata={"help": "drop depths whose confidence (1 - matching cost) is below this"})
    min_consistent: int = field(default=2, metadata={"help": "geometric filter: other views that must agree (0 = off)"})
    reproj_px: float = field(default=2.0, metadata={"help": "geometric filter: max reprojection error, pixels (ACMM: 2)"})
    rel_depth: float = field(default=0.01, metadata={"help": "geometric filter: max relative depth difference"})
    depth_near: float | None = field(default=None, metadata={"help": "depth range: the sparse points' 1st percentile times this (default: 0.6 for patchmatch, whose search is continuous; 1/1.1 for the sweep, whose planes get coarser as the range grows)"})
    depth_far: float | None = field(default=None, metadata={"help": "depth range: the sparse points' 99th percentile times this (default: 1.25 for patchmatch, 1.1 for the sweep)"})
    min_angle_deg: float = field(default=2.0, metadata={"help": "view selection: minimum triangulation angle"})
    pm_levels: int = field(default=3, metadata={"help": "patchmatch: pyramid levels (each halves the image)"})
    pm_iterations: int = field(default=5, metadata={"help": "patchmatch: iterations at the coarsest level"})
    pm_fine_iterations: int = field(default=1, metadata={"help": "patchmatch: iterations at each finer level"})
    pm_final_iterations: int = field(default=1, metadata={"help": "patchmatch: extra geometric-consistency iterations at full working resolution"})
    pm_radius: int = field(default=5, metadata={"help": "patchmatch: NCC window radius in pixels"})
    pm_stride: int = field(default=2, metadata={"help": "patchmatch: NCC window sampled every this many pixels"})
    pm_sigma_color: float = field(default=0.1, metadata={"help": "patchmatch: bilateral NCC weight's grey-level sigma (grey in 0..1)"})
    pm_fine_sources: int = field(default=4, metadata={"help": "patchmatch: after the coarsest level, match only the best this many of the source views (0 = all; measured at 1600x1067: 4 of 8 is 1.6x faster, same accuracy)"})
    pm_fine_refine: int = field(default=3, metadata={"help": "patchmatch: refinement hypotheses per pixel after the coarsest level (3: perturbed depth, normal, both; 6: also random ones)"})
    pm_reuse_cost: bool = field(default=True, metadata={"help": "patchmatch: finer levels start from the coarser level's costs (upsampled) instead of recomputing them"})
    pm_same_depth: float = field(default=1e-3, metadata={"help": "patchmatch: candidates this close in relative depth (and --pm-same-normal-deg in normal) share one cost evaluation"})
    pm_same_normal_deg: float = field(default=1.5, metadata={"help": "patchmatch: normal tolerance of --pm-same-depth, degrees"})
    geom_consistency: bool = field(default=True, metadata={"help": "patchmatch: geometric-consistency term between views (ACMM)"})
    geom_weight: float = field(default=0.2, metadata={"help": "patchmatch: weight of the geometric term (pixels of reprojection error)"})
    triangulate: bool = field(default=True, metadata={"help": "cameras without sparse points: triangulate SIFT matches with the cameras held fixed, for view selection and depth ranges"})
    pm_seed: int = field(default=0, metadata={"help": "patchmatch: random seed (results are deterministic for a seed)"})
    n_depths: int = field(default=128, metadata={"help": "sweep: depth hypotheses (planes, uniform in inverse depth)"})
    window: int = field(default=7, metadata={"help": "sweep: ZNCC window size in pixels (odd)"})
    best_k: int = field(default=2, metadata={"help": "sweep: aggregate the best k source scores per pixel"})


# Named settings for a caller that needs other values than the defaults (which are for 1600-px photos):
# "fast" is PatchMatch for small images and previews (the demo): 4 sources, 2 pyramid levels, fewer iterations.
MVS_PRESETS: dict[str, dict] = {
    "fast": dict(n_sources=4, pm_levels=2, pm_iterations=4, pm_fine_iterations=1, pm_final_iterations=1,
                 min_consistent=1),
}


@dataclass
class DepthResult:
    depth: np.ndarray  # (h, w) float32 at working resolution
    confidence: np.ndarray  # (h, w) float32 in [0, 1]
    view: View  # the reference view at working resolution
    sources: list[str]
    normal: np.ndarray | None = None  # (h, w, 3) float16 unit normals, reference camera frame (patchmatch)


def _gray(img: np.ndarray) -> np.ndarray:
    g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    return g.astype(np.float32) / 255.0


def _working_view(view: View, max_size: int) -> View:
    W, H = view.intrinsics.size
    s = min(1.0, max_size / max(W, H)) if max_size > 0 else 1.0
    if s >= 1.0:
        return view
    intr = view.intrinsics.scaled(int(round(W * s)), int(round(H * s)))
    return dataclasses.replace(view, intrinsics=intr, extra=dict(view.extra))


def select_sources(model, ref: View, cfg: MVSConfig) -> list[View]:
    """Rank the other views for ``ref``: shared sparse points weighted by triangulation angle; without
    points, by viewing-direction similarity and distance."""
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
    return [v for s, v in scores[: cfg.n_sources] if s > 0]


# Depth-range factors on the sparse points' (1st, 99th) percentiles, per method: PatchMatch searches depth
# continuously, so a wide range costs it little; the sweep's planes get coarser as its range grows.
DEPTH_RANGE_FACTORS = {"patchmatch": (0.6, 1.25), "sweep": (1 / 1.1, 1.1)}


def depth_range(model, view: View, near: float = DEPTH_RANGE_FACTORS["patchmatch"][0],
                far: float = DEPTH_RANGE_FACTORS["patchmatch"][1]) -> tuple[float, float] | None:
    """Depth range of the sparse points seen in ``view``: their 1st percentile x ``near`` to their 99th x ``far``;
    None without points. The near side is widened most: a surface seen at a grazing angle close to the camera
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


def plane_sweep(ref_img: np.ndarray, ref: View, sources: list[tuple[np.ndarray, View]], zmin: float, zmax: float,
                cfg: MVSConfig) -> tuple[np.ndarray, np.ndarray]:
    """Fronto-parallel plane sweep; returns (depth (h, w), confidence (h, w)) for ``ref``."""
    H, W = ref_img.shape
    win = (cfg.window, cfg.window)
    Kr_inv = np.linalg.inv(ref.intrinsics.K)
    mu_r = cv2.boxFilter(ref_img, -1, win)
    var_r = cv2.boxFilter(ref_img * ref_img, -1, win) - mu_r * mu_r
    inv_depths = np.linspace(1.0 / zmax, 1.0 / zmin, cfg.n_depths)
    world_from_ref = invert_rigid(ref.cam_from_world)
    n_src = len(sources)
    k = min(cfg.best_k, n_src)
    rel = [s.cam_from_world @ world_from_ref for _, s in sources]
    nvec = np.array([[0.0, 0.0, 1.0]])
    # running winner-take-all: best score, its plane index, and the scores of its two neighbouring planes
    best_s = np.full((H, W), -np.inf, np.float32)
    best = np.zeros((H, W), np.int32)
    s_lo = np.full((H, W), -1.0, np.float32)
    s_hi = np.full((H, W), -1.0, np.float32)
    prev = np.full((H, W), -1.0, np.float32)
    for i, inv_d in enumerate(inv_depths):
        top = [np.full((H, W), -1.0, np.float32) for _ in range(k)]  # running best-k, sorted high to low
        for j, (img, src) in enumerate(sources):
            R, t = rel[j][:3, :3], rel[j][:3, 3:4]
            Hm = src.intrinsics.K @ (R + t @ nvec * inv_d) @ Kr_inv
            warped = cv2.warpPerspective(img, Hm, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                         borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
            mu_s = cv2.boxFilter(warped, -1, win)
            var_s = cv2.boxFilter(warped * warped, -1, win) - mu_s * mu_s
            cov = cv2.boxFilter(warped * ref_img, -1, win) - mu_r * mu_s
            zncc = cov / np.sqrt(np.maximum(var_r * var_s, 1e-10))
            # outside the source image (border -1 inside the window) or textureless: no evidence
            zncc[(mu_s < -0.01) | (var_s < 1e-5)] = -1.0
            x = zncc
            for m in range(k):  # insertion into the sorted best-k
                hi = np.maximum(top[m], x)
                x = np.minimum(top[m], x)
                top[m] = hi
        score = sum(top) / k
        # the plane after the current winner gives its upper neighbour score
        after = best == i - 1
        s_hi[after] = score[after]
        win_now = score > best_s
        best_s[win_now] = score[win_now]
        best[win_now] = i
        s_lo[win_now] = prev[win_now]
        s_hi[win_now] = -1.0
        prev = score
    s0 = best_s
    denom = s_lo - 2 * s0 + s_hi
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where((denom < -1e-6) & (best > 0) & (best < cfg.n_depths - 1), 0.5 * (s_lo - s_hi) / denom, 0.0)
    off = np.clip(off, -0.5, 0.5)
    step = inv_depths[1] - inv_depths[0] if cfg.n_depths > 1 else 0.0
    inv = inv_depths[best] + off * step
    depth = (1.0 / inv).astype(np.float32)
    conf = np.clip(s0, 0, 1).astype(np.float32)
    # the extreme planes are not minima but limits of the search
    edge = (best == 0) | (best == cfg.n_depths - 1)
    conf[edge | (var_r < 1e-5)] = 0  # a textureless reference window has no evidence
    return depth, conf


def _nearest_pixel(uv: np.ndarray, z: np.ndarray, intr) -> np.ndarray:
    """(N, 2) integer pixel (column, row) nearest to each projection; -1 where behind or outside the image."""
    with np.errstate(invalid="ignore"):
        ij = np.round(np.nan_to_num(uv, nan=-1.0)).astype(np.int64)
        ok = (z > 0) & (ij[:, 0] >= 0) & (ij[:, 0] < intr.width) & (ij[:, 1] >= 0) & (ij[:, 1] < intr.height)
    ij[~ok] = -1
    return ij


def geometric_filter(results: dict[str, DepthResult], cfg: MVSConfig, stats: dict | None = None) -> dict[str, np.ndarray]:
    """Keep depths that at least ``min_consistent`` other views confirm (reprojection within ``reproj_px``
    and relative depth within ``rel_depth``); returns the per-view count of agreeing views. ``stats`` gets
    the mean forward-backward reprojection error (pixels) of the agreeing pairs."""
    counts = {}
    err_sum, err_n = 0.0, 0
    for name, r in results.items():
        d = r.depth
        valid = d > 0
        cnt = np.zeros(d.shape, np.int32)
        pts, uv = backproject_depth(np.where(valid, d, 0), r.view.intrinsics, r.view.cam_from_world, return_pixels=True)
        for sname in r.sources:
            s = results.get(sname)
            if s is None or not len(pts):
                continue
            # into the source: its depth at the nearest pixel ...
            intr = s.view.intrinsics
            uv_s, z = project(pts, intr, s.view.cam_from_world)
            ij = _nearest_pixel(uv_s, z, intr)
            ok = ij[:, 0] >= 0
            ds = np.zeros(len(pts), np.float32)
            ds[ok] = s.depth[ij[ok, 1], ij[ok, 0]]
            ok &= ds > 0
            # ... and back: that depth -> world -> reference pixel and depth
            pw = transform_points(invert_rigid(s.view.cam_from_world), intr.pixel_rays(ij[ok]) * ds[ok, None])
            uv_r, zr = project(pw, r.view.intrinsics, r.view.cam_from_world)
            err = np.linalg.norm(uv_r - uv[ok], axis=1)
            d_ref = d[valid][ok]
            good = (err < cfg.reproj_px) & (np.abs(zr - d_ref) / d_ref < cfg.rel_depth)
            agree = np.zeros(len(pts), bool)
            agree[np.flatnonzero(ok)] = good
            err_sum += float(err[good].sum())
            err_n += int(good.sum())
            cnt[valid] += agree
        counts[name] = cnt
    if stats is not None:
        stats["mean_reprojection_px"] = err_sum / err_n if err_n else float("nan")
    return counts


def _triangulated(dataset):
    """The dataset's model with sparse points triangulated from its images with the cameras held fixed
    (given poses come without points); the model unchanged, with a warning, when that fails."""
    import tempfile

    from ..triangulate import triangulate_given

    with tempfile.TemporaryDirectory(prefix="photorecon_tri_") as work:
        model = triangulate_given(dataset.layout.images, dataset.model, work)
    if len(model.points):
        log.info("mvs: %d sparse points triangulated with the given cameras", len(model.points))
    return model


def run_mvs(dataset, out_dir: str | Path | None = None, cfg: MVSConfig | None = None) -> dict:
    """MVS for every view of a ``Dataset``; writes depth maps (at working resolution: the camera's, or smaller
    with the same aspect ratio when the images exceed ``max_size``), confidences, normals and previews
    to ``out_dir`` (default: DATASET/depth). Returns a report dict. Raises ``NoDepthError`` if no view
    yields depth."""
    cfg = cfg or MVSConfig()
    model = dataset.model
    out = Path(out_dir) if out_dir else dataset.layout.depth
    out.mkdir(parents=True, exist_ok=True)
    grey: dict[str, np.ndarray] = {}
    work: dict[str, View] = {}

    def image(v: View):
        if v.name not in grey:
            wv = _working_view(v, cfg.max_size)
            g = _gray(dataset.image(v))
            if g.shape != (wv.intrinsics.height, wv.intrinsics.width):
                g = cv2.resize(g, wv.intrinsics.size, interpolation=cv2.INTER_AREA)
            grey[v.name], work[v.name] = g, wv
        return grey[v.name], work[v.name]

    results: dict[str, DepthResult] = {}
    skipped: dict[str, str] = {}
    t0 = time.perf_counter()
    triangulated = False
    if len(model.points) == 0 and cfg.triangulate:
        model = _triangulated(dataset)
        triangulated = len(model.points) > 0
    t_tri = time.perf_counter() - t0
    t0 = time.perf_counter()
    no_points = len(model.points) == 0
    if no_points:
        log.warning("mvs: the camera model has no sparse points; depth ranges are guessed from the cameras")
    plan: list[tuple[View, list[View], tuple[float, float]]] = []
    near, far = DEPTH_RANGE_FACTORS[cfg.method]
    near = near if cfg.depth_near is None else cfg.depth_near
    far = far if cfg.depth_far is None else cfg.depth_far
    for v in model.views:
        rng = camera_depth_range(model.views, v) if no_points else depth_range(model, v, near, far)
        if rng is None:
            skipped[v.name] = "no sparse points (or a degenerate depth range) in this view"
            log.warning("mvs: view %s skipped: %s", v.name, skipped[v.name])
            continue
        srcs = select_sources(model, v, cfg)
        if not srcs:
            skipped[v.name] = "no source view with enough shared points and baseline"
            log.warning("mvs: view %s skipped: %s", v.name, skipped[v.name])
            continue
        plan.append((v, srcs, rng))
    planned = {v.name for v, _, _ in plan}
    kept = []
    for v, srcs, rng in plan:  # PatchMatch's geometric term reads the sources' own depth maps
        srcs = [s for s in srcs if s.name in planned]
        if srcs:
            kept.append((v, srcs, rng))
        else:
            skipped[v.name] = "every source view of it was skipped"
            log.warning("mvs: view %s skipped: %s", v.name, skipped[v.name])
    plan = kept
    if cfg.method == "sweep":
        for v, srcs, rng in bar(plan, desc="mvs depth (sweep)"):
            ref_img, ref_w = image(v)
            src = [image(s) for s in srcs]
            depth, conf = plane_sweep(ref_img, ref_w, src, rng[0], rng[1], cfg)
            depth[conf < cfg.min_confidence] = 0
            results[v.name] = DepthResult(depth, conf, ref_w, [s.name for s in srcs])
    elif plan:
        from .patchmatch import PMJob, patchmatch_all

        views = {v.name: v for v in model.views}

        def level_image(name: str, lv: View) -> np.ndarray:
            g, _ = image(views[name])
            if g.shape != (lv.intrinsics.height, lv.intrinsics.width):
                g = cv2.resize(g, lv.intrinsics.size, interpolation=cv2.INTER_AREA)
            return g

        jobs = {v.name: PMJob(image(v)[1], [s.name for s in srcs], rng[0], rng[1], model.points_seen_by(v.name))
                for v, srcs, rng in plan}
        pm_out = patchmatch_all(list(jobs.values()), level_image, cfg)
        grey.clear()  # every view's image is no longer needed: memory for the filter
        while pm_out:
            name, (depth, normal, cost, wv, _) = pm_out.popitem()
            conf = np.clip(1.0 - cost, 0.0, 1.0).astype(np.float32)
            del cost
            depth[(conf < cfg.min_confidence) | ~np.isfinite(depth)] = 0
            results[name] = DepthResult(depth, conf, wv, jobs[name].sources, normal)
    for v, _, _ in plan:  # masked pixels (masks/NAME.png or the image's alpha) have no depth
        r = results.get(v.name)
        mask = dataset.mask(v) if r is not None else None
        if mask is not None:
            h, w = r.depth.shape
            if mask.shape != (h, w):
                mask = cv2.resize(mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
            r.depth[~mask] = 0
    t_depth = time.perf_counter() - t0
    if not results:
        raise NoDepthError("mvs: no view yielded depth (" + "; ".join(f"{k}: {m}" for k, m in list(skipped.items())[:5]) + ")")
    consistency: dict = {}
    if cfg.min_consistent > 0:
        counts = geometric_filter(results, cfg, consistency)
        before = sum(int((r.depth > 0).sum()) for r in results.values())
        for name, r in results.items():
            r.depth[counts[name] < cfg.min_consistent] = 0
        after = sum(int((r.depth > 0).sum()) for r in results.values())
        consistency["kept_fraction"] = after / before if before else 0.0
    written = 0
    stats = {}
    for v in model.views:
        r = results.get(v.name)
        if r is None:
            continue
        d, c = r.depth, np.where(r.depth > 0, r.confidence, 0).astype(np.float32)
        if not np.count_nonzero(d):
            log.warning("mvs: view %s: no depth survived filtering", v.name)
            skipped[v.name] = "no depth survived filtering"
            continue
        write_depth(out, v.name, d, c)
        if r.normal is not None:
            with atomic_path(out / f"{v.name}.normal.npy") as tmp:
                np.save(tmp, np.where(d[..., None] > 0, r.normal, 0).astype(np.float16))
        stats[v.name] = {"valid_fraction": float((d > 0).mean()), "sources": r.sources,
                         "size": [int(d.shape[1]), int(d.shape[0])]}
        written += 1
    if not written:
        raise NoDepthError("mvs: no depth survived filtering in any view")
    report = {"views": written, "skipped": skipped, "method": cfg.method, "depth_seconds": t_depth,
              "sparse_points": int(len(model.points)), "triangulated": triangulated,
              "triangulation_seconds": t_tri, "consistency": consistency,
              "seconds_per_view": t_depth / max(len(results), 1), "per_view": stats}
    atomic_write_json(out / "mvs_report.json", report)
    return report
