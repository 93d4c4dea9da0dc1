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
4. **Filtering**: confidence threshold (and, optionally, textureless reference windows), then geometric
   consistency: each depth is re-projected into the depth maps of its source views and of the next best ranked
   views (``filter_sources`` in all: a surface hidden from some sources is confirmed by the views that see it)
   and back; it is kept when at least ``min_consistent`` views (at most as many as it is checked against) agree within
   ``reproj_px`` pixels and ``rel_depth`` relative depth, or (PatchMatch's normals) on the surface: the two
   points within ``reproj_px`` pixel footprints of each other's tangent plane, up to ``plane_reproj_px`` pixels
   apart (``consistency_count``; surfaces seen at grazing angles). A depth that k views confirm gets at least
   confidence 1 - 1/k (``consistency_confidence``), its weight in TSDF fusion. A view checked against one other
   view (a stereo pair) gets a left-right check instead: within ``pair_reproj_px`` pixels, no plane test.

Outputs, in the synth layout: ``depth/NAME.npy`` (float32 z-depth, 0 = none), ``depth/NAME.conf.npy``
(float32 confidence in [0, 1]) and ``depth/NAME.png`` (preview).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Literal

import cv2
import numpy as np

from ..cameras import View
from ..errors import NoDepthError
from ..io.atomic import atomic_path, atomic_write_json
from ..io.images import write_depth
from ..results import Result
from ..tasks import IN_PROCESS, Executor, Task
from .filter import (PLANE_MAX_ANGLE_DEG, _consistency_count_any, _consistency_count_pinhole, _filter_config,
                     _filter_plan, _nearest_pixel, consistency_count, geometric_filter)
from .select import DEPTH_RANGE_FACTORS, camera_depth_range, depth_range, select_sources
from .sweep import plane_sweep
from ..fields import check_config, expect_config
from .views import choose_depth_views

log = logging.getLogger("photorecon")


@dataclass
class MVSConfig:
    """Settings of the multi-view stereo stage (``photorecon mvs``)."""

    method: Literal["patchmatch", "sweep"] = field(default="patchmatch", metadata={"flag": "--mvs", "help": "patchmatch: per-pixel depth and normal (ACMH/ACMM); sweep: fronto-parallel plane sweep (a fast preview)"})
    n_sources: int = field(default=8, metadata={"help": "source views matched per reference view", "range": (1, 256)})
    max_size: int = field(default=1600, metadata={"help": "working resolution: longest image side in pixels (0 = full resolution)", "range": (64, 65536), "also": (0,)})
    min_confidence: float = field(default=0.2, metadata={"help": "drop depths whose confidence (1 - matching cost, 0..1) is below this before the geometric filter (0 = the filter alone decides)", "range": (0.0, 1.0)})
    min_texture: float = field(default=0.0, metadata={"help": "patchmatch: no depth where the window's grey standard deviation (grey 0..1) is below this (0 = off)", "range": (0.0, 1.0)})
    texture_rel: float = field(default=0.0, metadata={"help": "patchmatch: no depth where the window's grey std. deviation is below this fraction of the image's median (0 = off)", "range": (0.0, 100.0)})
    textured_min_confidence: float = field(default=0.0, metadata={"help": "with --texture-rel: the confidence threshold (in place of --min-confidence) of the pixels it keeps", "range": (0.0, 1.0)})
    min_consistent: int = field(default=2, metadata={"help": "geometric filter: other views that must agree with a depth, at most the views checked (0 = off)", "range": (0, 256)})
    pair_reproj_px: float = field(default=1.0, metadata={"help": "geometric filter of a view checked against one other view (a stereo pair): left-right check, max forward-backward reprojection error, pixels (0 = as --reproj-px)", "range": (0.0, 1000.0)})
    filter_sources: int = field(default=16, metadata={"help": "geometric filter: views each depth is checked against (the matching sources, then the next best ranked; 0 = the matching sources only)", "range": (0, 256)})
    consistency_confidence: bool = field(default=True, metadata={"help": "geometric filter: a depth that k views confirm gets at least confidence 1 - 1/k (its fusion weight)"})
    reproj_px: float = field(default=2.0, metadata={"help": "geometric filter: max reprojection error, pixels", "range": (0.0, 1000.0), "exclusive_min": True})
    rel_depth: float = field(default=0.01, metadata={"help": "geometric filter: max relative depth difference (fraction of the depth)", "range": (0.0, 1.0), "exclusive_min": True})
    plane_reproj_px: float = field(default=10.0, metadata={"help": "geometric filter: a view also confirms a depth within this many pixels when planes and normals agree (0 = off)", "range": (0.0, 1000.0)})
    depth_near: float | None = field(default=None, metadata={"help": "depth range: the sparse points' 1st percentile times this (default: 0.6 for patchmatch, 1/1.1 for the sweep)", "range": (0.0, 100.0), "exclusive_min": True})
    depth_far: float | None = field(default=None, metadata={"help": "depth range: the sparse points' 99th percentile times this (default: 1.25 for patchmatch, 1.1 for the sweep)", "range": (0.0, 1000.0), "exclusive_min": True})
    min_angle_deg: float = field(default=2.0, metadata={"help": "view selection: minimum triangulation angle, degrees", "range": (0.0, 90.0)})
    pm_levels: int = field(default=3, metadata={"help": "patchmatch: pyramid levels (each halves the image)", "range": (1, 8)})
    pm_iterations: int = field(default=5, metadata={"help": "patchmatch: iterations at the coarsest level", "range": (1, 100)})
    pm_fine_iterations: int = field(default=1, metadata={"help": "patchmatch: iterations at each finer level", "range": (0, 100)})
    pm_final_iterations: int = field(default=1, metadata={"help": "patchmatch: extra geometric-consistency iterations (0 = none)", "range": (0, 100)})
    pm_final_level: int = field(default=0, metadata={"help": "patchmatch: pyramid level of the extra geometric-consistency round (0 = full resolution; 1 = half: faster)", "range": (0, 7)})
    pm_skip_consistent: int = field(default=2, metadata={"help": "patchmatch: the extra geometric round skips pixels that this many sources confirm within 1 pixel (0 = off)", "range": (0, 256)})
    pm_radius: int = field(default=5, metadata={"help": "patchmatch: NCC window radius, pixels (with --pm-stride 2, radius 5 = 6x6 samples over 11x11 pixels)", "range": (1, 32)})
    pm_stride: int = field(default=2, metadata={"help": "patchmatch: the NCC window is sampled every this many pixels", "range": (1, 16)})
    pm_sparse_min_size: int = field(default=1024, metadata={"help": "patchmatch: levels with a long side of at least this many pixels sample the window as a checkerboard (0 = off)", "range": (0, 65536)})
    pm_sigma_color: float = field(default=0.1, metadata={"help": "patchmatch: grey-level sigma of the bilateral NCC weight (grey 0..1)", "range": (0.0, 10.0), "exclusive_min": True})
    pm_fine_sources: int = field(default=0, metadata={"help": "patchmatch: after the coarsest level, match only the best this many source views (0 = all)", "range": (0, 256)})
    pm_fine_refine: int = field(default=2, metadata={"help": "patchmatch: refinement hypotheses per pixel after the coarsest level (2, 3 or 6: also random ones)", "range": (0, 6)})
    pm_reuse_cost: bool = field(default=True, metadata={"help": "patchmatch: finer levels start from the coarser level's costs (upsampled) instead of recomputing them"})
    pm_same_depth: float = field(default=1e-3, metadata={"help": "patchmatch: candidates this close in relative depth (and --pm-same-normal-deg in normal) share one cost evaluation", "range": (0.0, 1.0)})
    pm_same_normal_deg: float = field(default=1.5, metadata={"help": "patchmatch: normal tolerance of --pm-same-depth, degrees", "range": (0.0, 90.0)})
    geom_consistency: bool = field(default=True, metadata={"help": "patchmatch: geometric-consistency term between views (ACMM)"})
    geom_weight: float = field(default=0.2, metadata={"help": "patchmatch: weight of the geometric term (per pixel of reprojection error)", "range": (0.0, 100.0)})
    planar_prior: bool = field(default=False, metadata={"help": "patchmatch: planar prior (ACMP): planes through confident pixels tried where the depth is not confident"})
    triangulate: bool = field(default=True, metadata={"help": "cameras without sparse points: triangulate SIFT matches with the cameras held fixed (view selection, depth ranges)"})
    pm_seed: int = field(default=0, metadata={"help": "patchmatch: random seed (results are deterministic for a seed)", "range": (0, 2**31 - 1)})
    n_depths: int = field(default=128, metadata={"help": "sweep: depth hypotheses (planes, uniform in inverse depth)", "range": (2, 16384)})
    window: int = field(default=7, metadata={"help": "sweep: ZNCC window size in pixels (odd)", "range": (1, 63), "odd": True})
    best_k: int = field(default=2, metadata={"help": "sweep: aggregate the best k source scores per pixel", "range": (1, 256)})
    depth_views: Literal["auto", "all"] = field(default="auto", metadata={"help": "views that get a depth map: auto = enough views to see every sparse point well from --depth-view-coverage directions (a redundant capture computes fewer depth maps; a small one keeps all); all = every view"})
    depth_view_coverage: int = field(default=3, metadata={"help": "--depth-views auto: chosen views that must see each sparse point (at a good angle and resolution)", "range": (1, 64)})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.fields)


