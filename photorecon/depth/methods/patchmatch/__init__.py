"""PatchMatch multi-view stereo as a depth method (``--method patchmatch``, the default): per view its rounds, coarse
to fine, each one task (round r of a view after round r - 1 of itself and, with the geometric term, of its
sources). Its settings are ``MVSConfig``'s ``pm_*`` fields, ``geom_*``, ``planar_prior``, ``min_texture`` and
``texture_rel``.

- ``solver``: PatchMatch on one view, one round at a time (``pm_view_round``), and its rounds (``pm_rounds``).
- ``kernels``: its numba kernels.
"""
from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from ....tasks import Task
from ... import work

log = logging.getLogger("photorecon")

NAME = "patchmatch"
# PatchMatch searches depth continuously, so a wide range costs it little; the near side is widened most
# (``select.depth_range``)
DEPTH_RANGE = (0.6, 1.25)
SEEDS = True  # the sparse points a view sees start as planes of its first round

# PatchMatch on a view matched against one other view only (a stereo pair), where no third view outvotes a window
# that straddles a depth edge: smaller, denser and sharper windows, unless set otherwise (synthetic rectified
# pairs at 640x480, knot / room, depth within 1% on the co-visible pixels: 0.88 / 0.90 -> 0.94 / 0.95)
PAIR_SETTINGS = {"pm_radius": 3, "pm_stride": 1, "pm_sigma_color": 0.05}


# a capture whose views the coarse depth maps choose (``--depth-views coarse``, or auto on a large one) computes the
# coarsest round for every view, most of which get no other: with the default pyramid it gets levels until that
# round's long side is at most COVER_MAX_SIDE (at the default 1600 px: 4 levels, the round at 200 px instead of
# 400, a quarter of its pixels; at 800 px the default 3 levels already give 200 px, where the cover's rules were
# measured on gold_cape). The chosen views then go through one more, cheap round (one iteration, the sources the
# coarser round used) on their way to their own resolution.
COVER_MAX_SIDE = 300


def adapt(cfg, plan: dict, cover: bool = False):
    """``cfg`` for this ``plan``: ``PAIR_SETTINGS`` in place of the defaults when every view of the ``plan`` has
    one source; with ``cover`` (the coarse round chooses the views), the default pyramid deepened until the
    coarsest round's long side is at most ``COVER_MAX_SIDE`` (``cover_levels``)."""
    from ...config import MVSConfig

    defaults = MVSConfig()
    if cover and plan and cfg.pm_levels == defaults.pm_levels:
        levels = cover_levels(cfg.pm_levels, max(max(p[0].intrinsics.size) for p in plan.values()))
        if levels != cfg.pm_levels:
            log.info("mvs: the coarse round at 1/%d of the working resolution (%d pyramid levels): it runs for every "
                     "view", 2 ** (levels - 1), levels)
            cfg = dataclasses.replace(cfg, pm_levels=levels)
    if not plan or any(len(p[1]) != 1 for p in plan.values()):
        return cfg
    changes = {k: v for k, v in PAIR_SETTINGS.items() if getattr(cfg, k) == getattr(defaults, k)}
    if changes:
        log.info("mvs: every view has one source view (a stereo pair): %s",
                 ", ".join(f"{k} {v}" for k, v in changes.items()))
    return dataclasses.replace(cfg, **changes)


def cover_levels(levels: int, side: int) -> int:
    """Pyramid levels, at least ``levels``, whose coarsest level of a ``side``-pixel long side is at most
    ``COVER_MAX_SIDE`` (each level halves the image)."""
    while side / 2 ** (levels - 1) > COVER_MAX_SIDE:
        levels += 1
    return levels


def _jobs(ctx: work.MVSContext) -> dict:
    """Per planned view its ``solver.PMJob``; a view whose depth map stops at a coarser level (``ctx.levels``) stops
    at that level's last round."""
    from .solver import PMJob, last_round

    return {n: PMJob(wv, srcs, rng[0], rng[1], seeds, last_round(ctx.cfg, work.depth_level(ctx, n)))
            for n, (wv, srcs, rng, seeds) in ctx.plan.items()}


def _round_file(ctx: work.MVSContext, r: int, name: str, what: str):
    return ctx.work / f"r{r}" / f"{name}.{what}.npy"


