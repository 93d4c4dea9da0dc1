"""``photorecon convert``: cameras between COLMAP text/binary, transforms.json (nerfstudio / instant-ngp and NeRF
Blender-synthetic), IDR / NeuS ``cameras_sphere.npz``, LLFF ``poses_bounds.npy`` and PyTorch3D (write only)."""
from __future__ import annotations

from pathlib import Path

from ..conventions import pytorch3d_from_opencv, pytorch3d_intrinsics
from ..errors import BadArgumentError
from .atomic import atomic_write_json
from .colmap_text import SparseModel, write_colmap_text
from .dataset import read_model
from .formats import write_llff, write_neus
from .nerf import read_transforms, write_blender, write_transforms

FORMATS = ("auto", "colmap-text", "colmap-bin", "transforms", "blender", "neus", "llff", "pytorch3d")


def load_cameras(src: str | Path, src_world: str | None = None, neus_world: str = "normalized") -> SparseModel:
    """``src_world``: the NeRF world orientation of a transforms.json (default: as the file records it);
    ``neus_world``: "normalized" or "original" world of a NeuS ``cameras_sphere.npz``."""
    src = Path(src)
    if src.is_file() and src.suffix == ".json":
        return SparseModel(read_transforms(src, src_world))
    return read_model(src, neus_world=neus_world)


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


def output_format(dst: Path) -> str:
    """The format ``auto`` picks from DST's name."""
    if dst.suffix == ".npz":
        return "neus"
    if dst.suffix == ".npy":
        return "llff"
    if dst.suffix == ".json":
        return "blender" if dst.stem in ("transforms_train", "transforms_val", "transforms_test") else "transforms"
    return "colmap-text"


def convert_cameras(src, dst, to: str = "auto", world: str = "none", src_world: str | None = None,
                    neus_world: str = "normalized", bounds: tuple[float, float] | None = None) -> Path:
    """Read cameras from ``src`` (anything ``read_model`` reads) and write them to ``dst`` as ``to``.
    ``world``: NeRF world orientation written to a transforms.json; ``bounds``: LLFF near / far for every
    image (default: from the sparse points)."""
    model = load_cameras(src, src_world, neus_world)
    dst = Path(dst)
    if to == "auto":
        to = output_format(dst)
    suffix = {"transforms": ".json", "pytorch3d": ".json", "blender": ".json", "neus": ".npz", "llff": ".npy"}
    if to in suffix and dst.suffix != suffix[to]:
        raise BadArgumentError(f"convert: {to} output must be a {suffix[to]} file, got {dst}")
    if to == "colmap-text":
        return write_colmap_text(model, dst)
    if to == "colmap-bin":
        from .colmap import write_colmap_binary

        return write_colmap_binary(model, dst)
    if to == "transforms":
        return write_transforms(model.views, dst, world=world)
    if to == "blender":
        return write_blender(model.views, dst)
    if to == "neus":
        return write_neus(model.views, dst, points=model.points)
    if to == "llff":
        return write_llff(model.views, dst, points=model.points, bounds=bounds, points_of=model.points_seen_by)
    if to == "pytorch3d":
        return write_pytorch3d(model, dst)
    raise BadArgumentError(f"convert: unknown output format {to!r}; expected one of {FORMATS}")
