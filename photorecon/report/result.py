"""A result to look at: the mesh, cameras and photos of a result folder (``reconstruct`` or ``fuse`` output) or
of a mesh file, read while another photorecon run may be writing the folder."""
from __future__ import annotations

import json
import logging
from pathlib import Path

import trimesh

from ..cameras import View
from ..io.paths import inside
from ..layout import Layout

log = logging.getLogger("photorecon")

MESH_NAMES = ("mesh.ply", "mesh.glb", "mesh.obj")


def find_mesh(folder: Path) -> Path | None:
    for name in MESH_NAMES:
        if (folder / name).is_file():
            return folder / name
    return None


def writing_run(folder: str | Path) -> str | None:
    """The photorecon run (another process) that is writing the result folder ``folder`` now, in words
    (``process PID: COMMAND``), or None: nobody holds its lock (``OUT/.photorecon.lock``), or that cannot be
    told (no ``flock`` on this file system)."""
    import os

    from ..io.output import LOCK

    try:
        import fcntl
    except ImportError:  # pragma: no cover (Windows)
        return None
    try:
        fd = os.open(Path(folder) / LOCK, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            return None  # not held: no run, or a stale lock
        except BlockingIOError:
            pass
        except OSError:
            return None
        try:
            info = json.loads(os.pread(fd, 4096, 0).decode("utf-8", "replace") or "{}")
        except (OSError, ValueError):
            info = {}
        info = info if isinstance(info, dict) else {}
        return f"process {info.get('pid', '?')}" + (f": {info['command']}" if info.get("command") else "")
    finally:
        os.close(fd)


# while a run writes the folder, a file may be between its two renames (a folder swapped in): tried again so long
LOAD_RETRY_SECONDS = 3.0


def load_result(path: str | Path) -> tuple[trimesh.Trimesh, list[View], dict[str, Path]]:
    """A result to look at: ``path`` is a result folder (``reconstruct`` or ``fuse`` output: OUT/mesh.ply,
    .glb or .obj, cameras from OUT/sparse/0 or OUT/transforms.json when there, images in OUT/images) or a
    mesh file (with the cameras of its folder when it has any; OUT/textured and a mesh in it: OUT's). Returns (mesh, cameras, view name -> image file). Raises ``InputDataError`` (no mesh, a
    mesh without faces, unreadable cameras).

    A folder that another photorecon run is writing (``writing_run``) is read as it is (its last complete
    stages: every file and folder there is replaced whole), with a warning; a read that fails is tried again
    for ``LOAD_RETRY_SECONDS`` (a folder being swapped in), then the error names the run."""
    import time

    from ..errors import InputDataError

    p = Path(path)
    folder = p if p.is_dir() else p.parent
    deadline = time.monotonic() + LOAD_RETRY_SECONDS
    while True:
        try:
            result = _load_result(p)
        except (InputDataError, OSError) as exc:
            run = writing_run(folder)
            if run is None:
                raise
            if time.monotonic() < deadline:
                time.sleep(0.2)
                continue
            if isinstance(exc, OSError):
                exc = InputDataError(f"{exc.filename or folder}: {exc.strerror or exc}")
            raise InputDataError(f"{exc}; a photorecon run ({run}) is writing {folder} now: look at it when the "
                                 "run has finished") from None
        run = writing_run(folder)
        if run is not None:
            log.warning("view: a photorecon run (%s) is writing %s now: showing what it holds at this moment "
                        "(its last complete stages); look again when the run has finished", run, folder)
        return result


def _load_result(path: Path) -> tuple[trimesh.Trimesh, list[View], dict[str, Path]]:
    from ..errors import InputDataError
    from ..mesh import load_mesh

    if path.is_dir():
        mesh_path = find_mesh(path)
        if mesh_path is None:
            raise InputDataError(f"{path}: no {', '.join(MESH_NAMES)}; expected the output folder of "
                                 "'photorecon reconstruct' or 'fuse', or a mesh file")
    elif path.is_file():
        mesh_path = path
    else:
        raise InputDataError(f"{path}: no such result folder or mesh file")
    mesh = load_mesh(mesh_path)  # InputDataError for an unreadable file or a mesh without faces
    folder = path if path.is_dir() else path.parent
    if Layout(folder.parent).textured == folder and not result_cameras(folder):
        folder = folder.parent  # OUT/textured (or a mesh in it): the cameras and photos of OUT
    cameras = result_cameras(folder)
    images = {}
    for v in cameras:
        p = inside(Layout(folder).images, v.image_file or v.name, f"view {v.name}")
        if p.is_file():
            images[v.name] = p
    return mesh, cameras, images


def result_model(path: str | Path) -> tuple[bytes, dict] | None:
    """A result folder's textured model for the live viewer: (OUT/model.glb's bytes, its placement in the frame of
    OUT's mesh and cameras, ``live.model_placement`` from report.json's texture section), or None when ``path`` is
    a mesh file or a folder without model.glb. A model whose placement cannot be read is left out with a warning
    (the mesh is shown)."""
    import json

    from .live import model_placement

    layout = Layout(path)
    glb = layout.model("glb")
    if not Path(path).is_dir() or not glb.is_file():
        return None
    try:
        report = json.loads(layout.report_json.read_text()) if layout.report_json.is_file() else {}
        placement = model_placement(report.get("texture") if isinstance(report, dict) else None)
        return glb.read_bytes(), placement
    except (OSError, ValueError) as exc:
        log.warning("view: %s is not shown (%s); showing the mesh", glb, exc)
        return None


def result_cameras(folder: Path) -> list[View]:
    """The cameras of a result folder (OUT/sparse/0 or OUT/transforms.json), or [] when it has none."""
    if not (Layout(folder).sparse.is_dir() or Layout(folder).transforms.is_file()):
        return []
    from ..io.dataset import read_model

    return read_model(folder).views
