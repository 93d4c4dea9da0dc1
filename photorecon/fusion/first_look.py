"""A first look at the model from the coarse depth maps: on a large capture the depth stage first computes a coarse
depth map of every view (PatchMatch's coarsest round, at a quarter or an eighth of the working resolution) to
choose the views that get full depth maps. Those maps already show the shape; fused at their own (coarse) pixel
footprint they give a mesh in seconds, long before the full depth maps exist.

The coarse maps are unfiltered: a pixel counts where its matching cost is below ``max_cost`` (1 - NCC, 0 =
perfect), and a voxel is kept where at least ``min_views`` maps saw it (the TSDF weight), which removes most of
what one view alone got wrong; then the usual cleaning drops debris and floaters. The result is for looking at,
not for measuring: the full result replaces it.
"""
from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import trimesh

from ..cameras import View
from ..mesh import CleanConfig, clean
from .config import DepthFrame, FusionConfig
from .tsdf import tsdf_fuse

log = logging.getLogger("photorecon")

FIRST_LOOK_MAX_COST = 0.4  # 1 - NCC: pixels matched at least this well
FIRST_LOOK_MIN_VIEWS = 2.0  # TSDF weight: voxels at least two coarse maps saw


def first_look_frames(maps: dict[str, tuple], max_cost: float = FIRST_LOOK_MAX_COST) -> list[DepthFrame]:
    """Depth frames from coarse maps ``{name: (view at the map's resolution, depth, normal, cost)}``: the depth
    where it is finite, positive and matched with a cost below ``max_cost``, else 0."""
    frames = []
    for name in sorted(maps):
        view, depth, _normal, cost = maps[name][:4]
        d = np.asarray(depth, np.float32)
        if d.shape != (view.intrinsics.height, view.intrinsics.width):
            raise ValueError(f"first look: view {name}: depth map {d.shape} does not match its view "
                             f"{view.intrinsics.height}x{view.intrinsics.width}")
        ok = np.isfinite(d) & (d > 0)
        if cost is not None:
            ok &= np.asarray(cost) < max_cost
        frames.append(DepthFrame(view=view, depth=np.where(ok, d, 0).astype(np.float32)))
    return frames


def first_look_mesh(maps: dict[str, tuple], cfg: FusionConfig | None = None, cameras: list[View] | None = None,
                    max_cost: float = FIRST_LOOK_MAX_COST, min_views: float = FIRST_LOOK_MIN_VIEWS) -> trimesh.Trimesh:
    """The mesh of the coarse maps (see the module docstring): TSDF fusion at ``cfg``'s voxel in pixel footprints
    of the coarse maps (so a few times coarser than the full result's), voxels seen by at least ``min_views``
    maps, then cleaned (``mesh.clean``: debris and floaters; no hole filling, no support removal).
    Raises ``NoDepthError`` / ``EmptyMeshError`` when nothing is left."""
    cfg = replace(cfg or FusionConfig(), mesher="tsdf", voxel_size=None, voxels_across=None, normal_sdf=0.0,
                  weight_threshold=max(min_views, 1.0), chunk_voxels=None)
    frames = first_look_frames(maps, max_cost)
    mesh = tsdf_fuse(frames, cfg)
    return clean(mesh, CleanConfig(fill_holes_voxels=0.0, closed="off", scene="open"), cameras=cameras or [f.view for f in frames])