# Named settings for a caller that needs other values than the defaults (which are for 1600-px photos):
# "fast" is PatchMatch for small images and previews (the demo): 4 sources, 2 pyramid levels, fewer iterations.
MVS_PRESETS: dict[str, dict] = {
    "fast": dict(n_sources=4, pm_levels=2, pm_iterations=4, pm_fine_iterations=1, pm_final_iterations=1,
                 min_consistent=1, min_confidence=0.2, filter_sources=0),  # one view confirms: keep the cost threshold
}


# PatchMatch on a view matched against one other view only (a stereo pair), where no third view outvotes a window
# that straddles a depth edge: smaller, denser and sharper windows, unless set otherwise (synthetic rectified
# pairs at 640x480, knot / room, depth within 1% on the co-visible pixels: 0.88 / 0.90 -> 0.94 / 0.95)
PAIR_SETTINGS = {"pm_radius": 3, "pm_stride": 1, "pm_sigma_color": 0.05}


def _pair_config(cfg: MVSConfig, plan: dict) -> MVSConfig:
    """``cfg`` with ``PAIR_SETTINGS`` in place of the defaults when every view of the ``plan`` has one source."""
    if cfg.method != "patchmatch" or not plan or any(len(p[1]) != 1 for p in plan.values()):
        return cfg
    defaults = MVSConfig()
    changes = {k: v for k, v in PAIR_SETTINGS.items() if getattr(cfg, k) == getattr(defaults, k)}
    if changes:
        log.info("mvs: every view has one source view (a stereo pair): %s",
                 ", ".join(f"{k} {v}" for k, v in changes.items()))
    return dataclasses.replace(cfg, **changes)


