"""The depth stage as a task graph (in-process by default, or on a Dask cluster: ``photorecon.distributed``): per
view the depth method's tasks (``methods``), then the view's multi-view geometric filter, which writes its files
to the output folder.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..io.images import write_depth
from ..tasks import Task
from . import work
from .fill import fill_holes, fill_on
from .filter import _filter_config, consistency_count
from .methods import method
from .work import MVSContext


def mvs_tasks(ctx: MVSContext) -> list[Task]:
    """The depth stage's task graph: per view the method's tasks (``tasks(ctx)`` of ``ctx.cfg.method``'s module:
    the sweep's one, or PatchMatch's rounds), then its consistency filter (after its own and its checked views'
    last task)."""
    cfg = ctx.cfg
    tasks, last = method(cfg.method).tasks(ctx)
    tasks = list(tasks)
    for n in ctx.plan:
        deps = [last[n]] + ([last[s] for s in work.checked_views(ctx, n) if s in last] if cfg.min_consistent > 0 else [])
        tasks.append(Task(f"filter:{n}", ("filter", n), tuple(dict.fromkeys(deps))))
    return tasks


def run_task(ctx: MVSContext, kind: str, name: str, *args) -> dict:
    """One task: ``"filter"`` (a view's geometric consistency against its checked views, then its files in
    ``out``), else a task of the depth method ``kind`` (its ``run_task(ctx, name, *args)``)."""
    if kind == "filter":
        return filter_task(ctx, name)
    return method(kind).run_task(ctx, name, *args)


def filter_task(ctx: MVSContext, name: str) -> dict:
    """View ``name``'s unfiltered result (``work/raw``) checked against the views ``work.checked_views`` names
    (``filter.consistency_count``), its gaps filled (``fill.fill_holes``, a method with normals), and written to
    ``ctx.out`` when any depth is left. Returns its statistics."""
    cfg = ctx.cfg
    t0 = time.perf_counter()
    res = work.raw_result(ctx, name, normal=True)
    before = int((res.depth > 0).sum())
    err_sum, err_n, filled, settled = 0.0, 0, 0, 0
    if cfg.min_consistent > 0:
        checked = dataclasses.replace(res, sources=work.checked_views(ctx, name))
        sources = {s: work.raw_result(ctx, s, normal=cfg.plane_reproj_px > 0, confidence=False) for s in checked.sources}
        cnt, err_sum, err_n = consistency_count(checked, sources, _filter_config(cfg, len(sources)))
        res.depth[cnt < min(cfg.min_consistent, len(sources))] = 0  # no more confirming views than there are
        if cfg.consistency_confidence:  # k views agree: confidence at least 1 - 1/k
            res.confidence = np.maximum(res.confidence, 1.0 - 1.0 / np.maximum(cnt, 1)).astype(np.float32)
        if res.normal is not None and fill_on(cfg, len(sources)):  # PatchMatch: gaps filled with confirmed planes
            images = {s: (work.working_grey(ctx, s), ctx.plan[s][0]) for s in ctx.plan[name][1]}
            _, fill_stats = fill_holes(dataclasses.replace(res, sources=checked.sources), sources,
                                       _filter_config(cfg, len(sources)), min(cfg.min_consistent, len(sources)),
                                       work.level_image(ctx, name, res.view), images,
                                       work.mask_at(ctx, name, res.depth.shape))
            filled, settled = fill_stats["filled"], fill_stats.get("settled", 0)
    d = res.depth
    info = {"before": before, "after": int((d > 0).sum()), "filled": filled, "settled": settled, "err_sum": err_sum,
            "err_n": err_n, "seconds": time.perf_counter() - t0}
    if not np.count_nonzero(d):
        return {**info, "written": False}
    write_depth(ctx.out, name, d, np.where(d > 0, res.confidence, 0).astype(np.float32))
    if res.normal is not None:
        work.save(ctx.out / f"{name}.normal.npy", np.where(d[..., None] > 0, res.normal, 0).astype(np.float16))
    return {**info, "written": True, "valid_fraction": float((d > 0).mean()), "sources": res.sources,
            "size": [int(d.shape[1]), int(d.shape[0])]}
