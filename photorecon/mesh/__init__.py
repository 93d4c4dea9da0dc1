"""Mesh: the fused mesh in, the cleaned mesh and its files out.

- ``geometry``: per-triangle quantities (edge cross products, areas, centres) the other modules share.
- ``clean``: floaters and small components removed, hole filling, simplification to a face budget
  (``CleanConfig``, ``clean``); the Open3D conversions.
- ``holes``: hole filling that keeps the observed surface (``fill_small_holes``), and the watertight companion
  of an object (``closed_companion``).
- ``support``: for object captures, the plane the object stands on and the support removed.
- ``scene``: whether a capture is an object or an open scene, from its cameras.
- ``texture``: a texture atlas from the images (``TextureConfig``, ``texture_output``); ``atlas``: its charts
  and their packing.
- ``export``: PLY / OBJ / GLB written atomically; any mesh file loaded.

In-memory meshes are trimesh ``Trimesh`` with ``process=False``: geometry is never rewritten behind the
caller's back.
"""
from .geometry import face_areas, face_centres, face_cross
from .clean import (CleanConfig, boundary_edges, clean, clean_open3d, edge_use_counts, fill_holes, floater_mask, from_open3d,
                    harmonic_fill, largest_piece, log, poisson_surface, raycasting_scene, simplify, to_open3d, triangle_components, _linked,
                    _vertex_colors, _weighted_percentile)
from .holes import (boundary_length, boundary_loops, close_mesh, closed_companion, fill_loops, fill_small_holes,
                    filled_area)
from .export import MESH_FORMATS, MESH_SUFFIXES, export, load_mesh, parse_formats
from .support import (find_support, find_support_plane, ransac_plane, remove_support, _look_at_point,
                      _support_rims)

__all__ = ["CleanConfig", "MESH_FORMATS", "MESH_SUFFIXES", "boundary_edges", "boundary_length", "boundary_loops",
           "clean", "close_mesh", "closed_companion", "fill_loops", "fill_small_holes", "filled_area", "clean_open3d", "edge_use_counts",
           "export", "face_areas", "face_centres", "face_cross",
           "fill_holes", "find_support", "find_support_plane", "floater_mask", "from_open3d", "harmonic_fill",
           "largest_piece", "load_mesh", "parse_formats", "poisson_surface", "ransac_plane", "raycasting_scene", "remove_support", "simplify",
           "to_open3d", "triangle_components"]
