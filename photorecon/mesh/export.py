"""Mesh files: the output formats (PLY, OBJ, GLB), export written atomically, and loading any mesh file."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..errors import BadArgumentError, EmptyMeshError, InputDataError
from ..io.atomic import atomic_path

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")
MESH_FORMATS = ("ply", "obj", "glb")


def parse_formats(text: str) -> tuple[str, ...]:
    """``"ply,glb"`` -> ("ply", "glb"); raises ``BadArgumentError`` for an empty list or an unknown format."""
    formats = tuple(f.strip().lower() for f in text.split(",") if f.strip())
    if not formats or any(f not in MESH_FORMATS for f in formats):
        raise BadArgumentError(f"--formats: expected ply, obj and/or glb, got {text!r}")
    return formats


def export(mesh: trimesh.Trimesh, path: str | Path) -> Path:
    """Write PLY (binary, vertex colours), OBJ or GLB by suffix, atomically."""
    path = Path(path)
    suf = path.suffix.lower()
    if suf[1:] not in MESH_FORMATS:
        raise BadArgumentError(f"{path}: unsupported mesh format; expected .ply, .obj or .glb")
    if not len(mesh.faces):
        raise EmptyMeshError(f"{path}: refusing to write an empty mesh")
    with atomic_path(path) as tmp:
        if suf == ".ply":
            data = trimesh.exchange.ply.export_ply(mesh, encoding="binary", vertex_normal=False)
            Path(tmp).write_bytes(data)
        else:
            mesh.export(tmp, file_type=suf[1:])
    return path


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """Load a mesh file as one ``Trimesh`` (scenes are concatenated), keeping texture/vertex colours.

    Raises ``InputDataError`` naming the file when it is missing, unreadable or has no faces.
    """
    path = Path(path)
    if not path.is_file():
        raise InputDataError(f"{path}: no such mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputDataError(f"{path}: unsupported mesh format {path.suffix!r}; expected one of {MESH_SUFFIXES}")
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InputDataError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)] if loaded.geometry else []
        loaded = trimesh.util.concatenate(geoms) if geoms else None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputDataError(f"{path}: the mesh has no faces; a triangle mesh is needed to render")
    check_finite_vertices(loaded.vertices, path)
    return loaded


def check_finite_vertices(vertices, path, what: str = "vertices") -> None:
    """Raise ``InputDataError`` naming ``path``, how many of ``vertices`` ((N, 3)) have a NaN or infinite
    coordinate and the index of the first, when any has."""
    bad = ~np.isfinite(np.asarray(vertices, np.float64).reshape(-1, 3)).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InputDataError(f"{path}: {int(bad.sum())} of {len(bad)} {what} have NaN or infinite coordinates "
                             f"(the first: index {first}); remove them or re-export the file")
