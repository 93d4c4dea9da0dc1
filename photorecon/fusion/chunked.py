"""Chunked TSDF fusion: the grid split into chunks of at most ``chunk_blocks`` voxel blocks, each fused from the
views that see it as a task (in this process or on a Dask cluster), the pieces stitched into one mesh.
"""
from __future__ import annotations

import logging

from dataclasses import dataclass, replace

import numpy as np
import trimesh

from ..arrays import key_rows, row_keys, unique_rows, unique_sorted
from ..cameras import View
from ..errors import NoDepthError
from .config import DepthFrame, FusionConfig, _BLOCK_RES, _BYTES_PER_VOXEL
from .frames import depth_levels, load_frame, nonempty, resolution_weights
from .budget import _band_block_keys, tsdf_voxel_size
from .pieces import chunk_core, stitch_pieces
from .tsdf import _depth_max, _extract, _integrate_frame, _new_grid

log = logging.getLogger("photorecon")


# --- TSDF in spatial chunks (one task each: in-process or on a Dask cluster) -------------------------------
@dataclass
class _ChunkContext:
    """What every chunk task needs: the dataset (depth maps read from disk by the task), the settings, each
    frame's view and valid depth range (in fusion order), the voxel, the depth limit, the chunk size in blocks
    and the folder the pieces go to."""

    dataset: object
    cfg: FusionConfig
    cams: list[tuple[View, float, float]]
    voxel: float
    depth_max: float
    chunk_blocks: int
    work: object
    factors: list[float] | None = None  # per frame (as ``cams``) its weight factor (``frames.resolution_weights``)
    levels: dict | None = None  # view name -> its depth map's level below the working resolution (``depth_levels``)


def _sample_blocks(frames: list[DepthFrame], voxel: float, trunc: float) -> np.ndarray:
    """Unique (N, 3) block coordinates the frames' sampled surfaces (and their truncation band) fall in,
    dilated by one block (samples are sparser than blocks at high resolution)."""
    k = _band_block_keys(frames, voxel, trunc)
    if not len(k):
        return np.zeros((0, 3), np.int64)
    off = np.stack(np.meshgrid(*[[-1, 0, 1]] * 3, indexing="ij"), -1).reshape(-1, 3)
    step = row_keys(off) - row_keys(np.zeros((1, 3)))  # what each neighbour's offset adds to a key
    return key_rows(unique_sorted(k[:, None] + step[None]))


def plan_chunks(frames: list[DepthFrame], voxel: float, trunc: float, chunk_blocks: int) -> list[tuple[tuple[int, int, int], int]]:
    """The chunks (index (i, j, k): blocks [index * chunk_blocks, (index + 1) * chunk_blocks) on each axis) that
    hold surface, each with its estimated block count (for the grid's first allocation)."""
    blocks = _sample_blocks(frames, voxel, trunc)
    ids, counts = unique_rows(np.floor_divide(blocks, chunk_blocks), return_counts=True)
    return [(tuple(int(x) for x in i), int(c)) for i, c in zip(ids, counts)]


