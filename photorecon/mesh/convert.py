"""Open3D conversions and the Open3D operations the mesh modules share: trimesh <-> Open3D meshes, a ray-casting
scene, screened Poisson surface reconstruction, the largest connected piece, Open3D's minimal hole closing.
Open3D is imported inside each function (it takes seconds to load); this module imports nothing of photorecon's."""
from __future__ import annotations

import numpy as np
import trimesh


def to_open3d(mesh: trimesh.Trimesh):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
                                  o3d.utility.Vector3iVector(np.asarray(mesh.faces, np.int32)))
    vc = _vertex_colors(mesh)
    if vc is not None:
        m.vertex_colors = o3d.utility.Vector3dVector(vc[:, :3].astype(np.float64) / 255.0)
    return m

def raycasting_scene(mesh: trimesh.Trimesh):
    """An Open3D ``RaycastingScene`` holding ``mesh`` (ray casting, closest points, distances)."""
    import open3d as o3d

    t = o3d.t.geometry.TriangleMesh()
    t.vertex.positions = o3d.core.Tensor(np.asarray(mesh.vertices, np.float32))
    t.triangle.indices = o3d.core.Tensor(np.asarray(mesh.faces, np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(t)
    return scene

def poisson_surface(cloud, depth: int):
    """Screened Poisson surface reconstruction (Open3D) of the oriented point ``cloud`` at octree ``depth``:
    (Open3D mesh, per-vertex sample density). One thread: with more, the same points give a different mesh
    from run to run (Open3D 0.20); one thread also costs fewer CPU seconds (the dark walnut's 1.1 M points
    at depth 10: 33 CPU s, 33 s wall, against 42 CPU s, 28 s wall on two threads)."""
    import open3d as o3d

    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(cloud, depth=int(depth), n_threads=1)
    return mesh, np.asarray(density)

def largest_piece(mesh, manifold: bool = False) -> trimesh.Trimesh:
    """The largest connected piece (by triangles) of ``mesh`` (trimesh or Open3D), duplicated vertices merged,
    as a trimesh; ``manifold``: also without the faces that make an edge non-manifold (Open3D's rule)."""
    import open3d as o3d

    m = mesh if isinstance(mesh, o3d.geometry.TriangleMesh) else to_open3d(mesh)
    m.remove_duplicated_vertices()
    labels, counts, _ = m.cluster_connected_triangles()
    labels = np.asarray(labels)
    if len(counts) > 1:
        m.remove_triangles_by_mask(labels != int(np.argmax(counts)))
        m.remove_unreferenced_vertices()
    if manifold:
        m.remove_non_manifold_edges()
    return from_open3d(m)

def from_open3d(m, block: int = 1 << 20) -> trimesh.Trimesh:
    """A trimesh copy of the Open3D mesh ``m`` (vertices, triangles, colours 0..255): it holds no reference to
    ``m``'s storage, so ``m`` is freed once its last reference goes. Colours converted ``block`` vertices at a
    time (no float copies of the whole colour array)."""
    colors = None
    if m.has_vertex_colors():
        vc = np.asarray(m.vertex_colors)
        colors = np.empty(vc.shape, np.uint8)
        for s in range(0, len(vc), block):
            colors[s:s + block] = np.clip(vc[s:s + block], 0, 1) * 255
    return trimesh.Trimesh(np.array(m.vertices), np.asarray(m.triangles), vertex_colors=colors, process=False)

def _vertex_colors(mesh: trimesh.Trimesh) -> np.ndarray | None:
    if mesh.visual.kind == "vertex":
        return np.asarray(mesh.visual.vertex_colors)
    return None


def open3d_fill_holes(mesh: trimesh.Trimesh, hole_size: float) -> trimesh.Trimesh:
    """Close holes that fit in a sphere of radius ``hole_size`` (scene units; Open3D's tensor ``fill_holes``,
    VTK's vtkFillHolesFilter)."""
    import open3d as o3d

    t = o3d.t.geometry.TriangleMesh.from_legacy(to_open3d(mesh))
    filled = t.fill_holes(hole_size=float(hole_size)).to_legacy()
    out = from_open3d(filled)
    return out if len(out.faces) >= len(mesh.faces) else mesh
