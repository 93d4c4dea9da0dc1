"""What the depth stage's tasks share: their context (``MVSContext``: the dataset, the settings, the plan, the
folders), the views' grey images and masks at working resolution (a small cache per process), and the files in
the work folder (each written atomically; a view's unfiltered result in ``work/raw``, depth last).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from ..cameras import View
from ..errors import NoDepthError
from ..io.atomic import atomic_path
from .config import DepthResult, MVSConfig


def gray(img: np.ndarray) -> np.ndarray:
    g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    return g.astype(np.float32) / 255.0


def working_view(view: View, max_size: int) -> View:
    W, H = view.intrinsics.size
    s = min(1.0, max_size / max(W, H)) if max_size > 0 else 1.0
    if s >= 1.0:
        return view
    intr = view.intrinsics.scaled(int(round(W * s)), int(round(H * s)))
    return dataclasses.replace(view, intrinsics=intr, extra=dict(view.extra))



@dataclass
class MVSContext:
    """What every MVS task needs (sent once to each worker): the dataset, the settings, the plan (view name ->
    (working-resolution view, source names, depth range, seed points)) and the folders. Arrays between tasks
    go through ``work`` (each file written atomically), results to ``out``."""

    dataset: object
    cfg: MVSConfig
    plan: dict[str, tuple[View, list[str], tuple[float, float], np.ndarray]]
    work: Path
    out: Path
    filter_sources: dict[str, list[str]] = field(default_factory=dict)  # view -> the views its filter checks
    # view -> the pyramid level its depth map stops at (0: the working resolution; 1: half of it, 2: a quarter:
    # ``views.half_resolution_views``, ``views.mesh_levels``); a view not named: 0
    levels: dict[str, int] = field(default_factory=dict)


def depth_level(ctx: MVSContext, name: str) -> int:
    """The pyramid level of view ``name``'s depth map (0: the working resolution)."""
    return ctx.levels.get(name, 0)


def view_at(view: View, shape: tuple[int, int]) -> View:
    """``view`` (a working-resolution view) scaled to a map of ``shape`` (h, w): a depth map at a coarser level."""
    h, w = shape
    if (h, w) == (view.intrinsics.height, view.intrinsics.width):
        return view
    return dataclasses.replace(view, intrinsics=view.intrinsics.scaled(w, h))


def checked_views(ctx: MVSContext, name: str) -> list[str]:
    """The views the consistency filter checks ``name`` against (its matching sources without a longer list)."""
    return ctx.filter_sources.get(name) or ctx.plan[name][1]


def dataset_view(ctx: MVSContext, name: str) -> View:
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


def plan_view(ctx: MVSContext, name: str) -> View:
    """View ``name`` at its working resolution (the plan's, else from ``max_size``)."""
    return ctx.plan[name][0] if name in ctx.plan else working_view(dataset_view(ctx, name), ctx.cfg.max_size)


def working_grey(ctx: MVSContext, name: str) -> np.ndarray:
    """View ``name``'s grey image (float32 0..1) at its working resolution, from a small per-process cache."""
    v = dataset_view(ctx, name)
    wv = plan_view(ctx, name)
    path = ctx.dataset.image_path(v)
    try:
        key = (str(path), path.stat().st_mtime_ns, wv.intrinsics.size)
    except OSError:
        key = (str(path), None, wv.intrinsics.size)

    def make():
        g = gray(ctx.dataset.image(v))
        if g.shape != (wv.intrinsics.height, wv.intrinsics.width):
            g = cv2.resize(g, wv.intrinsics.size, interpolation=cv2.INTER_AREA)
        return g

    return _cached(_GREY_CACHE, key, make)


def level_mask(ctx: MVSContext, name: str, lv: View) -> np.ndarray | None:
    """View ``name``'s mask (True = foreground) at ``lv``'s resolution, or None without one: PatchMatch computes
    only these pixels. A pixel of a coarser level is foreground when any of its working-resolution pixels is."""
    v = dataset_view(ctx, name)
    wv = plan_view(ctx, name)

    def make():
        m = ctx.dataset.mask(v)
        if m is not None and m.shape != (wv.intrinsics.height, wv.intrinsics.width):
            m = cv2.resize(m.astype(np.uint8), wv.intrinsics.size, interpolation=cv2.INTER_NEAREST) > 0
        return m

    m = _cached(_MASK_CACHE, (str(ctx.dataset.image_path(v)), str(ctx.dataset.mask_path(v)), wv.intrinsics.size), make)
    if m is None or m.shape == (lv.intrinsics.height, lv.intrinsics.width):
        return m
    return cv2.resize(m.astype(np.float32), lv.intrinsics.size, interpolation=cv2.INTER_AREA) > 0


