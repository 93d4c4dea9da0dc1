"""The TSDF's voxel size and what it costs: the voxel blocks the depth maps touch (sampled), the grid's bytes
and the mesh's faces before fusing, and the voxel chosen (``tsdf_voxel_size``): ``--voxel-size`` when given
(refused when its grid would not fit), else a few pixel footprints, coarsened with a warning only when the grid,
or the mesh under ``--memory-gb``, would not fit."""
from __future__ import annotations

import logging

import numpy as np

from ..arrays import unique_sorted
from ..cameras import camera_center
from ..errors import BadArgumentError, NoDepthError
from ..resources import available_bytes
from .config import DepthFrame, FusionConfig, _BLOCK_RES, _BYTES_PER_VOXEL, budget_share
from .frames import DEPTH_LEVEL, _sample_depth_points, pixel_footprint, scene_diagonal
from .grid import _cell_keys

log = logging.getLogger("photorecon")


def _available_bytes() -> int:
    return available_bytes()

def _band_block_keys(frames: list[DepthFrame], voxel: float, trunc: float) -> np.ndarray:
    """Unique ``_cell_keys`` of the voxel blocks that the frames' sampled surface points, moved by -trunc, 0 and
    +trunc along their rays (the truncation band), fall in (with ``trunc`` = 0: the surface's blocks)."""
    block = voxel * _BLOCK_RES
    keys = [np.zeros(0, np.int64)]
    for f in frames:
        pts = _sample_depth_points(f, 20000)
        if not len(pts):
            continue
        ray = pts - camera_center(f.view.cam_from_world)
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        shifts = (-trunc, 0.0, trunc) if trunc > 0 else (0.0,)
        keys.append(unique_sorted(_cell_keys(np.concatenate([pts + s * ray for s in shifts]), block)))
    return unique_sorted(np.concatenate(keys))


# Marching cubes' faces per voxel block that the surface crosses (a block of 16^3 voxels; measured: 300 on the
# synthetic blob at two voxel sizes), and the fusion's peak bytes per face of the mesh: extraction, stitching,
# the Open3D copy, its cleaning and hole filling (measured: 200 on Herz-Jesu-P8 before holes were filled; with
# hole filling, gold_cape's open scene peaked at 2.1 GB for 5.2 M faces estimated at 200, of which about 0.35 GB
# is the process without a mesh: about 330 a face)
FACES_PER_SURFACE_BLOCK = 540
MESH_BYTES_PER_FACE = 300


def estimate_faces(frames: list[DepthFrame], voxel: float) -> int:
    """The fused mesh's face count at ``voxel``, before fusing: the voxel blocks the depth maps' sampled surface
    points fall in (each view's surface: a block two views see counts once) x ``FACES_PER_SURFACE_BLOCK``. It
    follows the surface's area over the voxel's square, not the number of views."""
    return int(len(_band_block_keys(frames, voxel, 0.0)) * FACES_PER_SURFACE_BLOCK)

def estimate_blocks(frames: list[DepthFrame], voxel: float, trunc: float) -> int:
    """Count the voxel blocks the depth maps touch (sampled), with the truncation band: the grid's size."""
    n = len(_band_block_keys(frames, voxel, trunc))
    # sampled pixels miss blocks between samples when a pixel is smaller than a block: scale up
    return int(n * 1.5) + 64

def _grid_bytes(frames: list[DepthFrame], voxel: float, trunc_voxels: float) -> tuple[int, int]:
    n_blocks = estimate_blocks(frames, voxel, trunc_voxels * voxel)
    return n_blocks, n_blocks * _BLOCK_RES ** 3 * _BYTES_PER_VOXEL * 2  # hash map and extraction buffers

