"""LLFF cameras, read and written (``SCENE/poses_bounds.npy``, images in ``SCENE/images/``): N x 17, per image a
3x5 matrix flattened row-major, then ``near, far``. Its columns: the camera-to-world rotation in LLFF camera axes
(x down, y right, z backward), the camera centre, and ``[H, W, focal]``. The principal point is the image
centre. Images whose size differs from (W, H) (LLFF's ``images_4``-style downscales) get scaled intrinsics.

Camera i is paired with the i-th image file in sorted order (``common.sorted_images``, through
``paths.files_inside``: a link to a file outside the folder is refused).
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ...cameras import Intrinsics, View, camera_center
from ...conventions import opencv_from_opengl, opengl_from_opencv
from ...errors import BadArgumentError, InputDataError
from ..atomic import atomic_path
from .common import check_count, file_order, image_size, sorted_images
from .model import SparseModel

log = logging.getLogger("photorecon")

NAME = "llff"
LOOKS_FOR = "poses_bounds.npy (LLFF)"
FILE_NAME = "poses_bounds.npy"
SUFFIX = ".npy"
# LLFF camera axes (x down, y right, z backward) <- OpenGL camera axes (x right, y up, z backward):
# world_from_cam_gl[:3, :3] = llff_rotation @ LLFF_FROM_GL, as LLFF's own loader does
# (``concatenate([poses[:, 1:2], -poses[:, 0:1], poses[:, 2:]])``). TODO: move to conventions.py.
LLFF_FROM_GL = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])


def detect(path: Path) -> Path | None:
    """A ``.npy`` file, or a folder holding poses_bounds.npy."""
    if path.is_file():
        return path if path.suffix == ".npy" else None
    return path if (path / "poses_bounds.npy").is_file() else None


def read(path: Path, **options) -> SparseModel:
    return SparseModel(read_llff(path))


def write(model: SparseModel, path: Path, bounds: tuple[float, float] | None = None, **options) -> Path:
    return write_llff(model.views, path, points=model.points, bounds=bounds, points_of=model.points_seen_by)


def auto_output(path: Path) -> bool:
    return path.suffix == ".npy"


def read_llff(path: str | Path) -> list[View]:
    """Views from ``poses_bounds.npy`` (or the folder holding it); images from ``images/`` next to it.
    ``View.extra["near"]``, ``["far"]`` hold the file's depth bounds (in scene units)."""
    path = Path(path)
    if path.is_dir():
        path = path / "poses_bounds.npy"
    try:
        arr = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise InputDataError(f"{path}: no such file") from None
    except Exception as exc:
        raise InputDataError(f"{path}: not a readable .npy ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != 17:
        raise InputDataError(f"{path}: expected an N x 17 array (3x5 pose-and-hwf matrix + near, far per image), "
                             f"got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or np.issubdtype(arr.dtype, np.complexfloating):
        raise InputDataError(f"{path}: expected an N x 17 array of real numbers, got {arr.dtype} values")
    if len(arr) == 0:
        raise InputDataError(f"{path}: holds no camera (0 rows); expected one row per image in images/")
    arr = arr.astype(float)
    folder = path.parent / "images"
    images = sorted_images(folder)
    check_count(path, len(arr), images, folder)
    views = []
    for i, (row, img) in enumerate(zip(arr, images)):
        where = f"{path} row {i}"
        M = row[:15].reshape(3, 5)
        H, W, f = M[:, 4]
        if not np.isfinite(row).all():
            names = [f"pose[{r},{c}]" for r in range(3) for c in range(5)] + ["near", "far"]
            bad = [n for n, x in zip(names, row) if not np.isfinite(x)]
            raise InputDataError(f"{where}: {', '.join(bad)} not finite; every row needs 17 finite numbers")
        if not (np.isfinite(row).all() and H >= 1 and W >= 1 and f > 0 and H == round(H) and W == round(W)):
            raise InputDataError(f"{where}: expected finite values, integer H, W >= 1 and focal > 0, got "
                                 f"H={H:g} W={W:g} focal={f:g}")
        world_from_cam_gl = np.eye(4)
        world_from_cam_gl[:3, :3] = M[:, :3] @ LLFF_FROM_GL
        world_from_cam_gl[:3, 3] = M[:, 3]
        try:
            T = opencv_from_opengl(world_from_cam_gl)
        except BadArgumentError as exc:
            raise InputDataError(f"{where}: {exc}") from None
        W, H = int(round(W)), int(round(H))
        intr = Intrinsics(W, H, f, f, (W - 1) / 2, (H - 1) / 2)
        w, h = image_size(img, where)
        if (w, h) != (W, H):
            if abs(h * W - w * H) > min(W, H):
                raise InputDataError(f"{where}: image {img} is {w}x{h}, not a resize of the file's {W}x{H}")
            intr = intr.scaled(w, h)
        views.append(View(img.stem, intr, T, image_path=str(img),
                          image_file=img.name, extra={"near": float(row[15]), "far": float(row[16])}))
    return views


def llff_bounds(view: View, points: np.ndarray) -> tuple[float, float] | None:
    """LLFF's near / far for ``view``: the 0.1 and 99.9 percentiles of the depths of ``points`` in front of it
    (as LLFF's ``imgs2poses.py``), or None without such points."""
    if len(points) == 0:
        return None
    z = (points @ view.cam_from_world[:3, :3].T + view.cam_from_world[:3, 3])[:, 2]
    z = z[z > 0]
    if len(z) == 0:
        return None
    return float(np.percentile(z, 0.1)), float(np.percentile(z, 99.9))


def write_llff(views: list[View], path: str | Path, points: np.ndarray | None = None,
               bounds: tuple[float, float] | None = None, points_of=None, tol_px: float = 0.5) -> Path:
    """Write ``poses_bounds.npy`` (rows in sorted image-file order). Near / far per view: ``bounds`` if
    given, else from the sparse points it sees (``points_of(name)``, else all ``points``), else the view's
    own ``extra["near"/"far"]``. LLFF holds one focal length and a centred principal point: other cameras
    are refused (``InputDataError``); principal points up to ``tol_px`` off centre are written as centred."""
    path = Path(path)
    if not views:
        raise InputDataError(f"{path}: no cameras to write")
    all_points = np.zeros((0, 3)) if points is None else np.asarray(points, float)
    rows = []
    for v in file_order(views):
        i = v.intrinsics
        off = max(abs(i.cx - (i.width - 1) / 2), abs(i.cy - (i.height - 1) / 2))
        if i.has_distortion or abs(i.fx - i.fy) > 1e-6 * i.fx or off > tol_px:
            raise InputDataError(f"{path}: view {v.name} (fx={i.fx:g} fy={i.fy:g}, principal point {off:.2f} px off "
                                 "centre, distortion: {}) cannot be written: LLFF holds one focal length, a centred "
                                 "principal point and no distortion".format(i.has_distortion))
        if off > 1e-6:
            log.warning("%s: view %s's principal point is %.3f px off centre; written as centred", path, v.name, off)
        if bounds is not None:
            nf = (float(bounds[0]), float(bounds[1]))
        else:
            seen = points_of(v.name) if points_of is not None else np.zeros((0, 3))
            nf = llff_bounds(v, seen if len(seen) else all_points)
            if nf is None and "near" in v.extra and "far" in v.extra:
                nf = (float(v.extra["near"]), float(v.extra["far"]))
            if nf is None:
                raise InputDataError(f"{path}: no sparse points in front of view {v.name} to bound its depth; "
                                     "convert a model with points or give the bounds (--bounds NEAR FAR)")
        world_from_cam_gl = opengl_from_opencv(v.cam_from_world)
        M = np.zeros((3, 5))
        M[:, :3] = world_from_cam_gl[:3, :3] @ LLFF_FROM_GL.T
        M[:, 3] = camera_center(v.cam_from_world)
        M[:, 4] = [i.height, i.width, i.fx]
        rows.append(np.concatenate([M.ravel(), nf]))
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, np.array(rows))
    return path