@dataclass
class DepthResult:
    depth: np.ndarray  # (h, w) float32 at working resolution
    confidence: np.ndarray | None  # (h, w) float32 in [0, 1]; None for a filter's source view (not read)
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


def _restricted(model, names: list[str]):
    """``model`` with only the views ``names`` (their observations with them; the points unchanged): the views
    that get depth maps, which match one another."""
    if len(names) == len(model.views):
        return model
    keep = set(names)
    return dataclasses.replace(model, views=[v for v in model.views if v.name in keep],
                               observations={k: o for k, o in model.observations.items() if k in keep})


def _triangulated(dataset):
    """The dataset's model with sparse points triangulated from its images with the cameras held fixed
    (given poses come without points); the model unchanged, with a warning, when that fails."""
    import tempfile

    from ..poses.triangulate import triangulate_given

    with tempfile.TemporaryDirectory(prefix="photorecon_tri_") as work:
        model = triangulate_given(dataset.layout.images, dataset.model, work)
    if len(model.points):
        log.info("mvs: %d sparse points triangulated with the given cameras", len(model.points))
    return model


# --- the depth stage as a task graph (in-process by default, or on a Dask cluster: photorecon.distributed) ---
@dataclass
class _MVSContext:
    """What every MVS task needs (sent once to each worker): the dataset, the settings, the plan (view name ->
    (working-resolution view, source names, depth range, seed points)) and the folders. Arrays between tasks
    go through ``work`` (each file written atomically), results to ``out``."""

    dataset: object
    cfg: MVSConfig
    plan: dict[str, tuple[View, list[str], tuple[float, float], np.ndarray]]
    work: Path
    out: Path
    filter_sources: dict[str, list[str]] = field(default_factory=dict)  # view -> the views its filter checks