def _box_visible(view: View, lo: np.ndarray, hi: np.ndarray, zmin: float, zmax: float) -> bool:
    """Whether the world box [lo, hi] may hold points of ``view``'s depth between ``zmin`` and ``zmax``
    (conservative: corners' depth range against it, and their projection against the image when all are in
    front of the camera)."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    T = view.cam_from_world
    c = corners @ T[:3, :3].T + T[:3, 3]
    if c[:, 2].max() < zmin or c[:, 2].min() > zmax:
        return False
    if (c[:, 2] > 1e-9).all():
        intr = view.intrinsics
        u = intr.fx * c[:, 0] / c[:, 2] + intr.cx
        v = intr.fy * c[:, 1] / c[:, 2] + intr.cy
        if u.max() < -1 or v.max() < -1 or u.min() > intr.width or v.min() > intr.height:
            return False
    return True


def _chunk_task(ctx: _ChunkContext, index: tuple[int, int, int], est_blocks: int) -> dict:
    """Integrate one chunk from the frames that reach it and mesh it; keep the triangles whose centroid lies
    in the chunk's own (core) box. The grid holds the core blocks and one block layer around them, so every
    triangle of the core sees the same voxels (same values: the same frames in the same order) as in one
    volume. The piece goes to ``work/chunk_I_J_K.npz`` (atomically; a task whose piece is there returns)."""
    from pathlib import Path

    from ..resources import measure

    path = Path(ctx.work) / "chunk_{}_{}_{}.npz".format(*index)
    if path.is_file():
        return {"path": str(path), "seconds": 0.0, "reused": True}
    stats: dict = {}
    with measure(stats, "task"):
        info = _chunk_piece(ctx, index, est_blocks, path)
    # peak_mb: the process's peak during the task (the worker's imports included)
    return {"path": str(path), **info, **stats["task"]}


def _chunk_piece(ctx: _ChunkContext, index: tuple[int, int, int], est_blocks: int, path) -> dict:
    from ..io.atomic import atomic_path

    cfg, voxel = ctx.cfg, ctx.voxel
    trunc = cfg.trunc_voxels * voxel
    lo = np.array(index, np.int64) * ctx.chunk_blocks
    hi = lo + ctx.chunk_blocks
    block = voxel * _BLOCK_RES
    margin = trunc + block * np.sqrt(3)
    vbg = _new_grid(voxel, int(est_blocks * 1.5) + 64)
    used = 0
    for (view, dmin, dmax), factor in zip(ctx.cams, ctx.factors or [1.0] * len(ctx.cams)):
        if not _box_visible(view, (lo - 1) * block, (hi + 1) * block, dmin - margin, dmax + margin):
            continue
        f = load_frame(ctx.dataset, view, cfg, level=ctx.levels.get(view.name, 0) if ctx.levels else 0)
        if f is not None and _integrate_frame(vbg, f, cfg, voxel, ctx.depth_max, (lo - 1, hi + 1), factor):
            used += 1
    V, F, C = _extract(vbg, cfg) if used else (np.zeros((0, 3)), np.zeros((0, 3), np.int64), None)
    n_blocks = int(vbg.hashmap().size())
    del vbg
    if len(F):
        V, F, C = chunk_core(V, F, C, lo * block, hi * block)
    with atomic_path(path) as tmp:
        np.savez(tmp, vertices=V.astype(np.float32), faces=F.astype(np.int32),
                 colors=C if C is not None else np.zeros((0, 3), np.uint8))
    return {"frames": used, "blocks": n_blocks, "faces": int(len(F)),
            "grid_mb": round(n_blocks * _BLOCK_RES ** 3 * _BYTES_PER_VOXEL / 2**20, 1)}


def tsdf_fuse_chunked(dataset, frames: list[DepthFrame], cfg: FusionConfig, sparse_points: np.ndarray | None = None,
                      executor=None, work_dir=None, chunk_voxels: int | None = None) -> trimesh.Trimesh:
    """TSDF fusion in cubic chunks of ``chunk_voxels`` (``cfg.chunk_voxels``, default 256) voxels a side, one task
    per chunk that holds surface (``executor``: in-process by default, or a Dask cluster), stitched into one
    mesh equal to ``tsdf_fuse``'s (same voxel, same frames in the same order per voxel; each triangle kept by
    the one chunk whose core box holds its centroid). ``frames`` (from ``load_frames(dataset, cfg)``) serve the
    planning only (voxel size, chunks, each frame's depth range); the tasks read the depth maps of the frames
    that reach their chunk from ``dataset``. The whole-grid memory limit does not apply (a chunk's grid is
    bounded by its size). Pieces go to ``work_dir`` (removed on success; reused by a resumed run)."""
    import hashlib
    import json
    import shutil
    from pathlib import Path

    from ..tasks import IN_PROCESS, Task

    ex = executor or IN_PROCESS
    frames = nonempty(frames)
    if not len(frames):
        raise NoDepthError("every depth map is empty (all pixels invalid, masked or out of range): nothing to fuse")
    voxel, _ = tsdf_voxel_size(frames, replace(cfg, memory_limit_gb=cfg.memory_limit_gb or 1e6), sparse_points)
    trunc = cfg.trunc_voxels * voxel
    depth_max = _depth_max(frames, trunc)
    chunk_blocks = max(1, int(round((chunk_voxels or cfg.chunk_voxels or 256) / _BLOCK_RES)))
    chunks = plan_chunks(frames, voxel, trunc, chunk_blocks)
    by_name = {v.name: v for v in dataset.views}  # the camera's view: load_frame scales it to its depth map
    cams = [(by_name[f.view.name], float(f.depth[f.depth > 0].min()), float(f.depth.max())) for f in frames]

    def stat(v: View) -> list:
        p = dataset.depth_path(v)
        st = p.stat() if p.is_file() else None
        return [v.name, st and st.st_size, st and st.st_mtime_ns]

    key = hashlib.sha256(json.dumps([str(cfg), voxel, depth_max, chunk_blocks, [stat(v) for v, _, _ in cams]],
                                    default=str).encode()).hexdigest()[:16]
    root = Path(work_dir) if work_dir else Path(dataset.depth_dir).parent / ".fusion_work"
    ctx = _ChunkContext(dataset, cfg, cams, voxel, depth_max, chunk_blocks, root / key,
                        resolution_weights(frames, voxel / cfg.voxel_footprints),
                        depth_levels(dataset))
    log.debug("tsdf: voxel %.5g, %d chunks of %d^3 blocks", voxel, len(chunks), chunk_blocks)
    del frames
    info = ex.run(_chunk_task, [Task("{}_{}_{}".format(*i), (i, n)) for i, n in chunks], ctx, desc="tsdf chunks",
                  unit="chunk")
    pieces = []
    for r in info.values():
        with np.load(r["path"]) as z:
            pieces.append((z["vertices"], z["faces"], z["colors"] if len(z["colors"]) else None))
    mesh = stitch_pieces(pieces)
    shutil.rmtree(ctx.work, ignore_errors=True)
    try:
        root.rmdir()
    except OSError:
        pass
    mesh.metadata.update({"voxel_size": voxel, "mesher": "tsdf", "chunks": len(chunks),
                          "chunk_tasks": {k: {x: r.get(x) for x in ("seconds", "frames", "blocks", "faces", "peak_mb", "grid_mb")}
                                          for k, r in info.items()}})
    return mesh
