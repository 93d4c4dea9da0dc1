"""The surface of the textured model (``OUT/model.glb``, ``mesh.model``): open or closed (``--model-surface``), and
the closed surface's invented faces, those its closing added (the underside an object stood on, holes no photo saw
into): found on the closed companion (``invented_faces``), carried through the model's simplification
(``carry_marks``). The model textures its seen faces from the photos and colours the invented ones from the seen
faces around them, a part of their own with the material "invented".
"""
from __future__ import annotations

import numpy as np
import trimesh

from ..layout import Layout


def model_surface(mesh: trimesh.Trimesh, setting: str, layout: Layout,
                  fusion: dict | None = None) -> tuple[trimesh.Trimesh, np.ndarray | None, str]:
    """The surface the model is made of, by ``setting`` (``ModelConfig.model_surface``): ``mesh`` (the open,
    cleaned mesh) or the run's closed companion (``layout``'s mesh_closed.ply with its ``filled`` marks;
    ``close.closed_companion`` of ``mesh`` when the run wrote none as PLY) with its invented faces
    (``invented_faces``). auto: closed when the run has a companion (``fusion``: the fusion stage's facts, its
    ``closed``; without them: the files). Returns (surface, invented (F,) bool or None for the open one, why)."""
    from .close import closed_companion
    from .export import MESH_FORMATS, load_mesh

    fusion = fusion if isinstance(fusion, dict) else {}
    has = bool(fusion["closed"]) if "closed" in fusion else any(layout.mesh_closed(f).is_file() for f in MESH_FORMATS)
    if setting == "open":
        return mesh, None, "--model-surface open"
    if setting == "auto" and not has:
        return mesh, None, "no closed companion: an open scene, or --closed off"
    closed = filled = None
    if has and layout.mesh_closed("ply").is_file():
        closed = load_mesh(layout.mesh_closed("ply"))
        try:  # the PLY's face property (trimesh keeps the file's elements in the metadata)
            filled = np.asarray(closed.metadata["_ply_raw"]["face"]["data"]["filled"]).reshape(-1)
        except (KeyError, TypeError, ValueError):
            pass
    if filled is None or len(filled) != len(closed.faces):  # no PLY with its marks: closed here, as the fusion does
        src = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        src.metadata = cleaning_facts(mesh, fusion)
        closed = closed_companion(src)[0]
        filled = closed.face_attributes.get("filled")
    why = "--model-surface closed" if setting == "closed" else "an object capture: its closed companion, mesh_closed"
    return closed, invented_faces(mesh, closed, filled), why


def cleaning_facts(mesh: trimesh.Trimesh, fusion: dict | None) -> dict:
    """The cleaning's facts that the model's frame and its closing read (what ``--scene`` detected, the support
    plane, the voxel), as the mesh carries them or as the fusion stage recorded them (a mesh read from disk)."""
    return {k: v for src in (getattr(mesh, "metadata", None) or {}, fusion if isinstance(fusion, dict) else {})
            for k, v in src.items() if k in ("scene", "support_normal", "support_offset", "voxel_size")}


def invented_faces(mesh: trimesh.Trimesh, closed: trimesh.Trimesh, filled) -> np.ndarray:
    """(F,) bool over ``closed``'s faces: those its closing invented, marked ``filled`` and off ``mesh``, the open
    surface it closes (their centroid farther than a hundredth of ``mesh``'s median edge from it). The cleaning's
    own fills, small holes the photos face (marked in ``mesh`` too), lie on ``mesh``: they stay seen."""
    import open3d.core as o3c

    from .convert import raycasting_scene
    from .geometry import face_edges

    out = np.asarray(filled if filled is not None else np.zeros(len(closed.faces)), np.int64).reshape(-1) > 0
    if not out.any():
        return out
    V, e = np.asarray(mesh.vertices, np.float64), face_edges(np.asarray(mesh.faces, np.int64))
    edge = float(np.median(np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1)))
    centre = np.asarray(closed.triangles_center, np.float32)[out]
    out[out] = raycasting_scene(mesh).compute_distance(o3c.Tensor(centre)).numpy() > 0.01 * edge
    return out


def carry_marks(src: trimesh.Trimesh, marks: np.ndarray, dst: trimesh.Trimesh) -> np.ndarray:
    """``marks`` (one per face of ``src``) carried onto the faces of ``dst``, ``src`` simplified: each face takes
    the mark of the face of ``src`` nearest to its centroid.

    The invented faces are carried through the simplification, not found again by their distance to the seen
    ones: a decimated face lies within a fraction of its edge of the faces it stands for, so the nearest face of
    ``src`` is one of them at any scale, where a distance threshold needs a scale, and would call seen the
    invented faces next to the rim (and all of a fill that lies close to the surface: a thin object's base)."""
    import open3d.core as o3c

    from .convert import raycasting_scene

    centre = o3c.Tensor(np.asarray(dst.triangles_center, np.float32))
    return np.asarray(marks)[raycasting_scene(src).compute_closest_points(centre)["primitive_ids"].numpy()]
