"""IDR / NeuS cameras, read and written: ``SCENE/cameras_sphere.npz`` or ``cameras.npz``, images in ``SCENE/image/``
(or ``SCENE/images/``, as many copies of the layout name it), masks in ``SCENE/mask/`` or ``SCENE/masks/``.

* ``world_mat_i`` (3x4 or 4x4) is the projection ``K [R | t]`` (up to scale) from the *original* world to
  pixels; ``scale_mat_i`` maps the *normalised* world (the object inside the unit sphere) to the original one:
  ``X_world = scale_mat @ X_norm``, so NeuS projects ``X_norm`` with ``P = world_mat @ scale_mat``.
  ``world="normalized"`` (default, what the NeuS / IDR loaders train in) decomposes that product;
  ``world="original"`` decomposes ``world_mat`` alone (e.g. DTU's millimetres, the frame of its reference scans).
* ``K`` is taken in OpenCV's pixel convention, pixel (0, 0) = centre of the top-left pixel: the NeuS loader
  casts rays through integer pixel indices with ``K^-1``. The decomposition makes K's diagonal positive and
  R a proper rotation; a tiny skew (from the numerics of DTU's calibration) is dropped and kept in
  ``View.extra["skew"]`` (logged when it moves a pixel by more than 0.01 px).

Camera i is paired with the i-th image file in sorted order (``common.sorted_images``, through
``paths.files_inside``: a link to a file outside the folder is refused).
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import scipy.linalg

from ...cameras import Intrinsics, View
from ...errors import BadArgumentError, InputDataError
from ..atomic import atomic_path
from .common import check_count, file_order, image_size, sorted_images
from .model import SparseModel

log = logging.getLogger("photorecon")

NAME = "neus"
LOOKS_FOR = "cameras_sphere.npz (NeuS)"
FILE_NAME = "cameras_sphere.npz"
SUFFIX = ".npz"
NEUS_FILES = ("cameras_sphere.npz", "cameras.npz")
NEUS_WORLDS = ("normalized", "original")
NEUS_IMAGES = ("image", "images")
NEUS_MASKS = ("mask", "masks")


def detect(path: Path) -> Path | None:
    """A ``.npz`` file, or a folder holding cameras_sphere.npz or cameras.npz."""
    if path.is_file():
        return path if path.suffix == ".npz" else None
    return path if any((path / name).is_file() for name in NEUS_FILES) else None


def read(path: Path, neus_world: str = "normalized", **options) -> SparseModel:
    return SparseModel(read_neus(path, neus_world))


def write(model: SparseModel, path: Path, **options) -> Path:
    return write_neus(model.views, path, points=model.points)


def auto_output(path: Path) -> bool:
    return path.suffix == ".npz"


def _neus_folder(scene: Path, names: tuple[str, ...]) -> Path:
    """The first of ``scene/NAME`` holding images (IDR's ``image/``, else ``images/``), else the first one."""
    return next((scene / n for n in names if sorted_images(scene / n)), scene / names[0])


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
    check_count(path, n, images, folder)
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
    for i, v in enumerate(file_order(views)):
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
