"""Multi-view stereo on the CPU (numpy + OpenCV), no weights and no GPU: ``run_mvs``, the orchestration of the depth
stage (which views, their plan, the task graph, the report). For each reference view:

1. **View selection**: K source views ranked by shared sparse points weighted by their triangulation angle
   (best near 15 degrees, none below 2), or by camera geometry when the model has no points.
2. **Depth range** from the sparse points seen in the view (PatchMatch: 1st percentile x 0.6 to 99th x 1.25;
   the sweep, whose planes get coarser as the range grows: 1st / 1.1 to 99th x 1.1); for a model
   without any sparse point, from where the cameras' optical axes converge.
3. **Depth** by the method ``MVSConfig.method`` names, from the registry (``methods``): PatchMatch
   (``methods/patchmatch``, per-pixel planes) or a plane sweep (``methods/sweep.py``: ``n_depths`` fronto-parallel
   planes uniform in inverse depth, ZNCC over a ``window`` box, the best ``best_k`` sources; confidence = the
   aggregated ZNCC of the winner, TSDF fusion's weight), at most ``max_size`` pixels wide.
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

The task graph is ``graph.py``; what its tasks share (context, images, work files) is ``work.py``.

Outputs, in the synth layout: ``depth/NAME.npy`` (float32 z-depth, 0 = none), ``depth/NAME.conf.npy``
(float32 confidence in [0, 1]) and ``depth/NAME.png`` (preview).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..cameras import View
from ..errors import NoDepthError
from ..io.atomic import atomic_write_json
from ..layout import DEPTH_RESOLUTIONS
from ..results import Result
from ..tasks import IN_PROCESS, Executor
from ..fields import expect_config
from . import work
from .config import MVS_PRESETS, DepthResult, MVSConfig  # noqa: F401 (re-exported)
from .filter import _filter_config, _filter_plan, consistency_count  # noqa: F401 (re-exported)
from .graph import mvs_tasks, run_task
from .methods import method
from .select import camera_depth_range, depth_range, select_sources
from .views import (ViewChoice, choose_depth_views, coarse_depth_views, confirmed_surface, mesh_levels,
                    wants_coarse_cover)
from .work import MVSContext, gray as _gray, working_view as _working_view  # noqa: F401 (re-exported)

log = logging.getLogger("photorecon")


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

    with tempfile.TemporaryDirectory(prefix="photorecon_tri_") as tmp:
        model = triangulate_given(dataset.layout.images, dataset.model, tmp)
    if len(model.points):
        log.info("mvs: %d sparse points triangulated with the given cameras", len(model.points))
    return model


@dataclass
class MVSResult(Result):
    """What ``run_mvs`` did (also written to OUT_DIR/mvs_report.json)."""

    views: int  # views with a depth map written
    skipped: dict  # view name -> one-line reason
    method: str  # the depth method (MVSConfig.method: "patchmatch", "sweep")
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
    per_view: dict  # view name -> valid_fraction, sources, size (w, h), resolution ("full", "half", "quarter") and why
    reused_tasks: int  # tasks whose output an interrupted run had left
    task_seconds: dict  # task key -> seconds
    depth_views: dict  # chosen, of, reason, uncovered_points (--depth-views)


def _depth_plan(model, cfg: MVSConfig, no_points: bool, skipped: dict) -> dict[str, tuple]:
    """Per view of ``model`` that can get a depth map: (working-resolution view, source names, depth range,
    seed points); the others go to ``skipped`` with the reason (logged)."""
    m = method(cfg.method)
    near, far = m.DEPTH_RANGE
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
                             model.points_seen_by(v.name) if m.SEEDS else np.zeros((0, 3)))
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


def _coarse_choice(ctx: MVSContext, ex, on_first=None) -> tuple[dict, ViewChoice]:
    """``--depth-views coarse``: the method's coarse depth map of every planned view (``coarse_maps``; ``on_first``
    gets the maps of the views it computes first), then the views whose full depth maps cover that surface
    (``views.coarse_depth_views``). Returns the coarse tasks' results, the choice and the coarse maps."""
    results, maps = method(ctx.cfg.method).coarse_maps(ctx, ex, on_first)
    return results, coarse_depth_views([ctx.plan[n][0] for n in ctx.plan], maps, ctx.cfg), maps


