"""NeRF Blender-synthetic cameras: ``transforms_{train,val,test}.json``, read (one file or all splits of a folder)
and written. Each file is a transforms.json with ``camera_angle_x`` (+ ``camera_angle_y``) instead of focal
lengths (``transforms`` reads its frames; see there for the intrinsics and the RGBA images).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path

from ...cameras import View
from ...conventions import nerf_from_opencv
from ...errors import InputDataError
from ..atomic import atomic_write_json
from .model import SparseModel
from .transforms import BLENDER_SPLITS, _read_frames, read_transforms

log = logging.getLogger("photorecon")

NAME = "blender"
LOOKS_FOR = "transforms_train.json (Blender)"
SUFFIX = ".json"


def detect(path: Path) -> Path | None:
    """A folder holding ``transforms_train.json``, ``transforms_val.json`` or ``transforms_test.json``."""
    return path if any((path / f"transforms_{s}.json").is_file() for s in BLENDER_SPLITS) else None


def read(path: Path, **options) -> SparseModel:
    return SparseModel(read_blender(path))


def write(model: SparseModel, path: Path, **options) -> Path:
    return write_blender(model.views, path)


def auto_output(path: Path) -> bool:
    """``convert --to auto`` writes ``transforms_train.json`` (or val, test) in this format."""
    return path.suffix == ".json" and path.stem in tuple(f"transforms_{s}" for s in BLENDER_SPLITS)


def read_blender(path: str | Path) -> list[View]:
    """Views of the NeRF Blender-synthetic layout: one ``transforms_SPLIT.json`` file, or a folder holding
    ``transforms_train.json`` / ``transforms_val.json`` / ``transforms_test.json`` (all splits present, in that
    order; view names get a ``SPLIT_`` prefix and ``image_file`` the split folder, ``train/r_0.png``,
    since every split has its own ``r_0``: ``reconstruct SCENE/ --poses SCENE/`` pairs the right images)."""
    path = Path(path)
    if path.is_file():
        return read_transforms(path)
    files = [(s, path / f"transforms_{s}.json") for s in BLENDER_SPLITS if (path / f"transforms_{s}.json").is_file()]
    if not files:
        raise InputDataError(f"{path}: no transforms_train.json, transforms_val.json or transforms_test.json")
    views = []
    for split, f in files:
        for v in _read_frames(f, None, allow_empty=len(files) > 1):  # an empty split beside others is allowed
            if len(files) > 1:
                rel = Path(v.image_path).relative_to(path.absolute()).as_posix()
                v = dataclasses.replace(v, name=f"{split}_{v.name}", image_file=rel)
            views.append(v)
    if not views:
        raise InputDataError(f"{path}: the camera files {', '.join(f.name for _, f in files)} have no frames")
    return views


def write_blender(views: list[View], path: str | Path, tol_px: float = 0.5) -> Path:
    """Write ``views`` as a NeRF Blender-synthetic ``transforms_SPLIT.json`` (SPLIT from the file name, else
    "train"): ``camera_angle_x`` (+ ``camera_angle_y`` when fy != fx), frames with ``file_path`` =
    ``./SPLIT/STEM`` (no extension) and ``transform_matrix`` in photorecon's world. The format holds one
    pinhole camera with its principal point at the image centre: other cameras are refused
    (``InputDataError``), principal points up to ``tol_px`` off centre are written as centred (logged)."""
    path = Path(path)
    if not views:
        raise InputDataError(f"{path}: no cameras to write")
    split = path.stem[len("transforms_"):] if path.stem.startswith("transforms_") else "train"
    intr = views[0].intrinsics
    for v in views:
        i = v.intrinsics
        if i.size != intr.size or abs(i.fx - intr.fx) > 1e-6 * intr.fx or abs(i.fy - intr.fy) > 1e-6 * intr.fy:
            raise InputDataError(f"{path}: the Blender format holds one camera, but view {v.name} has "
                                 f"{i.width}x{i.height} fx={i.fx:g} and view {views[0].name} {intr.width}x{intr.height} "
                                 f"fx={intr.fx:g}; write --to transforms (per-frame intrinsics) instead")
        if i.has_distortion:
            raise InputDataError(f"{path}: view {v.name} has lens distortion, which the Blender format cannot hold; "
                                 "undistort first or write --to transforms")
        off = max(abs(i.cx - (i.width - 1) / 2), abs(i.cy - (i.height - 1) / 2))
        if off > tol_px:
            raise InputDataError(f"{path}: view {v.name}'s principal point ({i.cx:g}, {i.cy:g}) is {off:.2f} px off "
                                 "the image centre, which the Blender format cannot hold; write --to transforms instead")
        if off > 1e-6:
            log.warning("%s: view %s's principal point is %.3f px off centre; written as centred", path, v.name, off)
    W, H = intr.size
    out: dict = {"camera_angle_x": 2 * math.atan(0.5 * W / intr.fx)}
    if abs(intr.fx - intr.fy) > 1e-9 * intr.fx:
        out["camera_angle_y"] = 2 * math.atan(0.5 * H / intr.fy)
    out["photorecon_world"] = "none"
    out["frames"] = [{"file_path": f"./{split}/{Path(v.image_file or v.name).stem}",
                      "transform_matrix": nerf_from_opencv(v.cam_from_world, "none").tolist()} for v in views]
    return atomic_write_json(path, out)
