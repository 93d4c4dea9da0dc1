"""NeRF ``transforms.json`` (nerfstudio / instant-ngp), read and written.

* ``transform_matrix`` is camera-to-world with OpenGL camera axes (see ``conventions.nerf_from_opencv``), in
  the world named by ``world``: "none" (photorecon's world), "instant-ngp" or "nerfstudio" re-orientation.
  The file records it as ``"photorecon_world"``; nerfstudio's variant also gets ``applied_transform``.
* ``cx, cy`` follow nerfstudio and instant-ngp, which cast rays through ``pixel + 0.5``: the centre of the
  top-left pixel is (0.5, 0.5), like COLMAP. Converted here, once.
* Frame paths (``file_path``, ``depth_file_path``, ``mask_path``) lie inside the file's folder
  (``paths.inside``: absolute paths, ``..`` escapes and links to files outside are refused). A path without
  an extension (the Blender-synthetic ``./train/r_0``) names ``./train/r_0.png``.
* Intrinsics: ``fl_x, fl_y, cx, cy, w, h`` (+ ``k1 k2 p1 p2``, or ``k1 k2 k3 k4`` for a fisheye) at the top
  level, each overridable per frame. ``camera_model`` (nerfstudio's; per frame too) picks the lens:
  ``PINHOLE``, ``SIMPLE_PINHOLE``, ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV`` (k1 k2 p1 p2) or
  ``OPENCV_FISHEYE`` (k1..k4, OpenCV's fisheye model; instant-ngp's ``"is_fisheye": true`` says the same).
  The other models (``EQUIRECTANGULAR``, ``OMNIDIRECTIONALSTEREO_*``, ``VR180_*``, ``FISHEYE624``, ...) and
  coefficients a model does not hold (``k3`` of a perspective camera, instant-ngp's OpenCV 5-parameter
  lens) are refused, naming the frame.
  The NeRF Blender-synthetic files (``transforms_{train,val,test}.json``) give only ``camera_angle_x`` (and
  optionally ``camera_angle_y``): ``fl_x = 0.5 W / tan(0.5 camera_angle_x)`` with W, H from the image file,
  and the principal point at the image centre, ``cx, cy = W/2, H/2`` in NeRF pixels (= (W-1)/2, (H-1)/2 in
  photorecon's). Their RGBA images are read as stored (``read_image`` drops alpha without compositing on a
  background) and their alpha is the view's mask (``Dataset.mask``).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ...cameras import Intrinsics, View
from ...conventions import (NERF_WORLDS, colmap_from_opencv_pixels, nerf_from_opencv, opencv_from_colmap_pixels,
                            opencv_from_nerf)
from ...errors import BadArgumentError, InputDataError
from ..atomic import atomic_write_json
from ..paths import inside
from .common import image_size
from .model import SparseModel

NAME = "transforms"
LOOKS_FOR = "transforms.json"
FILE_NAME = "transforms.json"
SUFFIX = ".json"

_DIST = ("k1", "k2", "k3", "k4", "p1", "p2")
_INTR_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", *_DIST, "camera_angle_x", "camera_angle_y", "camera_model",
              "is_fisheye")
# nerfstudio's camera_model values: the perspective ones hold k1 k2 p1 p2, the fisheye k1..k4
PERSPECTIVE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
FISHEYE_MODELS = ("OPENCV_FISHEYE",)
BLENDER_SPLITS = ("train", "val", "test")




def detect(path: Path) -> Path | None:
    """A ``.json`` file (any name: also a Blender ``transforms_SPLIT.json``), or a folder's transforms.json."""
    if path.is_file():
        return path if path.suffix == ".json" else None
    return path / "transforms.json" if (path / "transforms.json").is_file() else None


def read(path: Path, world: str | None = None, **options) -> SparseModel:
    return SparseModel(read_transforms(path, world))


def write(model: SparseModel, path: Path, world: str = "none", **options) -> Path:
    return write_transforms(model.views, path, world=world)


def auto_output(path: Path) -> bool:
    """``convert --to auto`` writes a ``.json`` DST as transforms.json, unless it is named like a Blender split."""
    return path.suffix == ".json" and path.stem not in tuple(f"transforms_{s}" for s in BLENDER_SPLITS)


def _intr_dict(intr: Intrinsics) -> dict:
    d = {"camera_model": "OPENCV_FISHEYE" if intr.fisheye else "OPENCV", "fl_x": intr.fx, "fl_y": intr.fy,
         "cx": float(colmap_from_opencv_pixels(intr.cx)), "cy": float(colmap_from_opencv_pixels(intr.cy)),
         "w": intr.width, "h": intr.height}
    d.update({k: getattr(intr, k) for k in (("k1", "k2", "k3", "k4") if intr.fisheye else ("k1", "k2", "p1", "p2"))})
    return d


