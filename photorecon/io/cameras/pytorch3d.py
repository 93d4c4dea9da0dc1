"""PyTorch3D cameras (write only): a JSON file of per-image ``R``, ``T`` and ``K`` for ``PerspectiveCameras``."""
from __future__ import annotations

from pathlib import Path

from ...conventions import pytorch3d_from_opencv, pytorch3d_intrinsics
from ..atomic import atomic_write_json
from .model import SparseModel

NAME = "pytorch3d"
SUFFIX = ".json"


def write(model: SparseModel, path: Path, **options) -> Path:
    return write_pytorch3d(model, path)


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
