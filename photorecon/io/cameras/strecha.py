"""Strecha benchmark cameras (``*.camera`` files, e.g. ``gt_dense_cameras/0000.jpg.camera``).

Strecha, von Hansen, Van Gool, Fua, Thoennessen, "On Benchmarking Camera Calibration and Multi-View Stereo
for High Resolution Imagery", CVPR 2008 (Herz-Jesu, Fountain, Entry, Castle ...). One text file per photo,
nine lines of numbers::

    K            3 rows    fx s cx / 0 fy cy / 0 0 1   pixel (0, 0) = centre of the top-left pixel
    distortion   1 row     k1 k2 k3 (the benchmark's ground truth is undistorted: 0 0 0)
    R            3 rows    camera-to-world rotation (world_from_cam, OpenCV camera axes)
    C            1 row     camera centre in world coordinates
    size         1 row     width height

The projection is ``P = K [Rᵀ | −Rᵀ C]``, so photorecon's ``cam_from_world = [Rᵀ | −Rᵀ C]`` and K is used as
it is (same pixel convention). The files store R with about six significant digits; a rotation that is
orthonormal to 1e-3 is snapped to the nearest rotation (SVD), the centre C kept exactly.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...cameras import Intrinsics, View, rigid
from ...errors import BadArgumentError, InputDataError
from ..paths import files_inside
from .model import SparseModel

NAME = "strecha"
LOOKS_FOR = "Strecha *.camera files (gt_dense_cameras/)"
CAMERA_SUFFIX = ".camera"
_SNAP_TOL = 1e-3


def detect(path: Path) -> Path | None:
    """A folder holding ``*.camera`` files, itself or its ``gt_dense_cameras/``."""
    for folder in (path, path / "gt_dense_cameras"):
        if folder.is_dir() and any(p.name.endswith(CAMERA_SUFFIX) for p in folder.iterdir()):
            return folder
    return None


def read(path: Path, **options) -> SparseModel:
    return read_strecha(path)


def _nearest_rotation(R: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(R)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def read_strecha_camera(path: str | Path) -> View:
    """One ``NAME.camera`` file -> ``View`` named after the image stem (``0000.jpg.camera`` -> ``0000``,
    ``image_file = "0000.jpg"``). Raises ``InputDataError`` naming the file on malformed content."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputDataError(f"{path}: cannot read the Strecha camera file ({exc.__class__.__name__})") from None
    rows = [ln.split() for ln in text.splitlines() if ln.strip()]
    try:
        rows = [[float(x) for x in r] for r in rows]
    except ValueError as exc:
        raise InputDataError(f"{path}: not a Strecha camera file: {exc}") from None
    shape = [len(r) for r in rows]
    if shape != [3, 3, 3, 3, 3, 3, 3, 3, 2]:
        raise InputDataError(f"{path}: expected 9 lines of 3,3,3 (K), 3 (distortion), 3,3,3 (R), 3 (C), 2 "
                             f"(width height) numbers, got {len(rows)} lines of {shape}")
    K = np.array(rows[0:3])
    dist = np.array(rows[3])
    R = np.array(rows[4:7])  # world_from_cam rotation
    C = np.array(rows[7])
    w, h = rows[8]
    bad = [name for name, a in (("K", K), ("distortion", dist), ("R", R), ("C", C), ("size", np.array(rows[8])))
           if not np.all(np.isfinite(a))]
    if bad:
        raise InputDataError(f"{path}: non-finite number (NaN or inf) in {', '.join(bad)}; every entry must be finite")
    if w != int(w) or h != int(h) or w <= 0 or h <= 0:
        raise InputDataError(f"{path}: expected a positive integer image size 'width height', got {w:g} {h:g}")
    if np.any(dist != 0):
        raise InputDataError(f"{path}: non-zero radial distortion {dist.tolist()} is not supported "
                             "(undistort the images and give 0 0 0)")
    try:
        intr = Intrinsics.from_K(K, int(w), int(h))
    except BadArgumentError as exc:
        raise InputDataError(f"{path}: {exc}") from None
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > _SNAP_TOL or np.linalg.det(R) <= 0:
        raise InputDataError(f"{path}: R is not a rotation (|RᵀR - I| = {err:.3g}, det {np.linalg.det(R):.4f}); "
                             "expected the camera-to-world rotation")
    R = _nearest_rotation(R)
    cam_from_world = rigid(R.T, -R.T @ C)
    image_file = path.name[: -len(CAMERA_SUFFIX)] if path.name.endswith(CAMERA_SUFFIX) else path.name
    return View(Path(image_file).stem, intr, cam_from_world, image_file=image_file)


def read_strecha(folder: str | Path) -> SparseModel:
    """All ``*.camera`` files of ``folder`` (sorted by name) as a ``SparseModel`` with no points; a link to a
    camera file outside ``folder`` raises ``InputDataError`` (``paths.files_inside``)."""
    folder = Path(folder)
    files = [p for p in files_inside(folder, (CAMERA_SUFFIX,)) if p.name.endswith(CAMERA_SUFFIX)]
    if not files:
        raise InputDataError(f"{folder}: no Strecha *.camera files")
    views = [read_strecha_camera(p) for p in files]
    names = [v.name for v in views]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputDataError(f"{folder}: two camera files for image {dup[0]!r}")
    return SparseModel(views)

