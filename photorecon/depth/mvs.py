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
5. **Gap filling** (``fill_gaps``, PatchMatch; auto: on for a stereo pair): the small gaps the filter leaves
   (up to ``fill_max_gap`` pixels) take a confirmed neighbour's plane where the same consistency test and the
   images accept it (``fill.fill_holes``).

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
from typing import Callable

import cv2
import numpy as np

from ..cameras import View
from ..errors import NoDepthError
from ..io.atomic import atomic_path, atomic_write_json
from ..io.images import write_depth
from ..results import Result
from ..tasks import IN_PROCESS, Executor, Task
from .config import MVS_PRESETS, PAIR_SETTINGS, DepthResult, MVSConfig  # noqa: F401 (re-exported)
from .fill import fill_holes, fill_on
from .filter import (PLANE_MAX_ANGLE_DEG, _consistency_count_any, _consistency_count_pinhole, _filter_config,
                     _filter_plan, _nearest_pixel, consistency_count, geometric_filter)
from .select import DEPTH_RANGE_FACTORS, camera_depth_range, depth_range, select_sources
from .sweep import plane_sweep
from ..fields import check_config, expect_config
from .views import ViewChoice, choose_depth_views, coarse_depth_views, wants_coarse_cover

log = logging.getLogger("photorecon")


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


def _mask_at(ctx: _MVSContext, name: str, shape: tuple[int, int]) -> np.ndarray | None:
    """View ``name``'s mask (True = foreground) at ``shape`` (h, w), or None without one."""
    mask = _level_mask(ctx, name, _plan_view(ctx, name))
    if mask is not None and mask.shape != tuple(shape):
        mask = cv2.resize(mask.astype(np.uint8), tuple(shape)[::-1], interpolation=cv2.INTER_NEAREST) > 0
    return mask


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
    mask = _mask_at(ctx, name, depth.shape)  # masks/NAME.png or the image's alpha: no depth there
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
    from .methods.patchmatch.solver import PMJob

    return {n: PMJob(wv, srcs, rng[0], rng[1], seeds) for n, (wv, srcs, rng, seeds) in ctx.plan.items()}