def _filter_sources(ctx: _MVSContext, name: str) -> list[str]:
    """The views the consistency filter checks ``name`` against (its matching sources without a longer list)."""
    return ctx.filter_sources.get(name) or ctx.plan[name][1]


def _dataset_view(ctx: _MVSContext, name: str) -> View:
    return next(v for v in ctx.dataset.views if v.name == name)


_CACHE_SIZE = 12  # images (and masks) per process: a view's sources and itself, with room to spare


_GREY_CACHE: dict[tuple, np.ndarray] = {}  # per process: the last few working-resolution grey images


_MASK_CACHE: dict[tuple, np.ndarray | None] = {}  # per process: the last few views' masks at working resolution


def _cached(cache: dict, key: tuple, make: Callable[[], object]):
    """``cache[key]``, made by ``make()`` on a miss; the oldest entry goes when the cache holds ``_CACHE_SIZE``."""
    if key not in cache:
        value = make()
        while len(cache) >= _CACHE_SIZE:
            cache.pop(next(iter(cache)))
        cache[key] = value
    return cache[key]


def _plan_view(ctx: _MVSContext, name: str) -> View:
    """View ``name`` at its working resolution (the plan's, else from ``max_size``)."""
    return ctx.plan[name][0] if name in ctx.plan else _working_view(_dataset_view(ctx, name), ctx.cfg.max_size)


def _working_grey(ctx: _MVSContext, name: str) -> np.ndarray:
    """View ``name``'s grey image (float32 0..1) at its working resolution, from a small per-process cache."""
    v = _dataset_view(ctx, name)
    wv = _plan_view(ctx, name)
    path = ctx.dataset.image_path(v)
    try:
        key = (str(path), path.stat().st_mtime_ns, wv.intrinsics.size)
    except OSError:
        key = (str(path), None, wv.intrinsics.size)

    def make():
        g = _gray(ctx.dataset.image(v))
        if g.shape != (wv.intrinsics.height, wv.intrinsics.width):
            g = cv2.resize(g, wv.intrinsics.size, interpolation=cv2.INTER_AREA)
        return g

    return _cached(_GREY_CACHE, key, make)


def _level_mask(ctx: _MVSContext, name: str, lv: View) -> np.ndarray | None:
    """View ``name``'s mask (True = foreground) at ``lv``'s resolution, or None without one: PatchMatch computes
    only these pixels. A pixel of a coarser level is foreground when any of its working-resolution pixels is."""
    v = _dataset_view(ctx, name)
    wv = _plan_view(ctx, name)

    def make():
        m = ctx.dataset.mask(v)
        if m is not None and m.shape != (wv.intrinsics.height, wv.intrinsics.width):
            m = cv2.resize(m.astype(np.uint8), wv.intrinsics.size, interpolation=cv2.INTER_NEAREST) > 0
        return m

    m = _cached(_MASK_CACHE, (str(ctx.dataset.image_path(v)), str(ctx.dataset.mask_path(v)), wv.intrinsics.size), make)
    if m is None or m.shape == (lv.intrinsics.height, lv.intrinsics.width):
        return m
    return cv2.resize(m.astype(np.float32), lv.intrinsics.size, interpolation=cv2.INTER_AREA) > 0


