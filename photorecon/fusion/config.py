"""Fusion settings (``FusionConfig``) and the depth frame every mesher takes (``DepthFrame``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..cameras import View
from ..errors import BadArgumentError
from ..config_checks import check_config


_BYTES_PER_VOXEL = 4 + 4 + 12  # tsdf, weight, colour (float32)


_BLOCK_RES = 16


@dataclass
class FusionConfig:
    """Settings of the fusion stage (``photorecon fuse``)."""

    mesher: Literal["tsdf", "grid", "poisson"] = field(default="tsdf", metadata={"help": "TSDF fusion, per-view grid meshing, or screened Poisson from the depth maps' oriented points"})
    voxel_size: float | None = field(default=None, metadata={"help": "TSDF voxel size in scene units (default: --voxel-footprints pixel footprints, coarsened only when the grid would not fit in memory)", "range": (0.0, None), "exclusive_min": True})
    voxel_footprints: float = field(default=1.5, metadata={"help": "default TSDF voxel in pixel footprints (median depth / focal length, at the depth maps' resolution)", "range": (0.0, 1000.0), "exclusive_min": True})
    voxels_across: int | None = field(default=None, metadata={"help": "instead: voxel = scene diagonal (sparse points' 1-99%% box) / this", "range": (2, 100_000)})
    trunc_voxels: float = field(default=2.0, metadata={"help": "TSDF truncation distance, voxels", "range": (0.0, 100.0), "exclusive_min": True})
    weight_threshold: float = field(default=1.0, metadata={"help": "min. integrated weight (about: views) of an extracted voxel", "range": (0.0, 1e6)})
    depth_min: float = field(default=0.0, metadata={"help": "ignore depth below this, scene units", "range": (0.0, None)})
    depth_max: float | None = field(default=None, metadata={"help": "ignore depth beyond this, scene units (default: no limit)", "range": (0.0, None), "exclusive_min": True})
    conf_threshold: float = field(default=0.0, metadata={"help": "ignore depth whose confidence (NAME.conf.npy, 0..1) is below this", "range": (0.0, 1.0)})
    use_masks: bool = field(default=True, metadata={"help": "apply masks/NAME.png when present"})
    normal_sdf: float = field(default=0.2, metadata={"help": "TSDF: signed distance to the confirmed tangent plane, its cosine to the ray at least this (keeps grazing surfaces; 0 = along the ray)", "range": (0.0, 1.0)})
    normal_sdf_plane_tol: float = field(default=1.5, metadata={"help": "--normal-sdf: a pixel's plane counts where its depth map follows it within this many voxels (0 = everywhere)", "range": (0.0, 100.0)})
    confidence_weights: bool = field(default=True, metadata={"help": "TSDF: weight each pixel by its confidence map (NAME.conf.npy) when present"})
    max_stretch: float = field(default=8.0, metadata={"help": "grid: reject triangles whose edge exceeds this many pixel footprints", "range": (0.0, 10_000.0), "exclusive_min": True})
    chunk_voxels: int | None = field(default=None, metadata={"help": "TSDF in cubic chunks of this many voxels a side, one task each (default: one volume; 256 with --cluster)", "range": (16, 65536)})
    memory_limit_gb: float | None = field(default=None, metadata={"help": "refuse a voxel grid above this size, GB (default: 60%% of free memory)", "range": (0.0, 1e6), "exclusive_min": True})
    memory_gb: float = field(default=2.0, metadata={"metavar": "GB", "help": "TSDF: memory budget of the fusion, GB: depth frames are kept on disk and read one at a time when they would hold more than a quarter of it, the grid is fused in chunks of at most a quarter, and the voxel is coarsened (with a warning) when the mesh would need more than half (0 = no budget)", "range": (0.0, 1e6)})
    grid_budget_gb: float | None = field(default=0.5, metadata={"help": "TSDF: largest voxel grid held at once, GB; a larger scene is fused in chunks that each fit (same mesh; 0 = one grid)", "range": (0.0, 1e6)})
    poisson_depth: int = field(default=0, metadata={"help": "poisson: octree depth (0 = a cell of about 2 pixel footprints, depth 5 to 10)", "range": (0, 16)})
    poisson_trim: float = field(default=0.02, metadata={"help": "poisson: drop the surface where the sample density is below this quantile of the vertices' densities (0 = off)", "range": (0.0, 1.0)})
    watertight: bool = field(default=False, metadata={"help": "poisson: close what the cameras never saw into one watertight surface; report.json says how much area was invented"})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.config_checks)
        if self.watertight and self.mesher != "poisson":  # refused when built, before any stage runs
            raise BadArgumentError(f"--watertight needs --mesher poisson (got --mesher {self.mesher})")


@dataclass
class DepthFrame:
    """One view's depth ready for fusion: z-depth (H, W) float32 (0 = invalid), optional colour (H, W, 3)
    uint8 and optional per-pixel confidence (H, W) in [0, 1], used as the TSDF integration weight."""

    view: View
    depth: np.ndarray
    color: np.ndarray | None = None
    confidence: np.ndarray | None = None
    normal: np.ndarray | None = None  # (H, W, 3) unit normals in the camera frame (OpenCV axes), 0 = none


# The shares of ``FusionConfig.memory_gb`` (the fusion's budget): the depth frames held at once (more are read
# one at a time), the voxel grid held at once (more is fused in chunks), and the mesh (more coarsens the voxel).
BUDGET_SHARES = {"frames": 0.25, "grid": 0.25, "mesh": 0.5}


def budget_share(cfg: FusionConfig, part: str) -> float:
    """Bytes of the fusion's memory budget for ``part`` (``BUDGET_SHARES``); 0 without a budget. The grid's
    share is at most ``cfg.grid_budget_gb`` (0 there: one grid, whatever its size)."""
    share = BUDGET_SHARES[part] * cfg.memory_gb * (1 << 30) if cfg.memory_gb else 0.0
    if part == "grid":
        grid = cfg.grid_budget_gb * (1 << 30) if cfg.grid_budget_gb else 0.0
        return min(share, grid) if share and grid else grid
    return share


def frames_hold_bytes(cfg: FusionConfig) -> float | None:
    """What ``load_frames`` may hold in memory before it keeps the frames on disk and reads them one at a time
    (TSDF fusion, which streams them); None: no limit (the other meshers keep every frame)."""
    if cfg.mesher != "tsdf" or cfg.watertight or not cfg.memory_gb:
        return None
    return budget_share(cfg, "frames")
