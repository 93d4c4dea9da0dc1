"""COLMAP binary models through pycolmap (``cameras.bin``, ``images.bin``, ``points3D.bin``).

With ``photorecon.poses.sfm`` and ``photorecon.poses.triangulate``, the only modules that import pycolmap, always inside a
function (its API changes between versions; pycolmap 4.x: ``image.cam_from_world()`` is a method). Text models
are read and written without it (``colmap_text``). COLMAP's half-pixel convention is converted here, through
``conventions``, as in ``colmap_text``. Found in a dataset folder as ``colmap_text`` finds
its text model (cameras.bin where cameras.txt would be).
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from ...cameras import View
from ...conventions import intrinsics_from_colmap, opencv_from_colmap_pixels
from ...errors import BadArgumentError, InputDataError
from ..paths import inside
from .colmap_text import colmap_folder, write_colmap_text
from .model import SparseModel

NAME = "colmap-bin"
SUFFIX = None  # written as a folder


def detect(path: Path) -> Path | None:
    found = colmap_folder(path)
    return found[0] if found and found[1] == "binary" else None


def read(path: Path, **options) -> SparseModel:
    return read_colmap_binary(path)


def write(model: SparseModel, path: Path, **options) -> Path:
    return write_colmap_binary(model, path)


def _check_pose(pose, where: str):
    """A pose pycolmap read as it was stored: a zero quaternion (which pycolmap turns into the identity) or
    non-finite numbers raise ``InputDataError``."""
    q = np.asarray(getattr(getattr(pose, "rotation", None), "quat", [0.0, 0.0, 0.0, 1.0]), float)
    t = np.asarray(getattr(pose, "translation", [0.0, 0.0, 0.0]), float)
    if not (np.isfinite(q).all() and np.isfinite(t).all()):
        raise InputDataError(f"{where}: its rotation and translation must be finite, got {q.tolist()} {t.tolist()}")
    if not np.any(q):
        raise InputDataError(f"{where}: zero quaternion; the rotation must be a unit quaternion, e.g. 1 0 0 0 "
                             "(QW QX QY QZ) for none")


def sparse_from_pycolmap(rec, where: str = "COLMAP model") -> SparseModel:
    """A pycolmap ``Reconstruction`` as a ``SparseModel`` (registered images only); ``where`` names the model in
    errors. Image names are checked by ``paths.inside`` (relative, not leaving the image folder)."""
    views, obs = [], {}
    for image_id in sorted(rec.reg_image_ids()):
        image = rec.images[image_id]
        cam = rec.cameras[image.camera_id]
        model = cam.model.name if hasattr(cam.model, "name") else str(cam.model)
        try:
            intr = intrinsics_from_colmap(model, cam.width, cam.height, list(cam.params))
        except BadArgumentError as exc:
            raise InputDataError(f"image {image.name}: {exc}") from None
        pose = image.cam_from_world()
        _check_pose(pose, f"{where}: image {image.name}")
        M = np.eye(4)
        M[:3] = pose.matrix()
        inside(None, image.name, f"{where} image {image_id}")
        stem = Path(image.name).stem
        views.append(View(stem, intr, M, image_file=image.name, extra={"colmap_image_id": int(image_id)}))
        pts = image.points2D
        xy = opencv_from_colmap_pixels(np.array([p.xy for p in pts], float).reshape(-1, 2))
        ids = np.array([p.point3D_id if p.has_point3D() else -1 for p in pts], np.int64)
        obs[stem] = (xy, ids)
    pids = np.array(sorted(rec.point3D_ids()), np.int64) if rec.num_points3D() else np.zeros(0, np.int64)
    xyz = np.array([rec.points3D[int(i)].xyz for i in pids], float).reshape(-1, 3)
    rgb = np.array([rec.points3D[int(i)].color for i in pids], np.uint8).reshape(-1, 3)
    err = np.array([rec.points3D[int(i)].error for i in pids], float)
    return SparseModel(views, xyz, rgb, pids, err, obs)


def read_colmap_binary(folder: str | Path) -> SparseModel:
    """A COLMAP binary model (cameras.bin, images.bin, points3D.bin) as a ``SparseModel``."""
    import pycolmap

    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as exc:  # pycolmap raises RuntimeError/ValueError on unreadable models
        raise InputDataError(f"{folder}: cannot read the COLMAP model ({exc})") from None
    return sparse_from_pycolmap(rec, str(folder))


def write_colmap_binary(model: SparseModel, folder: str | Path) -> Path:
    """Write ``model`` as a COLMAP binary model (through a text copy that pycolmap converts)."""
    import pycolmap

    folder = Path(folder)
    with tempfile.TemporaryDirectory() as tmp:
        write_colmap_text(model, tmp)
        rec = pycolmap.Reconstruction(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        rec.write_binary(str(folder))
    return folder