def run_mvs(dataset, out_dir: str | Path | None = None, cfg: MVSConfig | None = None, executor: Executor | None = None,
            work_dir: str | Path | None = None, on_coarse=None, mesh_footprint=None) -> MVSResult:
    """MVS for every view of a ``Dataset``; writes depth maps (at working resolution: the camera's, or smaller
    with the same aspect ratio when the images exceed ``max_size``), confidences, normals and previews
    to ``out_dir`` (default: DATASET/depth). Returns a report dict. Raises ``NoDepthError`` if no view
    yields depth.

    The work is a task graph (``mvs_tasks``) run by ``executor`` (default: in this process, one task after the
    other; ``photorecon.distributed`` runs it on a Dask cluster). Intermediate maps go to ``work_dir`` (default
    OUT_DIR/.mvs_work), in a sub-folder named after a hash of the settings and inputs: an interrupted run's
    finished tasks are reused by the next run with the same settings; the sub-folder is removed on success.

    ``on_coarse(maps)``: on a capture that gets coarse depth maps (``views.wants_coarse_cover``), called with
    ``{name: (view at the map's resolution, depth, normal, cost)}`` of the views whose coarse maps are computed
    first (a spread share of a large capture, ``views.first_look_views``), before the others' and before the
    chosen views' full depth maps (the pipeline makes a first look of them). ``mesh_footprint(maps, working)``:
    on such a capture with ``--depth-resolution auto``, the pixel footprint the fused mesh will keep, planned from
    the coarse maps (``working``: view name -> view at its working resolution), or None; a view whose half- or
    quarter-resolution depth map has it gets that (``views.mesh_levels``)."""
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
    # capture: views.wants_coarse_cover) every view's coarse depth map (PatchMatch's coarsest round) and the cover of
    # that surface
    m = method(cfg.method)
    can_coarse = hasattr(m, "coarse_maps") and m.coarse_rounds(cfg)
    choice = None if can_coarse and cfg.depth_views == "coarse" else choose_depth_views(model, cfg)
    if choice is not None:
        model = _restricted(model, _log_choice(choice, cfg))
    coarse = can_coarse and wants_coarse_cover(choice, cfg)
    views = _depth_plan(model, cfg, no_points, skipped)
    cfg = m.adapt(cfg, views, cover=coarse) if hasattr(m, "adapt") else cfg
    work_root = Path(work_dir) if work_dir else out / ".mvs_work"
    ctx = MVSContext(dataset, cfg, views, work_root / work.work_key(dataset, cfg, views), out,
                      _filter_plan(model, views, cfg))
    coarse_results: dict = {}
    if coarse:
        coarse_results, coarse_choice, maps = _coarse_choice(ctx, ex, on_coarse)
        if mesh_footprint is not None and cfg.depth_resolution == "auto":
            working = {n: ctx.plan[n][0] for n in maps}
            surface = confirmed_surface(maps, {n: ctx.plan[n][1] for n in working}, max(1, cfg.min_consistent))
            need = mesh_footprint(surface, working)
            if need:
                coarse_choice = mesh_levels(coarse_choice, working, maps, need)
        del maps
        choice = coarse_choice if choice is None else coarse_choice.after(choice)
        model = _restricted(model, _log_choice(choice, cfg))
        views = _depth_plan(model, cfg, no_points, skipped)  # the sources among the chosen views
        levels = {n: choice.level(n) for n in views if choice.level(n)}  # depth maps at half or quarter resolution
        if levels:
            n_mesh = sum(1 for n in levels if n in choice.mesh_coarser)
            n_quarter = sum(1 for lvl in levels.values() if lvl == 2)
            log.info("mvs: %d of %d depth maps at half resolution and %d at a quarter (--depth-resolution %s: %d where "
                     "the fused mesh keeps no finer detail than that map has, %d where full-resolution views see their "
                     "surface as finely)", len(levels) - n_quarter, len(views), n_quarter, cfg.depth_resolution,
                     n_mesh, len(levels) - n_mesh)
        ctx = dataclasses.replace(ctx, plan=views, filter_sources=_filter_plan(model, views, cfg), levels=levels)
    t_graph = time.perf_counter()
    # the bar counts tasks (each view's PatchMatch rounds, then its filter), not views
    results = ex.run(run_task, mvs_tasks(ctx), ctx, desc=f"mvs depth ({cfg.method}, {len(views)} views)", unit="task")
    results.update(coarse_results)  # the coarse round of every view (the chosen ones' found it done)
    t_graph = time.perf_counter() - t_graph
    work.clear_caches()
    t_all = time.perf_counter() - t0
    task_seconds = sum(r["seconds"] for k, r in results.items() if not k.startswith("filter:"))
    task_cpu = sum(r.get("cpu_seconds", 0.0) for k, r in results.items() if not k.startswith("filter:"))
    mp_sources = sum(len(srcs) * wv.intrinsics.width * wv.intrinsics.height / 1e6 / 4 ** work.depth_level(ctx, n)
                     for n, (wv, srcs, _, _) in views.items())
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
        why = choice.resolution_reason(v.name) if choice is not None else None
        stats[v.name]["resolution"] = DEPTH_RESOLUTIONS[work.depth_level(ctx, v.name)]
        if why:
            stats[v.name]["resolution_reason"] = why
    if not stats:
        raise NoDepthError("mvs: no depth survived filtering in any view")
    shutil.rmtree(ctx.work, ignore_errors=True)
    try:
        work_root.rmdir()  # only when no other run's work is left in it
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
