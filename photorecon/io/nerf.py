"""NeRF ``transforms.json`` (nerfstudio / instant-ngp), read and written.

* ``transform_matrix`` is camera-to-world with OpenGL camera axes (see ``conventions.nerf_from_opencv``), in
  the world named by ``world``: "none" (photorecon's world), "instant-ngp" or "nerfstudio" re-orientation.
  The file records it as ``"photorecon_world"``; nerfstudio's variant also gets ``applied_transform``.
* ``cx, cy`` follow nerfstudio and instant-ngp, which cast rays through ``pixel + 0.5``: the centre of the
  top-left pixel is (0.5, 0.5), like COLMAP. Converted here, once.
* Frame paths are confined to the file's folder: absolute paths and ``..`` escapes are refused.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..cameras import Intrinsics, View
from ..conventions import NERF_WORLDS, nerf_from_opencv, opencv_from_nerf
from ..errors import InputDataError
from .atomic import atomic_write_json

_INTR_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2")


def _intr_dict(intr: Intrinsics) -> dict:
    d = {"camera_model": "OPENCV", "fl_x": intr.fx, "fl_y": intr.fy, "cx": intr.cx + 0.5, "cy": intr.cy + 0.5,
         "w": intr.width, "h": intr.height}
    d.update({k: getattr(intr, k) for k in ("k1", "k2", "p1", "p2")})
    return d


def write_transforms(views: list[View], path: str | Path, world: str = "none", image_dir: str = "images",
                     image_ext: str = ".png", depth_dir: str | None = None, mask_dir: str | None = None,
                     extra: dict | None = None) -> Path:
    """Write ``views`` to ``path``; ``image_dir``/``depth_dir``/``mask_dir`` are relative to its folder."""
    path = Path(path)
    world_T = NERF_WORLDS.get(world)
    if world_T is None:
        raise InputDataError(f"NeRF world orientation: expected one of {sorted(NERF_WORLDS)}, got {world!r}")
    shared = len({v.intrinsics for v in views}) == 1
    out: dict = {}
    if shared and views:
        out.update(_intr_dict(views[0].intrinsics))
    out["photorecon_world"] = world
    if world == "nerfstudio":
        out["applied_transform"] = world_T[:3].tolist()
    frames = []
    for v in views:
        image_file = v.extra.get("image_file", v.name + image_ext)
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


def confined(root: Path, rel: str, what: str) -> Path:
    """``root / rel`` if it stays inside ``root``; else ``InputDataError``."""
    if Path(rel).is_absolute():
        raise InputDataError(f"{what}: absolute path {rel!r} refused; paths must be relative to {root}")
    p = (root / rel).resolve()
    if not p.is_relative_to(root.resolve()):
        raise InputDataError(f"{what}: path {rel!r} leaves {root}; refused")
    return p


def read_transforms(path: str | Path, world: str | None = None) -> list[View]:
    """Views from a transforms.json. ``world`` defaults to the file's ``photorecon_world``, else nerfstudio's
    ``applied_transform`` if present, else "none". ``View.image_path`` is the confined absolute image path."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputDataError(f"{path}: no such file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputDataError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise InputDataError(f"{path}: expected an object with a 'frames' list")
    if world is None:
        world = data.get("photorecon_world")
        if world is None:
            world = "none"
            if "applied_transform" in data:
                A = np.asarray(data["applied_transform"], float)
                world = next((k for k, M in NERF_WORLDS.items() if np.allclose(M[:3], A)), None)
                if world is None:
                    raise InputDataError(f"{path}: applied_transform {A.tolist()} is not a known orientation")
    root = path.parent
    views = []
    for i, fr in enumerate(data["frames"]):
        where = f"{path} frame {i}"
        try:
            src = {**{k: data[k] for k in _INTR_KEYS if k in data}, **{k: fr[k] for k in _INTR_KEYS if k in fr}}
            for k in ("fl_x", "cx", "cy", "w", "h"):
                if k not in src:
                    raise InputDataError(f"{where}: missing intrinsics key {k!r}")
            dist = {k: float(src.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2")}
            model = "OPENCV" if any(dist.values()) else "PINHOLE"
            intr = Intrinsics(int(src["w"]), int(src["h"]), float(src["fl_x"]), float(src.get("fl_y", src["fl_x"])),
                              float(src["cx"]) - 0.5, float(src["cy"]) - 0.5, model=model,
                              **(dist if model == "OPENCV" else {}))
            T = opencv_from_nerf(np.asarray(fr["transform_matrix"], float), world)
            file_path = str(fr["file_path"])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputDataError(f"{where}: {exc}") from None
        img = confined(root, file_path, where)
        if not img.suffix and not img.exists():
            img = img.with_suffix(".png")
        extra = {"image_file": img.name}
        for key in ("depth_file_path", "mask_path"):
            if key in fr:
                extra[key] = str(confined(root, str(fr[key]), where))
        views.append(View(img.stem, intr, T, image_path=str(img), extra=extra))
    return views
