"""The original article's mesher, kept as a baseline: one grid mesh per view, concatenated.
"""
from __future__ import annotations

import trimesh

from .config import DepthFrame
from .grid import grid_mesh_view


def legacy_article_fuse(frames: list[DepthFrame], max_edge: float = 0.1) -> trimesh.Trimesh:
    """The original article's pipeline, for comparison only: grid-mesh each view, drop triangles with an edge
    longer than a fixed ``max_edge`` (scene units), and concatenate the per-view meshes (overlapping shells)."""
    parts = []
    for f in frames:
        m = grid_mesh_view(f, max_stretch=None)
        if len(m.faces):
            e = m.edges_unique_length[m.faces_unique_edges].max(1)
            m.update_faces(e <= max_edge)
            parts.append(m)
    return trimesh.util.concatenate(parts)