def tsdf_voxel_size(frames: list[DepthFrame], cfg: FusionConfig,
                    sparse_points: np.ndarray | None = None, say: bool = True) -> tuple[float, int]:
    """The TSDF voxel size and the estimated number of voxel blocks.

    ``cfg.voxel_size`` when given (refused, naming the memory it needs, when the grid would not fit);
    else ``cfg.voxel_footprints`` pixel footprints (``pixel_footprint``), or the scene diagonal /
    ``cfg.voxels_across`` when that is set. An automatic voxel is coarsened, with a warning stating the voxel
    chosen, only when its grid would exceed ``cfg.memory_limit_gb`` (default 60% of the available memory), or
    the mesh ``cfg.memory_gb``'s share (``say``: False for a plan, which warns of nothing)."""
    limit = cfg.memory_limit_gb * (1 << 30) if cfg.memory_limit_gb else 0.6 * _available_bytes()
    if cfg.voxel_size is not None:
        voxel = float(cfg.voxel_size)
        if not voxel > 0:
            raise BadArgumentError(f"voxel size: expected > 0, got {voxel}")
        diag = scene_diagonal(frames, sparse_points)
        if voxel > 0.5 * diag:  # a grid of one or two voxels across: no surface to extract
            raise BadArgumentError(f"voxel size {voxel:.4g} is larger than the scene, which is about {diag:.3g} "
                                   f"across; use a smaller --voxel-size (e.g. {diag / 300:.3g}: 300 voxels across)")
        n_blocks, need = _grid_bytes(frames, voxel, cfg.trunc_voxels)
        if need > limit:
            raise BadArgumentError(f"voxel size {voxel:.4g} needs about {need / 2**30:.1f} GB for {n_blocks} voxel "
                                   f"blocks, more than the {limit / 2**30:.1f} GB allowed; use a larger --voxel-size")
        return voxel, n_blocks
    if cfg.voxels_across:
        voxel = scene_diagonal(frames, sparse_points) / cfg.voxels_across
    else:
        if not cfg.voxel_footprints > 0:
            raise BadArgumentError(f"voxel footprints: expected > 0, got {cfg.voxel_footprints}")
        voxel = cfg.voxel_footprints * pixel_footprint(frames)
    if not voxel > 0:
        raise NoDepthError("the depth maps give no scale (zero footprint): nothing to fuse")
    first = voxel
    n_blocks, need = _grid_bytes(frames, voxel, cfg.trunc_voxels)
    for _ in range(30):
        if need <= limit:
            break
        # the blocks cover surfaces: their count falls about with the square of the voxel
        voxel *= max(1.1, 1.05 * np.sqrt(need / limit))
        n_blocks, need = _grid_bytes(frames, voxel, cfg.trunc_voxels)
    else:
        raise BadArgumentError(f"no voxel size up to {voxel:.4g} fits the grid in {limit / 2**30:.1f} GB; "
                               "set --memory-limit-gb or --voxel-size")
    if voxel != first and say:
        log.warning("tsdf: a %.4g voxel would need more than the %.1f GB allowed; coarsened to voxel %.4g "
                    "(%d blocks, about %.1f GB; --voxel-size or --memory-limit-gb to choose)", first,
                    limit / 2**30, voxel, n_blocks, need / 2**30)
    mesh_budget = budget_share(cfg, "mesh")
    if mesh_budget:
        first = voxel
        faces = estimate_faces(frames, voxel)
        for _ in range(30):
            if faces * MESH_BYTES_PER_FACE <= mesh_budget:
                break
            # faces follow the surface's area over the voxel's square
            voxel *= max(1.05, 1.02 * np.sqrt(faces * MESH_BYTES_PER_FACE / mesh_budget))
            faces = estimate_faces(frames, voxel)
        if voxel != first:
            n_blocks, _ = _grid_bytes(frames, voxel, cfg.trunc_voxels)
        if voxel != first and say:
            log.warning("tsdf: a %.4g voxel would make a mesh of about %.1f M faces, more than --memory-gb "
                        "%.3g GB holds; coarsened to voxel %.4g (about %.1f M faces; a larger --memory-gb "
                        "keeps the finer voxel)", first, estimate_faces(frames, first) / 1e6, cfg.memory_gb, voxel,
                        faces / 1e6)
    return voxel, n_blocks


# the settings that set the voxel (``tsdf_voxel_size``), which ``planned_footprint`` plans the depth maps for
VOXEL_SETTINGS = ("mesher", "watertight", "voxel_size", "voxel_footprints", "voxels_across", "memory_gb",
                  "memory_limit_gb")


def voxel_settings(cfg: FusionConfig) -> dict:
    """The values of ``VOXEL_SETTINGS`` in ``cfg``."""
    return {k: getattr(cfg, k) for k in VOXEL_SETTINGS}


def planned_footprint(maps: dict, working: dict, cfg: FusionConfig) -> float | None:
    """The pixel footprint (scene units) that the fused mesh's voxel asks of the depth maps, planned before they
    exist: the voxel ``tsdf_voxel_size`` would choose (``cfg.voxel_footprints`` footprints at the working
    resolution, coarsened for ``cfg.memory_gb``'s mesh share; or ``--voxel-size`` / ``--voxels-across``) for the
    surface of the coarse depth maps ``maps`` (view name -> (view at the map's resolution, depth, normal, cost),
    depth 0 off the surface: ``depth.views.confirmed_surface``; ``working``: view name -> the view at its working
    resolution), over ``cfg.voxel_footprints``: a depth map with a finer footprint resolves more than the mesh
    keeps. None when the mesher is not TSDF or the maps hold no surface."""
    from dataclasses import replace

    if cfg.mesher != "tsdf" or cfg.watertight:
        return None
    frames = []
    for name, (lv, depth, _, _) in maps.items():
        if name in working and np.any(depth > 0):
            level = np.log2(working[name].intrinsics.width / lv.intrinsics.width)
            frames.append(DepthFrame(view=replace(lv, extra={**lv.extra, DEPTH_LEVEL: level}),
                                     depth=np.asarray(depth, np.float32)))
    if not frames:
        return None
    auto = cfg.voxel_size is None
    voxel, _ = tsdf_voxel_size(frames, replace(cfg, memory_limit_gb=cfg.memory_limit_gb or 1e6) if auto else cfg,
                               say=False)
    return voxel / cfg.voxel_footprints