def tasks(ctx: work.MVSContext) -> tuple[list[Task], dict[str, str]]:
    """Per view its rounds: ``pm{r}:NAME`` after round r - 1 of the views it reads (``solver.round_dependencies``;
    a view that stops at a coarser level: its last round, ``solver.read_round``)."""
    from .solver import pm_rounds, read_round, round_dependencies

    jobs = _jobs(ctx)
    n_rounds = len(pm_rounds(ctx.cfg))
    out = []
    for r in range(n_rounds):
        out += [Task(f"pm{r}:{n}", (NAME, n, r),
                     tuple(f"pm{read_round(jobs[d], r, ctx.cfg)}:{d}" for d in round_dependencies(jobs[n], r, jobs, ctx.cfg)))
                for n in ctx.plan if r <= jobs[n].last_round]
    return out, {n: f"pm{jobs[n].last_round}:{n}" for n in ctx.plan}


def run_task(ctx: work.MVSContext, name: str, r: int = 0) -> dict:
    """Round ``r`` of view ``name``: its maps to ``work/r{r}``, the last round's result to ``work/raw``
    (``work.finish_depth``: confidence = 1 - cost)."""
    from . import solver

    cfg = ctx.cfg
    t0, c0 = time.perf_counter(), time.process_time()  # CPU: all threads of this process (the kernels' too)
    jobs = _jobs(ctx)
    last = r == jobs[name].last_round
    read_later = r < len(solver.pm_rounds(cfg)) - 1  # other views' later rounds read this round's maps
    done = work.raw_path(ctx, name, "depth") if last else _round_file(ctx, r, name, "depth")
    if done.is_file():
        return {"seconds": 0.0, "reused": True}

    def load(n: str, rr: int, what: str) -> np.ndarray:
        return work.load(_round_file(ctx, rr, n, what))

    depth, normal, cost, _, views = solver.pm_view_round(jobs[name], r, jobs, lambda n, lv: work.level_image(ctx, n, lv),
                                                         solver.PatchMatchParams(cfg), load,
                                                         lambda n, lv: work.level_mask(ctx, n, lv))
    seconds = time.perf_counter() - t0
    if read_later:  # (depth last: the file that says the round is done)
        work.save(_round_file(ctx, r, name, "normal"), normal)
        work.save(_round_file(ctx, r, name, "cost"), cost)
        if views is not None:
            work.save(_round_file(ctx, r, name, "views"), views)
        work.save(_round_file(ctx, r, name, "depth"), depth)
    if last:  # finish_depth zeroes rejected pixels in place: after the round's own maps are written
        work.finish_depth(ctx, name, depth, np.clip(1.0 - cost, 0.0, 1.0).astype(np.float32), normal)
    return {"seconds": seconds, "cpu_seconds": time.process_time() - c0}


def coarse_rounds(cfg) -> bool:
    """Whether the first round is a coarse one of its own (more than one round): ``--depth-views coarse``."""
    from .solver import pm_rounds

    return len(pm_rounds(cfg)) > 1


def coarse_maps(ctx: work.MVSContext, executor, on_first=None) -> tuple[dict, dict]:
    """The first (coarsest) round of every planned view, as tasks. Returns the tasks' results and per view (its
    view at that round's resolution, depth, normal, cost); the maps stay in the work folder, where the chosen
    views' next round reads them. ``on_first(maps)``: called with the maps of the views computed first, a spread
    share of a large capture's (``views.first_look_views``; all of a small one's), before the others are."""
    from ...views import first_look_views
    from .solver import level_view, pm_rounds

    names = list(ctx.plan)
    from ...graph import run_task as graph_task

    level = pm_rounds(ctx.cfg)[0][0]

    def maps_of(batch):
        return {n: (level_view(ctx.plan[n][0], level), *(work.load(_round_file(ctx, 0, n, what))
                                                         for what in ("depth", "normal", "cost"))) for n in batch}

    first = [names[k] for k in first_look_views([ctx.plan[n][0] for n in names])] if on_first else names
    picked = set(first)
    rest = [n for n in names if n not in picked]
    results = {}
    for batch in (first, rest):
        if not batch:
            continue
        desc = (f"mvs coarse depth ({len(names)} views)" if len(batch) == len(names) else
                f"mvs coarse depth (first look: {len(batch)} of {len(names)} views)" if batch is first else
                f"mvs coarse depth (the other {len(batch)} views)")
        results.update(executor.run(graph_task, [Task(f"pm0:{n}", (NAME, n, 0)) for n in batch], ctx, desc=desc,
                                    unit="task"))
        if batch is first and on_first is not None:
            on_first(maps_of(first))
    return results, maps_of(names)