def write_transforms(views: list[View], path: str | Path, world: str = "none", image_dir: str = "images",
                     image_ext: str = ".png", depth_dir: str | None = None, mask_dir: str | None = None,
                     extra: dict | None = None, units: str | None = None) -> Path:
    """Write ``views`` to ``path``; ``image_dir``/``depth_dir``/``mask_dir`` are relative to its folder.
    ``units``: "metre" or "arbitrary", recorded as the file's ``units`` key (omitted when None)."""
    path = Path(path)
    world_T = NERF_WORLDS.get(world)
    if world_T is None:
        raise InputDataError(f"NeRF world orientation: expected one of {sorted(NERF_WORLDS)}, got {world!r}")
    shared = len({v.intrinsics for v in views}) == 1
    out: dict = {}
    if shared and views:
        out.update(_intr_dict(views[0].intrinsics))
    out["photorecon_world"] = world
    if units is not None:
        if units not in ("metre", "arbitrary"):
            raise InputDataError(f"transforms.json units: expected 'metre' or 'arbitrary', got {units!r}")
        out["units"] = units
    if world == "nerfstudio":
        out["applied_transform"] = world_T[:3].tolist()
    frames = []
    for v in views:
        image_file = v.image_file or v.name + image_ext
        fr = {"file_path": f"{image_dir}/{image_file}" if image_dir else image_file,
              "transform_matrix": nerf_from_opencv(v.cam_from_world, world).tolist()}
        if not shared:
            fr.update(_intr_dict(v.intrinsics))
        if depth_dir:
            fr["depth_file_path"] = f"{depth_dir}/{v.name}.npy"
        if mask_dir:
            fr["mask_path"] = f"{mask_dir}/{v.name}.png"
        frames.append(fr)
    out["frames"] = frames
    if extra:
        out.update(extra)
    return atomic_write_json(path, out)


def _frame_image(root: Path, rel: str, where: str) -> Path:
    """The image ``root / rel`` (``paths.inside``), or ``root / rel.png`` when ``rel`` has no extension and
    does not exist (Blender-synthetic file paths)."""
    p = inside(root, rel, where)
    return inside(root, rel + ".png", where) if not p.suffix and not p.exists() else p


def _blender_intrinsics(src: dict, image: Path, where: str) -> dict:
    """fl_x, fl_y, cx, cy, w, h (NeRF pixels) from ``camera_angle_x`` (+ ``camera_angle_y``), W and H from
    ``w``/``h`` if given, else from the image file."""
    if "w" in src and "h" in src:
        W, H = int(src["w"]), int(src["h"])
    else:
        W, H = image_size(image, where)
    ax = float(src["camera_angle_x"])
    ay = float(src.get("camera_angle_y", 0.0))
    for name, a in (("camera_angle_x", ax), ("camera_angle_y", ay if "camera_angle_y" in src else 1.0)):
        if not 0 < a < math.pi:
            raise InputDataError(f"{where}: {name} = {a} is not a field of view in radians (0 < angle < pi)")
    fl_x = 0.5 * W / math.tan(0.5 * ax)
    fl_y = 0.5 * H / math.tan(0.5 * ay) if "camera_angle_y" in src else fl_x
    return {"fl_x": fl_x, "fl_y": fl_y, "cx": W / 2.0, "cy": H / 2.0, "w": W, "h": H, **src}


def _lens(src: dict, where: str) -> tuple[str, dict]:
    """(photorecon camera model, its distortion coefficients) of a frame's merged intrinsics ``src``, from
    ``camera_model`` (nerfstudio) or ``is_fisheye`` (instant-ngp); a model or a coefficient photorecon cannot
    hold raises ``InputDataError``."""
    name = src.get("camera_model")
    if name is None:
        name = "OPENCV_FISHEYE" if src.get("is_fisheye") else "OPENCV"
    if not isinstance(name, str) or name.upper() not in PERSPECTIVE_MODELS + FISHEYE_MODELS:
        raise InputDataError(f"{where}: camera_model {name!r} is not supported; photorecon reads perspective "
                             f"cameras ({', '.join(PERSPECTIVE_MODELS)}) and {FISHEYE_MODELS[0]} (360-degree, "
                             "stereo-panorama and other lens models: convert the images to one of these first)")
    name = name.upper()
    dist = {k: float(src.get(k, 0.0)) for k in _DIST}
    held = ("k1", "k2", "k3", "k4") if name in FISHEYE_MODELS else ("k1", "k2", "p1", "p2")
    extra = [f"{k}={dist[k]:g}" for k in _DIST if k not in held and dist[k] != 0.0]
    if extra:
        raise InputDataError(f"{where}: {name} camera with {', '.join(extra)}: photorecon's {name} holds only "
                             f"{' '.join(held)} (a {'fisheye' if name in FISHEYE_MODELS else 'perspective'} lens); "
                             "undistort the images or give camera_model "
                             + ("OPENCV_FISHEYE with k1..k4" if name not in FISHEYE_MODELS else "OPENCV with k1 k2 p1 p2"))
    if name in FISHEYE_MODELS:
        return "OPENCV_FISHEYE", {k: dist[k] for k in held}
    if any(dist[k] for k in held):
        return "OPENCV", {k: dist[k] for k in held}
    return "PINHOLE", {}


