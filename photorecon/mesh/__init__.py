"""Mesh: the fused mesh in, the cleaned mesh and its files out.

- ``geometry``: per-triangle quantities (edge cross products, areas, centres) the other modules share.
- ``convert``: the Open3D conversions and operations (ray casting, screened Poisson, the largest piece).
- ``solve``: sparse symmetric solves and the uniform graph Laplacian (``harmonic_fill``: values diffused over
  a graph).
- ``clean``: floaters and small components removed, hole filling, simplification to a face budget
  (``CleanConfig``, ``clean``).
- ``boundary``: the rims of holes (``boundary_loops``) and their measures; ``patch``: a faired patch over given
  rims (``fill_loops``); ``fill``: hole filling that keeps the observed surface (``fill_small_holes``);
  ``close``: the watertight companion of an object (``closed_companion``).
- ``support``: for object captures, the plane the object stands on and the support removed.
- ``scene``: whether a capture is an object or an open scene, from its cameras.
- ``texture``: a texture atlas from the images (``TextureConfig``, ``texture_output``); ``atlas``: its charts
  and their packing.
- ``export``: PLY / OBJ / GLB written atomically; any mesh file loaded.

In-memory meshes are trimesh ``Trimesh`` with ``process=False``: geometry is never rewritten behind the
caller's back.
"""
from .geometry import face_areas, face_centres, face_cross, triangle_components
from .convert import from_open3d, largest_piece, open3d_fill_holes, poisson_surface, raycasting_scene, to_open3d
from .solve import harmonic_fill
from .boundary import boundary_length, boundary_loops
from .patch import fill_loops, filled_area
from .fill import fill_small_holes
from .close import close_mesh, closed_companion
from .clean import CleanConfig, boundary_edges, clean, clean_open3d, edge_use_counts, floater_mask, simplify
from .export import MESH_FORMATS, MESH_SUFFIXES, export, load_mesh, parse_formats
from .support import find_support, find_support_plane, ransac_plane, remove_support

__all__ = ["CleanConfig", "MESH_FORMATS", "MESH_SUFFIXES", "boundary_edges", "boundary_length", "boundary_loops",
           "clean", "clean_open3d", "close_mesh", "closed_companion", "edge_use_counts", "export", "face_areas",
           "face_centres", "face_cross", "fill_loops", "fill_small_holes", "filled_area", "find_support",
           "find_support_plane", "floater_mask", "from_open3d", "harmonic_fill", "largest_piece", "load_mesh",
           "open3d_fill_holes", "parse_formats", "poisson_surface", "ransac_plane", "raycasting_scene",
           "remove_support", "simplify", "to_open3d", "triangle_components"]
