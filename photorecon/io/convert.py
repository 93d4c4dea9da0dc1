"""``photorecon convert``: cameras between COLMAP text/binary, transforms.json and PyTorch3D."""
from __future__ import annotations

from pathlib import Path

from ..conventions import pytorch3d_from_opencv, pytorch3d_intrinsics
from ..errors import BadArgumentError
from .atomic import atomic_write_json
from .colmap_text import SparseModel, write_colmap_text
from .dataset import read_model
from .nerf import read_transforms, write_transforms


def load_cameras(src: str | Path, src_world: str | None = None) -> SparseModel:
    src = Path(src)
    if src.is_file() and src.suffix == ".json":
        return SparseModel(read_transforms(src, src_world))
    return read_model(src)


def write_pytorch3d(model: SparseModel, path: str | Path) -> Path:
    """PyTorch3D cameras as JSON: per image R (3x3), T (3), K (4x4, screen and NDC), image_size (H, W).
    ``X_view = X_world @ R + T``; use ``PerspectiveCameras(R=R[None], T=T[None], K=K_ndc[None])`` (in_ndc=True)
    or ``K=K_screen[None], in_ndc=False, image_size=[(H, W)]``."""
    cams = []
    for v in model.views:
        R, T = pytorch3d_from_opencv(v.cam_from_world)
        intr = v.intrinsics
        cams.append({"name": v.name, "R": R.tolist(), "T": T.tolist(),
                     "K_screen": pytorch3d_intrinsics(intr, "screen").tolist(),
                     "K_ndc": pytorch3d_intrinsics(intr, "ndc").tolist(),
                     "image_size": [intr.height, intr.width]})
    return atomic_write_json(path, {"convention": "pytorch3d: X_view = X_world @ R + T; +x left, +y up, +z forward",
                                    "cameras": cams})


def convert_cameras(src, dst, to: str = "auto", world: str = "none", src_world: str | None = None) -> Path:
    model = load_cameras(src, src_world)
    dst = Path(dst)
    if to == "auto":
        to = "transforms" if dst.suffix == ".json" else "colmap-text"
    if to in ("transforms", "pytorch3d") and dst.suffix != ".json":
        raise BadArgumentError(f"convert: {to} output must be a .json file, got {dst}")
    if to == "colmap-text":
        return write_colmap_text(model, dst)
    if to == "colmap-bin":
        from ..sfm import write_colmap_binary

        return write_colmap_binary(model, dst)
    if to == "transforms":
        return write_transforms(model.views, dst, world=world)
    if to == "pytorch3d":
        return write_pytorch3d(model, dst)
    raise BadArgumentError(f"convert: unknown output format {to!r}")