def _number(src: dict, key: str, where: str, kind=float):
    """``src[key]`` as a number (``kind``); anything else raises ``InputDataError`` naming the key."""
    value = src[key]
    try:
        if isinstance(value, (bool, list, dict)) or value is None:
            raise TypeError
        return kind(float(value)) if kind is int else kind(value)
    except (TypeError, ValueError, OverflowError):
        raise InputDataError(f"{where}: {key}: expected a number, got {value!r:.60}") from None


def _file_world(path: Path, data: dict) -> str:
    """The world orientation a transforms.json records: ``photorecon_world``, else the one nerfstudio's
    ``applied_transform`` stands for, else "none"."""
    world = data.get("photorecon_world")
    if world is not None:
        if not isinstance(world, str) or world not in NERF_WORLDS:
            raise InputDataError(f"{path}: photorecon_world {world!r} is not one of {sorted(NERF_WORLDS)}")
        return world
    if "applied_transform" not in data:
        return "none"
    try:
        A = np.asarray(data["applied_transform"], float)
    except (TypeError, ValueError):
        A = None
    if A is None or A.shape not in ((3, 4), (4, 4)):
        raise InputDataError(f"{path}: applied_transform: expected a 3x4 matrix of numbers, got "
                             f"{data['applied_transform']!r:.80}")
    world = next((k for k, M in NERF_WORLDS.items() if np.allclose(M[:3], A[:3])), None)
    if world is None:
        raise InputDataError(f"{path}: applied_transform {A.tolist()} is not a known orientation")
    return world


def _frame_path(fr: dict, key: str, where: str) -> str:
    value = fr[key]
    if not isinstance(value, str) or not value:
        raise InputDataError(f"{where}: {key}: expected a file path (text, relative to the file's folder), got "
                             f"{value!r:.60}")
    return value


def read_transforms(path: str | Path, world: str | None = None) -> list[View]:
    """Views from a transforms.json. ``world`` defaults to the file's ``photorecon_world``, else nerfstudio's
    ``applied_transform`` if present, else "none". ``View.image_path`` is the confined absolute image path.
    A file without frames raises ``InputDataError``."""
    return _read_frames(Path(path), world, allow_empty=False)


def _read_frames(path: Path, world: str | None, allow_empty: bool) -> list[View]:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputDataError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputDataError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise InputDataError(f"{path}: expected an object with a 'frames' list")
    if not data["frames"] and not allow_empty:
        raise InputDataError(f"{path}: the camera file has no frames (its 'frames' list is empty); list one frame "
                             "per image, each with file_path and transform_matrix")
    if world is None:
        world = _file_world(path, data)
    elif world not in NERF_WORLDS:
        raise BadArgumentError(f"NeRF world orientation: expected one of {sorted(NERF_WORLDS)}, got {world!r}")
    root = path.parent.absolute()
    views = []
    for i, fr in enumerate(data["frames"]):
        where = f"{path} frame {i}"
        if not isinstance(fr, dict):
            raise InputDataError(f"{where}: expected an object with file_path and transform_matrix, got {fr!r:.60}")
        for key, what in (("file_path", "the image file, relative to the file's folder"),
                          ("transform_matrix", "a 4x4 camera-to-world matrix")):
            if key not in fr:
                raise InputDataError(f"{path}: frame {i} has no {key} ({what})")
        file_path = _frame_path(fr, "file_path", where)
        try:
            M = np.asarray(fr["transform_matrix"], float)
        except (TypeError, ValueError):
            raise InputDataError(f"{where}: transform_matrix: expected a 4x4 matrix of numbers (camera-to-world), "
                                 f"got {fr['transform_matrix']!r:.80}") from None
        src = {**{k: data[k] for k in _INTR_KEYS if k in data}, **{k: fr[k] for k in _INTR_KEYS if k in fr}}
        for k in ("fl_x", "fl_y", "cx", "cy", *_DIST, "camera_angle_x", "camera_angle_y"):
            if k in src:
                src[k] = _number(src, k, where)
        for k in ("w", "h"):
            if k in src:
                src[k] = _number(src, k, where, int)
        try:
            if "fl_x" not in src and "camera_angle_x" in src:
                src = _blender_intrinsics(src, _frame_image(root, file_path, where), where)
            for k in ("fl_x", "cx", "cy", "w", "h"):
                if k not in src:
                    raise InputDataError(f"{where}: missing intrinsics key {k!r} (give fl_x, cx, cy, w, h or "
                                         "camera_angle_x at the top level or in the frame)")
            model, dist = _lens(src, where)
            intr = Intrinsics(int(src["w"]), int(src["h"]), float(src["fl_x"]), float(src.get("fl_y", src["fl_x"])),
                              float(opencv_from_colmap_pixels(float(src["cx"]))),
                              float(opencv_from_colmap_pixels(float(src["cy"]))), model=model, **dist)
            T = opencv_from_nerf(M, world)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputDataError(f"{where}: {exc}") from None
        img = _frame_image(root, file_path, where)
        files = {key: str(inside(root, _frame_path(fr, key, where), where)) if key in fr else None
                 for key in ("depth_file_path", "mask_path")}
        views.append(View(img.stem, intr, T, image_path=str(img), image_file=img.name,
                          depth_file=files["depth_file_path"], mask_file=files["mask_path"]))
    return views