def mask_at(ctx: MVSContext, name: str, shape: tuple[int, int]) -> np.ndarray | None:
    """View ``name``'s mask (True = foreground) at ``shape`` (h, w), or None without one."""
    mask = level_mask(ctx, name, plan_view(ctx, name))
    if mask is not None and mask.shape != tuple(shape):
        mask = cv2.resize(mask.astype(np.uint8), tuple(shape)[::-1], interpolation=cv2.INTER_NEAREST) > 0
    return mask


def level_image(ctx: MVSContext, name: str, lv: View) -> np.ndarray:
    g = working_grey(ctx, name)
    if g.shape != (lv.intrinsics.height, lv.intrinsics.width):
        g = cv2.resize(g, lv.intrinsics.size, interpolation=cv2.INTER_AREA)
    return g


def save(path: Path, array: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        np.save(tmp, array)


def load(path: Path) -> np.ndarray:
    try:
        return np.load(path)
    except (OSError, ValueError) as exc:
        raise NoDepthError(f"mvs: intermediate file {path} is missing or unreadable ({exc.__class__.__name__}); "
                           "was the work folder removed while the run went on?") from None


def raw_path(ctx: MVSContext, name: str, what: str) -> Path:
    return ctx.work / "raw" / f"{name}.{what}.npy"


def finish_depth(ctx: MVSContext, name: str, depth: np.ndarray, conf: np.ndarray, normal: np.ndarray | None) -> None:
    """A view's unfiltered result: low-confidence, non-finite and masked pixels to 0; to ``work/raw`` (depth last:
    the file that says the view is done)."""
    cfg = ctx.cfg
    mask = mask_at(ctx, name, depth.shape)  # masks/NAME.png or the image's alpha: no depth there
    min_conf = cfg.min_confidence
    if normal is not None and not cfg.planar_prior and (cfg.min_texture > 0 or cfg.texture_rel > 0):
        from .planar import relative_texture, textureless  # PatchMatch: no evidence where the window is flat

        grey = level_image(ctx, name, view_at(plan_view(ctx, name), depth.shape))  # the depth map's resolution
        if cfg.min_texture > 0:
            depth[textureless(grey, cfg.pm_radius, cfg.min_texture)] = 0
        if cfg.texture_rel > 0:
            depth[relative_texture(grey, cfg.pm_radius, mask) < cfg.texture_rel] = 0
            min_conf = cfg.textured_min_confidence
    depth[(conf < min_conf) | ~np.isfinite(depth)] = 0
    if mask is not None:
        depth[~mask] = 0
    save(raw_path(ctx, name, "conf"), conf.astype(np.float32))
    if normal is not None:
        save(raw_path(ctx, name, "normal"), normal.astype(np.float16))
    save(raw_path(ctx, name, "depth"), depth.astype(np.float32))


def raw_result(ctx: MVSContext, name: str, normal: bool = False, confidence: bool = True) -> DepthResult:
    """View ``name``'s unfiltered result from ``work/raw``; ``confidence=False`` for a source of the filter, which
    reads only its depth (and normals)."""
    n_path = raw_path(ctx, name, "normal")
    depth = load(raw_path(ctx, name, "depth"))
    return DepthResult(depth, load(raw_path(ctx, name, "conf")) if confidence else None,
                       view_at(ctx.plan[name][0], depth.shape), ctx.plan[name][1],
                       load(n_path) if normal and n_path.is_file() else None)



def work_key(dataset, cfg: MVSConfig, plan: dict) -> str:
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


def clear_caches() -> None:
    """Forget the cached grey images and masks (at the end of a run)."""
    _GREY_CACHE.clear()
    _MASK_CACHE.clear()