def _level_image(ctx: _MVSContext, name: str, lv: View) -> np.ndarray:
    g = _working_grey(ctx, name)
    if g.shape != (lv.intrinsics.height, lv.intrinsics.width):
        g = cv2.resize(g, lv.intrinsics.size, interpolation=cv2.INTER_AREA)
    return g


def _save(path: Path, array: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        np.save(tmp, array)


def _load(path: Path) -> np.ndarray:
    try:
        return np.load(path)
    except (OSError, ValueError) as exc:
        raise NoDepthError(f"mvs: intermediate file {path} is missing or unreadable ({exc.__class__.__name__}); "
                           "was the work folder removed while the run went on?") from None


def _raw_path(ctx: _MVSContext, name: str, what: str) -> Path:
    return ctx.work / "raw" / f"{name}.{what}.npy"


def _finish_depth(ctx: _MVSContext, name: str, depth: np.ndarray, conf: np.ndarray, normal: np.ndarray | None) -> None:
    """A view's unfiltered result: low-confidence, non-finite and masked pixels to 0; to ``work/raw`` (depth last:
    the file that says the view is done)."""
    cfg = ctx.cfg
    mask = _level_mask(ctx, name, _plan_view(ctx, name))  # masks/NAME.png or the image's alpha: no depth there
    h, w = depth.shape
    if mask is not None and mask.shape != (h, w):
        mask = cv2.resize(mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    min_conf = cfg.min_confidence
    if normal is not None and not cfg.planar_prior and (cfg.min_texture > 0 or cfg.texture_rel > 0):
        from .planar import relative_texture, textureless  # PatchMatch: no evidence where the window is flat

        grey = _working_grey(ctx, name)  # the last round's depth is at the working resolution
        if cfg.min_texture > 0:
            depth[textureless(grey, cfg.pm_radius, cfg.min_texture)] = 0
        if cfg.texture_rel > 0:
            depth[relative_texture(grey, cfg.pm_radius, mask) < cfg.texture_rel] = 0
            min_conf = cfg.textured_min_confidence
    depth[(conf < min_conf) | ~np.isfinite(depth)] = 0
    if mask is not None:
        depth[~mask] = 0
    _save(_raw_path(ctx, name, "conf"), conf.astype(np.float32))
    if normal is not None:
        _save(_raw_path(ctx, name, "normal"), normal.astype(np.float16))
    _save(_raw_path(ctx, name, "depth"), depth.astype(np.float32))


def _raw_result(ctx: _MVSContext, name: str, normal: bool = False, confidence: bool = True) -> DepthResult:
    """View ``name``'s unfiltered result from ``work/raw``; ``confidence=False`` for a source of the filter, which
    reads only its depth (and normals)."""
    n_path = _raw_path(ctx, name, "normal")
    return DepthResult(_load(_raw_path(ctx, name, "depth")), _load(_raw_path(ctx, name, "conf")) if confidence else None,
                       ctx.plan[name][0], ctx.plan[name][1], _load(n_path) if normal and n_path.is_file() else None)


def _pm_jobs(ctx: _MVSContext) -> dict:
    from .patchmatch import PMJob

    return {n: PMJob(wv, srcs, rng[0], rng[1], seeds) for n, (wv, srcs, rng, seeds) in ctx.plan.items()}


def _mvs_task(ctx: _MVSContext, kind: str, name: str, r: int = 0) -> dict:
    """One task: ``"sweep"`` (a view's plane sweep), ``"pm"`` (round ``r`` of a view's PatchMatch) or
    ``"filter"`` (a view's geometric consistency against its sources, then its files in ``out``). A task whose
    output is already in ``work`` (a retry, a resumed run) returns at once."""
    cfg = ctx.cfg
    t0 = time.perf_counter()
    if kind == "sweep":
        if _raw_path(ctx, name, "depth").is_file():
            return {"seconds": 0.0, "reused": True}
        ref_w, srcs, rng, _ = ctx.plan[name]
        src = [(_working_grey(ctx, s), ctx.plan[s][0]) for s in srcs]
        depth, conf = plane_sweep(_working_grey(ctx, name), ref_w, src, rng[0], rng[1], cfg)
        _finish_depth(ctx, name, depth, conf, None)
        return {"seconds": time.perf_counter() - t0}
    if kind == "pm":
        from .patchmatch import PatchMatchParams, pm_rounds, pm_view_round

        last = r == len(pm_rounds(cfg)) - 1
        done = _raw_path(ctx, name, "depth") if last else ctx.work / f"r{r}" / f"{name}.depth.npy"
        if done.is_file():
            return {"seconds": 0.0, "reused": True}
        jobs = _pm_jobs(ctx)

        def load(n: str, rr: int, what: str) -> np.ndarray:
            return _load(ctx.work / f"r{rr}" / f"{n}.{what}.npy")

        depth, normal, cost, _ = pm_view_round(jobs[name], r, jobs, lambda n, lv: _level_image(ctx, n, lv),
                                               PatchMatchParams(cfg), load, lambda n, lv: _level_mask(ctx, n, lv))
        seconds = time.perf_counter() - t0
        if last:
            _finish_depth(ctx, name, depth, np.clip(1.0 - cost, 0.0, 1.0).astype(np.float32), normal)
        else:
            _save(ctx.work / f"r{r}" / f"{name}.normal.npy", normal)
            _save(ctx.work / f"r{r}" / f"{name}.cost.npy", cost)
            _save(done, depth)
        return {"seconds": seconds}
    if kind == "filter":
        res = _raw_result(ctx, name, normal=True)
        before = int((res.depth > 0).sum())
        err_sum, err_n = 0.0, 0
        if cfg.min_consistent > 0:
            checked = dataclasses.replace(res, sources=_filter_sources(ctx, name))
            sources = {s: _raw_result(ctx, s, normal=cfg.plane_reproj_px > 0, confidence=False) for s in checked.sources}
            cnt, err_sum, err_n = consistency_count(checked, sources, _filter_config(cfg, len(sources)))
            res.depth[cnt < min(cfg.min_consistent, len(sources))] = 0  # no more confirming views than there are
            if cfg.consistency_confidence:  # k views agree: confidence at least 1 - 1/k
                res.confidence = np.maximum(res.confidence, 1.0 - 1.0 / np.maximum(cnt, 1)).astype(np.float32)
        d = res.depth
        info = {"before": before, "after": int((d > 0).sum()), "err_sum": err_sum, "err_n": err_n,
                "seconds": time.perf_counter() - t0}
        if not np.count_nonzero(d):
            return {**info, "written": False}
        write_depth(ctx.out, name, d, np.where(d > 0, res.confidence, 0).astype(np.float32))
        if res.normal is not None:
            _save(ctx.out / f"{name}.normal.npy", np.where(d[..., None] > 0, res.normal, 0).astype(np.float16))
        return {**info, "written": True, "valid_fraction": float((d > 0).mean()), "sources": res.sources,
                "size": [int(d.shape[1]), int(d.shape[0])]}
    raise ValueError(f"mvs task: unknown kind {kind!r}")


def mvs_tasks(ctx: _MVSContext) -> list[Task]:
    """The depth stage's task graph: per view its plane sweep, or its PatchMatch rounds (round r of a view after
    round r - 1 of itself and, with the geometric term, of its sources), then its consistency filter (after its
    own and its sources' last round)."""
    cfg = ctx.cfg
    names = list(ctx.plan)
    tasks: list[Task] = []
    if cfg.method == "sweep":
        last = {n: f"sweep:{n}" for n in names}
        tasks += [Task(last[n], ("sweep", n)) for n in names]
    else:
        from .patchmatch import pm_rounds, round_dependencies

        jobs = _pm_jobs(ctx)
        n_rounds = len(pm_rounds(cfg))
        for r in range(n_rounds):
            tasks += [Task(f"pm{r}:{n}", ("pm", n, r), tuple(f"pm{r - 1}:{d}" for d in round_dependencies(jobs[n], r, jobs, cfg)))
                      for n in names]
        last = {n: f"pm{n_rounds - 1}:{n}" for n in names}
    for n in names:
        deps = [last[n]] + ([last[s] for s in _filter_sources(ctx, n) if s in last] if cfg.min_consistent > 0 else [])
        tasks.append(Task(f"filter:{n}", ("filter", n), tuple(dict.fromkeys(deps))))
    return tasks


def _work_key(dataset, cfg: MVSConfig, plan: dict) -> str:
    """A hash of the settings, the plan and the images (names, sizes, times): a resumed run reuses the work of
    an interrupted one only when all of them are the same."""
    rows = []
    for name, (wv, srcs, rng, seeds) in sorted(plan.items()):
        p = Path(dataset.image_path(next(v for v in dataset.views if v.name == name)))
        st = p.stat() if p.is_file() else None
        rows.append([name, srcs, list(rng), wv.intrinsics.size, np.asarray(wv.cam_from_world).round(12).tolist(),
                     len(seeds), st and st.st_size, st and st.st_mtime_ns])
    blob = json.dumps({"cfg": asdict(cfg), "plan": rows, "masks": str(dataset.masks_dir)}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


@dataclass
class MVSResult(Result):
    """What ``run_mvs`` did (also written to OUT_DIR/mvs_report.json)."""

    views: int  # views with a depth map written
    skipped: dict  # view name -> one-line reason
    method: str  # "patchmatch" or "sweep"
    depth_seconds: float  # the depth tasks' own time, summed over workers
    wall_seconds: float  # the whole run, filter included
    graph_seconds: float  # the task graph alone
    workers: int
    sparse_points: int
    triangulated: bool  # sparse points triangulated from SIFT matches with the given cameras
    triangulation_seconds: float
    consistency: dict  # the geometric consistency filter's statistics
    seconds_per_view: float
    per_view: dict  # view name -> valid_fraction, sources, size
    reused_tasks: int  # tasks whose output an interrupted run had left
    task_seconds: dict  # task key -> seconds
    depth_views: dict  # chosen, of, reason, uncovered_points (--depth-views)


def run_mvs(dataset, out_dir: str | Path | None = None, cfg: MVSConfig | None = None, executor: Executor | None = None,
            work_dir: str | Path | None = None) -> MVSResult:
    """MVS for every view of a ``Dataset``; writes depth maps (at working resolution: the camera's, or smaller
    with the same aspect ratio when the images exceed ``max_size``), confidences, normals and previews
    to ``out_dir`` (default: DATASET/depth). Returns a report dict. Raises ``NoDepthError`` if no view
    yields depth.

    The work is a task graph (``mvs_tasks``) run by ``executor`` (default: in this process, one task after the
    other; ``photorecon.distributed`` runs it on a Dask cluster). Intermediate maps go to ``work_dir`` (default
    OUT_DIR/.mvs_work), in a sub-folder named after a hash of the settings and inputs: an interrupted run's
    finished tasks are reused by the next run with the same settings; the sub-folder is removed on success."""
    import shutil

    cfg = expect_config(cfg, MVSConfig, "cfg")
    ex = executor or IN_PROCESS
    model = dataset.model
    out = Path(out_dir) if out_dir else dataset.layout.depth
    out.mkdir(parents=True, exist_ok=True)
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
    choice = choose_depth_views(model, cfg)
    if len(choice.chosen) < len(model.views):
        log.info("mvs: depth maps for %d of %d views (--depth-views auto: each sparse point seen well by %d of "
                 "them)", len(choice.chosen), len(model.views), cfg.depth_view_coverage)
    model = _restricted(model, choice.chosen)
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
    views: dict[str, tuple] = {}
    for v, srcs, rng in plan:  # PatchMatch's geometric term reads the sources' own depth maps
        srcs = [s for s in srcs if s.name in planned]
        if srcs:
            views[v.name] = (_working_view(v, cfg.max_size), [s.name for s in srcs], rng,
                             model.points_seen_by(v.name) if cfg.method == "patchmatch" else np.zeros((0, 3)))
        else:
            skipped[v.name] = "every source view of it was skipped"
            log.warning("mvs: view %s skipped: %s", v.name, skipped[v.name])
    if not views:
        raise NoDepthError("mvs: no view yielded depth (" + "; ".join(f"{k}: {m}" for k, m in list(skipped.items())[:5]) + ")")
    cfg = _pair_config(cfg, views)
    work = Path(work_dir) if work_dir else out / ".mvs_work"
    ctx = _MVSContext(dataset, cfg, views, work / _work_key(dataset, cfg, views), out,
                      _filter_plan(model, views, cfg))
    t_graph = time.perf_counter()
    # the bar counts tasks (each view's PatchMatch rounds, then its filter), not views
    results = ex.run(_mvs_task, mvs_tasks(ctx), ctx, desc=f"mvs depth ({cfg.method}, {len(views)} views)", unit="task")
    t_graph = time.perf_counter() - t_graph
    _GREY_CACHE.clear()
    _MASK_CACHE.clear()
    t_all = time.perf_counter() - t0
    task_seconds = sum(r["seconds"] for k, r in results.items() if not k.startswith("filter:"))
    consistency: dict = {}
    filtered = {k.partition(":")[2]: r for k, r in results.items() if k.startswith("filter:")}
    if cfg.min_consistent > 0:
        err_n = sum(r["err_n"] for r in filtered.values())
        consistency["mean_reprojection_px"] = sum(r["err_sum"] for r in filtered.values()) / err_n if err_n else float("nan")
        before = sum(r["before"] for r in filtered.values())
        consistency["kept_fraction"] = sum(r["after"] for r in filtered.values()) / before if before else 0.0
    stats = {}
    for v in model.views:
        r = filtered.get(v.name)
        if r is None:
            continue
        if not r["written"]:
            log.warning("mvs: view %s: no depth survived filtering", v.name)
            skipped[v.name] = "no depth survived filtering"
            continue
        stats[v.name] = {k: r[k] for k in ("valid_fraction", "sources", "size")}
    if not stats:
        raise NoDepthError("mvs: no depth survived filtering in any view")
    shutil.rmtree(ctx.work, ignore_errors=True)
    try:
        work.rmdir()  # only when no other run's work is left in it
    except OSError:
        pass
    # depth_seconds: the depth tasks' own time (summed over workers); wall_seconds: the whole graph, filter included
    report = MVSResult(views=len(stats), skipped=skipped, method=cfg.method, depth_seconds=task_seconds,
                       wall_seconds=t_all, graph_seconds=t_graph, workers=ex.workers,
                       sparse_points=int(len(model.points)), triangulated=triangulated, triangulation_seconds=t_tri,
                       consistency=consistency, seconds_per_view=task_seconds / max(len(views), 1), per_view=stats,
                       reused_tasks=sum(1 for r in results.values() if r.get("reused")),
                       task_seconds={k: round(r["seconds"], 4) for k, r in results.items()},
                       depth_views=choice.to_dict())
    atomic_write_json(out / "mvs_report.json", report.to_dict())
    return report
