"""Camera files of two NeRF-era dataset layouts, read and written: IDR / NeuS ``cameras_sphere.npz`` and
LLFF ``poses_bounds.npy``. Both pair the i-th camera with the i-th image file in sorted order.

IDR / NeuS (``SCENE/cameras_sphere.npz`` or ``cameras.npz``, images in ``SCENE/image/``, or ``SCENE/images/``
as many copies of the layout name it; masks in ``SCENE/mask/`` or ``SCENE/masks/``):

* ``world_mat_i`` (3x4 or 4x4) is the projection ``K [R | t]`` (up to scale) from the *original* world to
  pixels; ``scale_mat_i`` maps the *normalised* world (the object inside the unit sphere) to the original one:
  ``X_world = scale_mat @ X_norm``, so NeuS projects ``X_norm`` with ``P = world_mat @ scale_mat``.
  ``world="normalized"`` (default, what the NeuS / IDR loaders train in) decomposes that product;
  ``world="original"`` decomposes ``world_mat`` alone (e.g. DTU's millimetres, the frame of its reference scans).
* ``K`` is taken in OpenCV's pixel convention, pixel (0, 0) = centre of the top-left pixel: the NeuS loader
  casts rays through integer pixel indices with ``K^-1``. The decomposition makes K's diagonal positive and
  R a proper rotation; a tiny skew (from the numerics of DTU's calibration) is dropped and kept in
  ``View.extra["skew"]`` (logged when it moves a pixel by more than 0.01 px).

LLFF (``SCENE/poses_bounds.npy``, images in ``SCENE/images/``): N x 17, per image a 3x5 matrix flattened
row-major, then ``near, far``. Its columns: the camera-to-world rotation in LLFF camera axes
(x down, y right, z backward), the camera centre, and ``[H, W, focal]``. The principal point is the image
centre. Images whose size differs from (W, H) (LLFF's ``images_4``-style downscales) get scaled intrinsics.

Both list their image folder through ``paths.files_inside``: a link to a file outside it is refused.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import scipy.linalg

from ..cameras import Intrinsics, View, camera_center
from ..conventions import opencv_from_opengl, opengl_from_opencv
from ..errors import BadArgumentError, InputDataError
from .atomic import atomic_path
from .nerf import image_size
from .paths import IMAGE_SUFFIXES, files_inside

log = logging.getLogger("photorecon")

NEUS_FILES = ("cameras_sphere.npz", "cameras.npz")
NEUS_WORLDS = ("normalized", "original")
# LLFF camera axes (x down, y right, z backward) <- OpenGL camera axes (x right, y up, z backward):
# world_from_cam_gl[:3, :3] = llff_rotation @ LLFF_FROM_GL, as LLFF's own loader does
# (``concatenate([poses[:, 1:2], -poses[:, 0:1], poses[:, 2:]])``). TODO: move to conventions.py.
LLFF_FROM_GL = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])


NEUS_IMAGES = ("image", "images")
NEUS_MASKS = ("mask", "masks")


def sorted_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` in sorted name order (as the NeuS / IDR / LLFF loaders list them; hidden files
    skipped, as their ``glob`` does); a link to a file outside ``folder`` raises ``InputDataError``."""
    return files_inside(folder, IMAGE_SUFFIXES)


def _neus_folder(scene: Path, names: tuple[str, ...]) -> Path:
    """The first of ``scene/NAME`` holding images (IDR's ``image/``, else ``images/``), else the first one."""
    return next((scene / n for n in names if sorted_images(scene / n)), scene / names[0])


def _check_count(path: Path, n: int, images: list[Path], folder: Path):
    if not images:
        raise InputDataError(f"{path}: no images in {folder}; the i-th camera belongs to the i-th sorted image there")
    if len(images) != n:
        raise InputDataError(f"{path}: {n} cameras but {len(images)} images in {folder}; camera i belongs to the "
                             "i-th sorted image, so the counts must match (remove the extra images or cameras)")


# --- IDR / NeuS -------------------------------------------------------------------------------------------
def decompose_projection(P, what: str) -> tuple[np.ndarray, np.ndarray]:
    """3x4 projection (up to scale, any sign) -> (K 3x3 with positive diagonal and K[2,2] = 1, cam_from_world
    4x4 with a proper rotation). Points in front of the camera have positive depth."""
    P = np.asarray(P, float)
    M = P[:, :3]
    if not np.isfinite(P).all() or abs(np.linalg.det(M)) < 1e-12 * max(np.abs(M).max(), 1e-300) ** 3:
        raise InputDataError(f"{what}: not a finite projection matrix with an invertible left 3x3")
    K, R = scipy.linalg.rq(M)
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R  # K R unchanged (D D = I)
    if np.linalg.det(R) < 0:  # M = -K R' with R' proper: the same projection, scaled by -1
        R = -R
    C = -np.linalg.solve(M, P[:, 3])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ C
    return K / K[2, 2], T


def _neus_file(path: Path) -> Path:
    if path.is_dir():
        for name in NEUS_FILES:
            if (path / name).is_file():
                return path / name
        raise InputDataError(f"{path}: no {' or '.join(NEUS_FILES)}")
    return path


