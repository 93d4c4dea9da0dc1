"""Plane-sweep stereo as a depth method (``--method sweep``, a fast preview): one reference image and its sources in,
a z-depth map and its confidence out (ZNCC over fronto-parallel planes uniform in inverse depth, the best
``best_k`` sources aggregated, sub-plane refinement); one task per view. Its settings are ``MVSConfig``'s
``n_depths``, ``window`` and ``best_k``.
"""
from __future__ import annotations

import time

import cv2
import numpy as np

from ...cameras import View, invert_rigid
from ...tasks import Task
from .. import work
from ..config import MVSConfig

NAME = "sweep"
# the sweep's planes get coarser as its range grows: a narrow range around the sparse points
DEPTH_RANGE = (1 / 1.1, 1.1)
SEEDS = False
NOTE = ("depth: --method sweep is a rough preview (fronto-parallel planes): its mesh is far less complete and accurate "
        "than --method patchmatch's; --quality preview is the quick look that keeps PatchMatch")
HINT = "--method sweep is a rough preview; use --method patchmatch (the default)"


def tasks(ctx: work.MVSContext) -> tuple[list[Task], dict[str, str]]:
    """One task per view: ``sweep:NAME``."""
    last = {n: f"sweep:{n}" for n in ctx.plan}
    return [Task(last[n], (NAME, n)) for n in ctx.plan], last


def run_task(ctx: work.MVSContext, name: str) -> dict:
    """The plane sweep of view ``name`` against its sources, to ``work/raw``."""
    t0, c0 = time.perf_counter(), time.process_time()
    if work.raw_path(ctx, name, "depth").is_file():
        return {"seconds": 0.0, "reused": True}
    ref_w, srcs, rng, _ = ctx.plan[name]
    src = [(work.working_grey(ctx, s), ctx.plan[s][0]) for s in srcs]
    depth, conf = plane_sweep(work.working_grey(ctx, name), ref_w, src, rng[0], rng[1], ctx.cfg)
    work.finish_depth(ctx, name, depth, conf, None)
    return {"seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0}


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