def _mvs_task(ctx: _MVSContext, kind: str, name: str, r: int = 0) -> dict:
    """One task: ``"sweep"`` (a view's plane sweep), ``"pm"`` (round ``r`` of a view's PatchMatch) or
    ``"filter"`` (a view's geometric consistency against its sources, then its files in ``out``). A task whose
    output is already in ``work`` (a retry, a resumed run) returns at once."""
    cfg = ctx.cfg
    t0, c0 = time.perf_counter(), time.process_time()  # CPU: all threads of this process (the kernels' too)
    if kind == "sweep":
        if _raw_path(ctx, name, "depth").is_file():
            return {"seconds": 0.0, "reused": True}
        ref_w, srcs, rng, _ = ctx.plan[name]
        src = [(_working_grey(ctx, s), ctx.plan[s][0]) for s in srcs]
        depth, conf = plane_sweep(_working_grey(ctx, name), ref_w, src, rng[0], rng[1], cfg)
        _finish_depth(ctx, name, depth, conf, None)
        return {"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0}
    if kind == "pm":
        from .methods.patchmatch.solver import PatchMatchParams, pm_rounds, pm_view_round

        last = r == len(pm_rounds(cfg)) - 1
        done = _raw_path(ctx, name, "depth") if last else ctx.work / f"r{r}" / f"{name}.depth.npy"
        if done.is_file():
            return {"seconds": 0.0, "reused": True}
        jobs = _pm_jobs(ctx)

        def load(n: str, rr: int, what: str) -> np.ndarray:
            return _load(ctx.work / f"r{rr}" / f"{n}.{what}.npy")

        depth, normal, cost, _, views = pm_view_round(jobs[name], r, jobs, lambda n, lv: _level_image(ctx, n, lv),
                                                      PatchMatchParams(cfg), load, lambda n, lv: _level_mask(ctx, n, lv))
        seconds = time.perf_counter() - t0
        if last:
            _finish_depth(ctx, name, depth, np.clip(1.0 - cost, 0.0, 1.0).astype(np.float32), normal)
        else:
            _save(ctx.work / f"r{r}" / f"{name}.normal.npy", normal)
            _save(ctx.work / f"r{r}" / f"{name}.cost.npy", cost)
            if views is not None:
                _save(ctx.work / f"r{r}" / f"{name}.views.npy", views)
            _save(done, depth)
        return {"seconds": seconds, "cpu_seconds": time.process_time() - c0}
    if kind == "filter":
        res = _raw_result(ctx, name, normal=True)
        before = int((res.depth > 0).sum())
        err_sum, err_n, filled, settled = 0.0, 0, 0, 0
        if cfg.min_consistent > 0:
            checked = dataclasses.replace(res, sources=_filter_sources(ctx, name))
            sources = {s: _raw_result(ctx, s, normal=cfg.plane_reproj_px > 0, confidence=False) for s in checked.sources}
            cnt, err_sum, err_n = consistency_count(checked, sources, _filter_config(cfg, len(sources)))
            res.depth[cnt < min(cfg.min_consistent, len(sources))] = 0  # no more confirming views than there are
            if cfg.consistency_confidence:  # k views agree: confidence at least 1 - 1/k
                res.confidence = np.maximum(res.confidence, 1.0 - 1.0 / np.maximum(cnt, 1)).astype(np.float32)
            if res.normal is not None and fill_on(cfg, len(sources)):  # PatchMatch: gaps filled with confirmed planes
                images = {s: (_working_grey(ctx, s), ctx.plan[s][0]) for s in ctx.plan[name][1]}
                _, fill_stats = fill_holes(dataclasses.replace(res, sources=checked.sources), sources,
                                           _filter_config(cfg, len(sources)), min(cfg.min_consistent, len(sources)),
                                           _working_grey(ctx, name), images, _mask_at(ctx, name, res.depth.shape))
                filled, settled = fill_stats["filled"], fill_stats.get("settled", 0)
        d = res.depth
        info = {"before": before, "after": int((d > 0).sum()), "filled": filled, "settled": settled, "err_sum": err_sum,
                "err_n": err_n,
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
        from .methods.patchmatch.solver import pm_rounds, round_dependencies

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
    consistency: dict  # the geometric filter's statistics (kept_fraction includes the filled gaps: filled_fraction)
    seconds_per_view: float
    cpu_seconds_per_view: float  # the depth tasks' CPU seconds (all threads) per view, filter excluded
    cpu_seconds_per_mp_source: float  # the same per megapixel-source (views x sources x working megapixels)
    per_view: dict  # view name -> valid_fraction, sources, size
    reused_tasks: int  # tasks whose output an interrupted run had left
    task_seconds: dict  # task key -> seconds
    depth_views: dict  # chosen, of, reason, uncovered_points (--depth-views)


def _depth_plan(model, cfg: MVSConfig, no_points: bool, skipped: dict) -> dict[str, tuple]:
    """Per view of ``model`` that can get a depth map: (working-resolution view, source names, depth range,
    seed points); the others go to ``skipped`` with the reason (logged)."""
    near, far = DEPTH_RANGE_FACTORS[cfg.method]
    near = near if cfg.depth_near is None else cfg.depth_near
    far = far if cfg.depth_far is None else cfg.depth_far
    def skip(name: str, reason: str) -> None:
        if name not in skipped:  # said once (a second plan, of the chosen views, meets the same view again)
            skipped[name] = reason
            log.warning("mvs: view %s skipped: %s", name, reason)

    plan: list[tuple[View, list[View], tuple[float, float]]] = []
    for v in model.views:
        rng = camera_depth_range(model.views, v) if no_points else depth_range(model, v, near, far)
        if rng is None:
            skip(v.name, "no sparse points (or a degenerate depth range) in this view")
            continue
        srcs = select_sources(model, v, cfg)
        if not srcs:
            skip(v.name, "no source view with enough shared points and baseline")
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
            skip(v.name, "every source view of it was skipped")
    if not views:
        raise NoDepthError("mvs: no view yielded depth (" + "; ".join(f"{k}: {m}" for k, m in list(skipped.items())[:5]) + ")")
    return views


def _log_choice(choice, cfg: MVSConfig) -> list[str]:
    if len(choice.chosen) < choice.total:
        what = "the coarse depth maps' surface" if choice.surface_samples is not None else "every sparse point"
        log.info("mvs: depth maps for %d of %d views (--depth-views %s: %s seen well by %d of them)",
                 len(choice.chosen), choice.total, cfg.depth_views, what, cfg.depth_view_coverage)
    return choice.chosen


def _pm_rounds(cfg: MVSConfig) -> list:
    from .methods.patchmatch.solver import pm_rounds

    return pm_rounds(cfg)


def _coarse_choice(ctx: _MVSContext, ex) -> tuple[dict, "ViewChoice"]:
    """``--depth-views coarse``: PatchMatch's first (coarsest) round for every planned view, then the views
    whose full depth maps cover that surface (``views.coarse_depth_views``). Returns the round's task results
    and the choice; the round's maps stay in the work folder, where the chosen views' next round reads them."""
    from .methods.patchmatch.solver import level_view

    names = list(ctx.plan)
    results = ex.run(_mvs_task, [Task(f"pm0:{n}", ("pm", n, 0)) for n in names], ctx,
                     desc=f"mvs coarse depth ({len(names)} views)", unit="task")
    level = _pm_rounds(ctx.cfg)[0][0]
    maps = {n: (level_view(ctx.plan[n][0], level), *(_load(ctx.work / "r0" / f"{n}.{what}.npy")
                                                     for what in ("depth", "normal", "cost"))) for n in names}
    return results, coarse_depth_views([ctx.plan[n][0] for n in names], maps, ctx.cfg)


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
    # the views that get depth maps: the sparse points' cover, then (--depth-views coarse, or auto on a large
    # capture: views.wants_coarse_cover) every view's coarsest PatchMatch round and the cover of that surface
    can_coarse = cfg.method == "patchmatch" and len(_pm_rounds(cfg)) > 1
    choice = None if can_coarse and cfg.depth_views == "coarse" else choose_depth_views(model, cfg)
    if choice is not None:
        model = _restricted(model, _log_choice(choice, cfg))
    coarse = can_coarse and wants_coarse_cover(choice, cfg)
    views = _depth_plan(model, cfg, no_points, skipped)
    cfg = _pair_config(cfg, views)
    work = Path(work_dir) if work_dir else out / ".mvs_work"
    ctx = _MVSContext(dataset, cfg, views, work / _work_key(dataset, cfg, views), out,
                      _filter_plan(model, views, cfg))
    coarse_results: dict = {}
    if coarse:
        coarse_results, coarse_choice = _coarse_choice(ctx, ex)
        choice = coarse_choice if choice is None else coarse_choice.after(choice)
        model = _restricted(model, _log_choice(choice, cfg))
        views = _depth_plan(model, cfg, no_points, skipped)  # the sources among the chosen views
        ctx = dataclasses.replace(ctx, plan=views, filter_sources=_filter_plan(model, views, cfg))
    t_graph = time.perf_counter()
    # the bar counts tasks (each view's PatchMatch rounds, then its filter), not views
    results = ex.run(_mvs_task, mvs_tasks(ctx), ctx, desc=f"mvs depth ({cfg.method}, {len(views)} views)", unit="task")
    results.update(coarse_results)  # the coarse round of every view (the chosen ones' found it done)
    t_graph = time.perf_counter() - t_graph
    _GREY_CACHE.clear()
    _MASK_CACHE.clear()
    t_all = time.perf_counter() - t0
    task_seconds = sum(r["seconds"] for k, r in results.items() if not k.startswith("filter:"))
    task_cpu = sum(r.get("cpu_seconds", 0.0) for k, r in results.items() if not k.startswith("filter:"))
    mp_sources = sum(len(srcs) * wv.intrinsics.width * wv.intrinsics.height / 1e6 for wv, srcs, _, _ in views.values())
    consistency: dict = {}
    filtered = {k.partition(":")[2]: r for k, r in results.items() if k.startswith("filter:")}
    if cfg.min_consistent > 0:
        err_n = sum(r["err_n"] for r in filtered.values())
        consistency["mean_reprojection_px"] = sum(r["err_sum"] for r in filtered.values()) / err_n if err_n else float("nan")
        before = sum(r["before"] for r in filtered.values())
        after = sum(r["after"] for r in filtered.values())
        consistency["kept_fraction"] = after / before if before else 0.0
        consistency["filled_fraction"] = sum(r.get("filled", 0) for r in filtered.values()) / after if after else 0.0
        consistency["settled_fraction"] = sum(r.get("settled", 0) for r in filtered.values()) / after if after else 0.0
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
                       consistency=consistency, seconds_per_view=task_seconds / max(len(views), 1),
                       cpu_seconds_per_view=task_cpu / max(len(views), 1),
                       cpu_seconds_per_mp_source=task_cpu / mp_sources if mp_sources else 0.0, per_view=stats,
                       reused_tasks=sum(1 for r in results.values() if r.get("reused")),
                       task_seconds={k: round(r["seconds"], 4) for k, r in results.items()},
                       depth_views=choice.to_dict())
    atomic_write_json(out / "mvs_report.json", report.to_dict())
    return report
