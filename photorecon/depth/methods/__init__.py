"""The depth methods, in one registry (``REGISTRY``): a method is a module of its own plus one line here. The
settings (``MVSConfig.method``'s choices and help, hence ``--method``), ``run_mvs`` and the pipeline read it; this
file imports no method (each is imported when first used).

Two kinds of method:

* **per view** (``"view"``): the depth stage's task graph (``depth.mvs.run_mvs``) plans each view (its source
  views, its depth range, its working resolution), runs the method's tasks, then the multi-view geometric
  filter and writes the depth maps. ``--method NAME`` chooses one. Its module has

  - ``DEPTH_RANGE``: (near, far) factors on the 1st and 99th percentile of the depths of the sparse points a
    view sees (the depth range searched);
  - ``SEEDS``: whether the plan carries the sparse points each view sees (``plan[name][3]``);
  - ``tasks(ctx) -> (tasks, last)``: its ``tasks.Task``s for the views of ``ctx.plan`` (a task's ``args`` start
    with the method's name; the graph calls ``run_task(ctx, *args[1:])``), and per view the key of its last
    task, which the filter waits for;
  - ``run_task(ctx, name, *args) -> dict``: one task; the last one of a view passes the view's unfiltered depth
    to ``depth.work.finish_depth``; returns ``{"seconds", "cpu_seconds"}``, or ``{"seconds": 0.0, "reused":
    True}`` when its output is already in the work folder (a retry, a resumed run);
  - optionally ``adapt(cfg, plan, cover) -> cfg`` (settings for this plan; ``cover``: the coarse round chooses
    the views), ``coarse_rounds(cfg) -> bool`` and
    ``coarse_maps(ctx, executor, on_first)`` (a coarse depth map of every view first, for ``--depth-views
    coarse``; ``on_first(maps)`` gets those of the views computed first),
    ``NOTE`` (a warning the pipeline logs before running it) and ``HINT`` (what to try when too little depth is
    confirmed).

* **whole stage** (``"stage"``): writes the depth folder itself, chosen by ``reconstruct``'s settings
  (``--depth-model``, ``--depth FOLDER``). Its module has ``SOURCE`` (the name the depth stage records),
  ``selected(run)``, ``check(run)`` (the input checks before anything is written), ``inputs(run, fingerprint)``
  (what the stage's key hashes, with the stage runner's ``fingerprint`` of files) and
  ``run_stage(dataset, run, out_dir, executor, work, factor) -> dict`` (the stage's facts, with ``"views"``: the
  depth maps written; ``executor()``: the executor of its tasks, made (a cluster started) when first called;
  ``work``: its work folder; ``factor``: the metric scale applied to given cameras).
"""
from __future__ import annotations

import importlib
from types import ModuleType
from typing import NamedTuple


class Entry(NamedTuple):
    kind: str  # "view" (per view, in run_mvs' task graph) or "stage" (writes the depth folder itself)
    module: str | ModuleType  # dotted path, imported when first used, or the module itself
    help: str = ""  # one line for the settings' help (per-view methods)


REGISTRY: dict[str, Entry] = {
    "patchmatch": Entry("view", "photorecon.depth.methods.patchmatch", "per-pixel depth and normal (ACMH/ACMM)"),
    "sweep": Entry("view", "photorecon.depth.methods.sweep", "fronto-parallel plane sweep (a fast preview)"),
    "mono": Entry("stage", "photorecon.depth.methods.mono"),
    "given": Entry("stage", "photorecon.depth.methods.given"),
}


def names(kind: str) -> tuple[str, ...]:
    """The registered methods of ``kind`` ("view" or "stage"), in registry order."""
    return tuple(n for n, e in REGISTRY.items() if e.kind == kind)


def view_help() -> str:
    """``MVSConfig.method``'s help: each per-view method and its line."""
    return "; ".join(f"{n}: {e.help}" for n, e in REGISTRY.items() if e.kind == "view")


def method(name: str) -> ModuleType:
    """The module of the method ``name``."""
    entry = REGISTRY.get(name)
    if entry is None:
        from ...errors import BadArgumentError

        raise BadArgumentError(f"depth method: expected one of {', '.join(REGISTRY)}, got {name!r}")
    return importlib.import_module(entry.module) if isinstance(entry.module, str) else entry.module


def stage_method(run) -> ModuleType | None:
    """The whole-stage method that ``reconstruct``'s settings ``run`` select (the first in registry order), or
    None: a per-view method (``MVSConfig.method``) makes the depth maps."""
    for name in names("stage"):
        m = method(name)
        if m.selected(run):
            return m
    return None


def register(name: str, kind: str, module: str | ModuleType, help: str = "") -> None:
    """Add a method at run time (a plug-in, a test); a per-view one becomes a valid ``MVSConfig.method`` (for
    configs built after this call). The registry is per process: for tasks on a cluster (``photorecon.distributed``)
    the workers look the method up in theirs, so such a method belongs in ``REGISTRY`` as a dotted module path."""
    REGISTRY[name] = Entry(kind, module, help)
    _forget_hints()


def unregister(name: str) -> None:
    REGISTRY.pop(name, None)
    _forget_hints()


def _forget_hints() -> None:
    """``MVSConfig.method``'s choices are the registry's per-view methods, read when its type hints are evaluated;
    the config checks cache them per class."""
    from ... import fields
    from ..config import MVSConfig

    fields._HINTS.pop(MVSConfig, None)