def read_neus(path: str | Path, world: str = "normalized") -> list[View]:
    """Views from an IDR / NeuS camera file (or the folder holding it); images from ``image/`` (or
    ``images/``) next to it, masks from ``mask/`` (or ``masks/``) when there is one per camera."""
    if world not in NEUS_WORLDS:
        raise BadArgumentError(f"NeuS world: expected one of {NEUS_WORLDS}, got {world!r}")
    path = _neus_file(Path(path))
    try:
        with np.load(path, allow_pickle=False) as z:
            raw = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise InputDataError(f"{path}: no such file") from None
    except Exception as exc:  # zip / pickle errors: all mean "not a camera npz"
        raise InputDataError(f"{path}: not a readable .npz ({exc})") from None
    data = {}
    for k, a in raw.items():
        if k.startswith(("world_mat_", "scale_mat_")) and not (np.issubdtype(a.dtype, np.number)
                                                                and not np.issubdtype(a.dtype, np.complexfloating)):
            raise InputDataError(f"{path}: {k} holds {a.dtype} values; expected a matrix of real numbers")
        if np.issubdtype(a.dtype, np.number) and not np.issubdtype(a.dtype, np.complexfloating):
            data[k] = np.asarray(a, float)
    if "world_mat_0" not in data:
        raise InputDataError(f"{path}: no 'world_mat_0'; an IDR/NeuS camera file holds world_mat_i (and scale_mat_i) "
                             f"for i = 0..N-1, found keys {sorted(data)[:6]}")
    n = 0
    while f"world_mat_{n}" in data:
        n += 1
    folder = _neus_folder(path.parent, NEUS_IMAGES)
    images = sorted_images(folder)
    _check_count(path, n, images, folder)
    masks = sorted_images(_neus_folder(path.parent, NEUS_MASKS))
    no_scale = [i for i in range(n) if f"scale_mat_{i}" not in data]
    if world == "normalized" and no_scale:
        log.warning("%s: no scale_mat for %d camera(s); the normalised world is the original one there", path,
                    len(no_scale))
    views = []
    for i, img in enumerate(images):
        W = data[f"world_mat_{i}"]
        S = data.get(f"scale_mat_{i}", np.eye(4))
        if W.shape not in ((3, 4), (4, 4)) or S.shape != (4, 4):
            raise InputDataError(f"{path}: world_mat_{i} must be 3x4 or 4x4 and scale_mat_{i} 4x4, got "
                                 f"{W.shape} and {S.shape}")
        for name, A in ((f"world_mat_{i}", W), (f"scale_mat_{i}", S)):
            if not np.isfinite(A).all():
                raise InputDataError(f"{path}: {name} holds {int((~np.isfinite(A)).sum())} NaN or infinite "
                                     "entries; every camera needs a finite matrix")
        P = (W[:3] @ S) if world == "normalized" else W[:3]
        K, T = decompose_projection(P, f"{path} world_mat_{i}")
        w, h = image_size(img, f"{path} camera {i}")
        try:
            intr = Intrinsics(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        except BadArgumentError as exc:
            raise InputDataError(f"{path} camera {i}: {exc}") from None
        extra = {"neus_index": i}
        if abs(K[0, 1]) > 0:
            extra["skew"] = float(K[0, 1])
            shift = abs(K[0, 1]) * (h / 2) / K[1, 1]
            if shift > 0.01:
                log.warning("%s camera %d: skew %.3g dropped (moves pixels by up to %.2f px)", path, i, K[0, 1], shift)
        mask_file = str(masks[i]) if len(masks) == n else None
        views.append(View(img.stem, intr, T, image_path=str(img), extra=extra, image_file=img.name, mask_file=mask_file))
    return views


def _file_order(views: list[View]) -> list[View]:
    return sorted(views, key=lambda v: v.image_file or v.name)


def neus_scale_mat(points: np.ndarray, margin: float = 1.1) -> np.ndarray:
    """``scale_mat`` putting ``points`` (N, 3; the 1st-99th percentile box) inside the unit sphere, or the
    identity without points."""
    S = np.eye(4)
    if len(points) < 4:
        return S
    lo, hi = np.percentile(points, [1, 99], axis=0)
    inside = points[np.all((points >= lo) & (points <= hi), axis=1)]
    center = (lo + hi) / 2
    radius = margin * np.linalg.norm(inside - center, axis=1).max() if len(inside) else 1.0
    S[:3, :3] *= radius
    S[:3, 3] = center
    return S


def write_neus(views: list[View], path: str | Path, scale_mat: np.ndarray | None = None,
               points: np.ndarray | None = None) -> Path:
    """Write ``cameras_sphere.npz``: ``world_mat_i`` = 4x4 ``[K [R|t]; 0 0 0 1]`` in photorecon's world (the
    original world) and ``scale_mat_i`` = ``scale_mat`` (default: the unit sphere around ``points``, else
    the identity). Camera i is the view whose image file sorts i-th, as the NeuS loader pairs them."""
    path = Path(path)
    if not views:
        raise InputDataError(f"{path}: no cameras to write")
    S = neus_scale_mat(np.zeros((0, 3)) if points is None else np.asarray(points, float)) if scale_mat is None \
        else np.asarray(scale_mat, float)
    if S.shape != (4, 4):
        raise BadArgumentError(f"scale_mat: expected 4x4, got {S.shape}")
    out = {}
    for i, v in enumerate(_file_order(views)):
        if v.intrinsics.has_distortion:
            raise InputDataError(f"{path}: view {v.name} has lens distortion, which IDR/NeuS cameras cannot hold; "
                                 "undistort first")
        Wm = np.eye(4)
        Wm[:3] = v.intrinsics.K @ v.cam_from_world[:3]
        out[f"world_mat_{i}"] = Wm
        out[f"scale_mat_{i}"] = S
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **out)
    return path


# --- LLFF -------------------------------------------------------------------------------------------------
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
    _check_count(path, len(arr), images, folder)
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
    for v in _file_order(views):
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
