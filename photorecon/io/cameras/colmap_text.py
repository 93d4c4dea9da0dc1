"""COLMAP text models (cameras.txt, images.txt, points3D.txt), read and written without pycolmap.

COLMAP's pixel convention (centre of the top-left pixel at (0.5, 0.5)) is converted here, once: everything
returned uses photorecon's OpenCV convention. Binary models are read through ``photorecon.sfm``.

An image's NAME is the rest of its line after CAMERA_ID and one space, spaces included (``" a  b.png"`` is a
file name). Names are relative to the image folder (``paths.inside``: absolute paths and ``..`` are refused).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ...cameras import Intrinsics, View
from ...conventions import (colmap_from_intrinsics, colmap_from_opencv, colmap_from_opencv_pixels,
                            intrinsics_from_colmap, opencv_from_colmap, opencv_from_colmap_pixels)
from ...errors import InputDataError
from ..atomic import atomic_write_text
from ..paths import inside
from .model import SparseModel

NAME = "colmap-text"
LOOKS_FOR = "sparse/0/ (COLMAP)"
SUFFIX = None  # written as a folder
COLMAP_FOLDERS = ("", "sparse/0", "sparse")  # where a dataset folder holds its COLMAP model, in this order


def colmap_folder(path: Path) -> tuple[Path, str] | None:
    """(the folder of the COLMAP model in ``path``, "text" or "binary"): the first of ``path``, ``path/sparse/0``
    and ``path/sparse`` with cameras.txt or cameras.bin, text first; None when there is none."""
    for sub in COLMAP_FOLDERS:
        folder = path / sub if sub else path
        if (folder / "cameras.txt").is_file():
            return folder, "text"
        if (folder / "cameras.bin").is_file():
            return folder, "binary"
    return None


def detect(path: Path) -> Path | None:
    found = colmap_folder(path)
    return found[0] if found and found[1] == "text" else None


def read(path: Path, **options) -> SparseModel:
    return read_colmap_text(path)


def write(model: SparseModel, path: Path, **options) -> Path:
    return write_colmap_text(model, path)


def _image_key(view: View) -> str:
    return view.image_file or view.name


def _cam_key(view: View) -> tuple:
    m, w, h, params = colmap_from_intrinsics(view.intrinsics)
    return m, w, h, tuple(params)


def write_colmap_text(model: SparseModel, folder: str | Path) -> Path:
    """Write cameras.txt, images.txt, points3D.txt (COLMAP pixel convention) into ``folder``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cams: dict[tuple, int] = {}
    cam_lines, img_lines = [], []
    for view in model.views:
        key = _cam_key(view)
        if key not in cams:
            cams[key] = len(cams) + 1
            m, w, h, params = key
            cam_lines.append(f"{cams[key]} {m} {w} {h} " + " ".join(repr(float(p)) for p in params))
    # track lookup
    tracks: dict[int, list[tuple[int, int]]] = {int(p): [] for p in model.point_ids}
    for i, view in enumerate(model.views, start=1):
        q, t = colmap_from_opencv(view.cam_from_world)
        cam_id = cams[_cam_key(view)]
        img_lines.append(f"{i} " + " ".join(repr(float(x)) for x in (*q, *t)) + f" {cam_id} {_image_key(view)}")
        uv, ids = model.observations.get(view.name, (np.zeros((0, 2)), np.zeros(0, np.int64)))
        parts = []
        for j, ((u, v), pid) in enumerate(zip(colmap_from_opencv_pixels(uv).reshape(-1, 2), ids)):
            parts.append(f"{float(u)!r} {float(v)!r} {int(pid)}")
            if pid >= 0 and int(pid) in tracks:
                tracks[int(pid)].append((i, j))
        img_lines.append(" ".join(parts))
    pt_lines = []
    errors = model.errors if model.errors is not None else np.zeros(len(model.points))
    for pid, xyz, rgb, err in zip(model.point_ids, model.points, model.colors, errors):
        tr = " ".join(f"{a} {b}" for a, b in tracks[int(pid)])
        pt_lines.append(f"{int(pid)} {float(xyz[0])!r} {float(xyz[1])!r} {float(xyz[2])!r} {int(rgb[0])} {int(rgb[1])} {int(rgb[2])} "
                        f"{float(err)!r} {tr}")
    atomic_write_text(folder / "cameras.txt", "# Camera list with one line of data per camera:\n"
                      "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n" + "\n".join(cam_lines) + "\n")
    atomic_write_text(folder / "images.txt", "# Image list with two lines of data per image:\n"
                      "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
                      "#   POINTS2D[] as (X, Y, POINT3D_ID)\n" + "\n".join(img_lines) + "\n")
    atomic_write_text(folder / "points3D.txt", "# 3D point list with one line of data per point:\n"
                      "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
                      + "\n".join(pt_lines) + ("\n" if pt_lines else ""))
    return folder


# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID, one separator, then NAME: the rest of the line
_IMAGE_LINE = re.compile(r"\s*(\S+(?:[ \t]+\S+){8})[ \t](.*)")


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of the lines of ``path`` that are not comments."""
    if not path.is_file():
        raise InputDataError(f"{path}: missing; a COLMAP text model needs cameras.txt, images.txt and points3D.txt")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputDataError(f"{path}: not a COLMAP text file (byte {exc.object[exc.start]:#04x} at offset {exc.start} "
                             "is not UTF-8 text); expected cameras.txt, images.txt and points3D.txt as COLMAP "
                             "writes them") from None
    return [(n, ln.rstrip("\n")) for n, ln in enumerate(text.splitlines(), 1) if not ln.startswith("#")]


def _numbers(tokens: list[str], what: str, kind=float) -> list:
    """``tokens`` as numbers (``kind``); a token that is not one raises ``ValueError`` naming ``what``."""
    try:
        return [kind(x) for x in tokens]
    except ValueError:
        bad = next(x for x in tokens if not _is_number(x, kind))
        raise ValueError(f"{what}: {bad!r} is not {'an integer' if kind is int else 'a number'}") from None


def _is_number(x: str, kind) -> bool:
    try:
        kind(x)
        return True
    except ValueError:
        return False


def read_colmap_text(folder: str | Path) -> SparseModel:
    """Read a COLMAP text model; raises ``InputDataError`` naming the file and line on malformed content."""
    folder = Path(folder)
    cams: dict[int, Intrinsics] = {}
    path = folder / "cameras.txt"
    for n, ln in _data_lines(path):
        if not ln.strip():
            continue
        try:
            tok = ln.split()
            if len(tok) < 4:
                raise ValueError("expected CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]")
            cam_id = _numbers(tok[:1], "CAMERA_ID", int)[0]
            if cam_id in cams:
                raise ValueError(f"camera {cam_id} is listed twice; each CAMERA_ID must be unique")
            w, h = _numbers(tok[2:4], "WIDTH, HEIGHT", int)
            cams[cam_id] = intrinsics_from_colmap(tok[1], w, h, _numbers(tok[4:], "PARAMS"))
        except (ValueError, IndexError) as exc:
            raise InputDataError(f"{path}: cannot parse camera line {n!r}: {exc}") from None
    path = folder / "images.txt"
    lines = _data_lines(path)
    # images.txt alternates a pose line and a (possibly empty) points line
    while lines and not lines[-1][1].strip() and len(lines) % 2:
        lines.pop()
    if len(lines) % 2:  # a pose line without its POINTS2D line: as if that line were empty
        lines.append((lines[-1][0] + 1, ""))
    views, obs = [], {}
    for k in range(0, len(lines) - 1, 2):
        (n, ln), (n_pts, pts) = lines[k], lines[k + 1]
        if not ln.strip():
            continue
        where = f"{path} line {n}"
        m = _IMAGE_LINE.fullmatch(ln)
        if m is None or not m.group(2):
            raise InputDataError(f"{where}: cannot parse image entry {ln!r}: expected IMAGE_ID, QW, QX, QY, QZ, TX, "
                                 "TY, TZ, CAMERA_ID, NAME")
        tok, name = m.group(1).split(), m.group(2)
        try:
            image_id = _numbers(tok[:1], "IMAGE_ID", int)[0]
            q = np.array(_numbers(tok[1:5], "QW QX QY QZ"))
            t = np.array(_numbers(tok[5:8], "TX TY TZ"))
            cam_id = _numbers(tok[8:9], "CAMERA_ID", int)[0]
            p = pts.split()
            if len(p) % 3:
                raise ValueError(f"its POINTS2D line (line {n_pts}) holds {len(p)} numbers, not X Y POINT3D_ID "
                                 "triples")
            arr = np.array(_numbers(p, "POINTS2D"), dtype=np.float64).reshape(-1, 3)
        except ValueError as exc:
            raise InputDataError(f"{where}: cannot parse image entry {ln!r}: {exc}") from None
        if not (np.isfinite(q).all() and np.isfinite(t).all()):
            raise InputDataError(f"{where}: image {name}: QW QX QY QZ TX TY TZ must be finite, got "
                                 f"{' '.join(tok[1:8])}")
        if not np.any(q):
            raise InputDataError(f"{path}: zero quaternion in line {n} (image {name}): QW QX QY QZ must be a "
                                 "rotation, e.g. 1 0 0 0 for none")
        if cam_id not in cams:
            raise InputDataError(f"{where}: image {name} uses camera {cam_id}, which {folder / 'cameras.txt'} does "
                                 f"not list (it lists {sorted(cams) or 'none'})")
        if not np.isfinite(arr).all():
            raise InputDataError(f"{path} line {n_pts}: image {name}'s POINTS2D holds a non-finite number")
        T = opencv_from_colmap(q / np.linalg.norm(q), t)
        inside(None, name, f"{path} image {tok[0]}")
        stem = Path(name).stem
        views.append(View(stem, cams[cam_id], T, image_file=name, extra={"colmap_image_id": image_id,
                                                                         "colmap_camera_id": cam_id}))
        obs[stem] = (opencv_from_colmap_pixels(arr[:, :2]), arr[:, 2].astype(np.int64))
    path = folder / "points3D.txt"
    ids, xyz, rgb, err = [], [], [], []
    for n, ln in _data_lines(path):
        tok = ln.split()
        if not tok:
            continue
        try:
            if len(tok) < 8:
                raise ValueError("expected POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[]")
            ids.append(_numbers(tok[:1], "POINT3D_ID", int)[0])
            xyz.append(_numbers(tok[1:4], "X Y Z"))
            colour = _numbers(tok[4:7], "R G B", int)
            if not all(0 <= c <= 255 for c in colour):
                raise ValueError(f"R G B must be 0..255, got {' '.join(tok[4:7])}")
            rgb.append(colour)
            err.append(_numbers(tok[7:8], "ERROR")[0])
            if not np.isfinite(xyz[-1]).all():
                raise ValueError(f"X Y Z must be finite, got {' '.join(tok[1:4])}")
        except ValueError as exc:
            raise InputDataError(f"{path}: cannot parse point line {n} {ln[:60]!r}: {exc}") from None
    return SparseModel(views, np.array(xyz, float).reshape(-1, 3), np.array(rgb, np.uint8).reshape(-1, 3),
                       np.array(ids, np.int64), np.array(err, float), obs)
