"""The picture "photo | model" (``OUT/model_view.png``): one input photo beside the textured model (model.glb)
rendered from the same camera, written by ``reconstruct``'s model stage and shown in report.html.

The photo is the one whose camera sees most of the model: the most of ``SAMPLES`` points spread evenly over the
model's area in front of it, unoccluded and not at a grazing angle (``Renderer.visible``). It is one of the photos
the model was textured from, not a held-out view: the picture shows how the texture lines up with the photo (and
what the model lacks), not how well it predicts an unseen view. The model is ray cast (``render.Renderer``)
unlit, as a texture baked from photos already holds their light, with its atlas downscaled by the photo's own
factor (``textured.shrink_atlas``); pixels it does not cover are white. Each half is at most ``MODEL_VIEW_SIDE``
pixels on its long side, with the photo's aspect ratio.
"""
from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np
import trimesh

from ..cameras import View
from ..io.images import write_image
from ..layout import Layout
from .textured import atlas_image, load_model, shrink_atlas

log = logging.getLogger("photorecon")

MODEL_VIEW_SIDE = 720  # the long side of each half of model_view.png, pixels
SAMPLES = 3000  # points on the model's surface that choose the photo
GAP = 8  # white pixels between the two halves
BACKGROUND = (1.0, 1.0, 1.0)


def _joined(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)


def best_view(mesh: trimesh.Trimesh, views: list[View], samples: int = SAMPLES) -> tuple[int, float]:
    """The index of the view that sees most of ``mesh``'s area, and the share of it that view sees."""
    from ..render import Renderer

    bare = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    pts, face = trimesh.sample.sample_surface(bare, samples, seed=0)
    normals = np.asarray(bare.face_normals)[face]
    r = Renderer(bare, plain=True)
    seen = [int(r.visible(np.asarray(pts), v, normals)[0].sum()) for v in views]
    k = int(np.argmax(seen))
    return k, seen[k] / max(len(pts), 1)


def half_size(width: int, height: int, side: int = MODEL_VIEW_SIDE) -> tuple[int, int]:
    """A photo's size in the picture: ``side`` on its long side at most, its aspect ratio kept."""
    s = min(1.0, side / max(width, height))
    return max(1, int(round(width * s))), max(1, int(round(height * s)))


def render_model(mesh: trimesh.Trimesh, view: View, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """``mesh`` (textured) ray cast unlit from ``view``'s camera at ``width`` x ``height``: (RGB, covered mask)."""
    from ..render import Renderer

    W = view.intrinsics.width
    scale = min(1.0, width / W)
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=_pil(shrink_atlas(atlas_image(mesh), scale)))
    small = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False,
                            visual=trimesh.visual.TextureVisuals(uv=mesh.visual.uv, material=mat))
    r = Renderer(small, unlit=True, background_color=BACKGROUND)
    out = r.render(replace(view, intrinsics=view.intrinsics.scaled(width, height)))
    return out.rgb, out.mask


def _pil(img: np.ndarray):
    from PIL import Image

    return Image.fromarray(img)


def photo_model_picture(mesh: trimesh.Trimesh, view: View, photo: np.ndarray,
                        side: int = MODEL_VIEW_SIDE) -> tuple[np.ndarray, dict]:
    """[photo | white gap | model rendered from ``view``], each half ``half_size`` of the photo; with the share
    of the half the model covers and the mean absolute difference (0-255, over the channels) between model and
    photo there."""
    import cv2

    H, W = photo.shape[:2]
    w, h = half_size(W, H, side)
    small = cv2.resize(photo, (w, h), interpolation=cv2.INTER_AREA) if (w, h) != (W, H) else photo
    rgb, mask = render_model(mesh, view, w, h)
    gap = np.full((h, GAP, 3), 255, np.uint8)
    diff = np.abs(rgb[mask].astype(np.float64) - small[mask].astype(np.float64))
    info = {"covered_fraction": round(float(mask.mean()), 4),
            "mean_abs_difference": round(float(diff.mean()), 2) if mask.any() else None}
    return np.concatenate([small[:, :, :3], gap, rgb], axis=1), info


def write_model_view(path: str | Path, meshes: list[trimesh.Trimesh], views: list[View],
                     images: Callable[[View], np.ndarray]) -> dict:
    """``path`` (PNG): the photo whose camera sees most of the model (``meshes``, in the cameras' frame) beside
    the model rendered from it. Returns report.json's ``texture.view``: the file, the photo, the share of the
    model's area it sees, the share of the picture the model covers, the mean absolute difference there."""
    if not views:
        raise ValueError("no cameras to render the model from")
    mesh = _joined(meshes)
    k, seen = best_view(mesh, views)
    picture, info = photo_model_picture(mesh, views[k], images(views[k]))
    write_image(path, picture)
    return {"file": Path(path).name, "photo": views[k].image_file or views[k].name, "view": views[k].name,
            "model_seen_fraction": round(seen, 4), **info}


def model_view_output(out: str | Path, texture: dict) -> dict:
    """``reconstruct``'s picture of its model: OUT/model_view.png from OUT/model.glb (moved back into the
    cameras' frame by ``texture``'s frame, report.json's ``texture`` section), the cameras and photos of OUT.
    Returns report.json's ``texture.view`` ({} when there is no model.glb)."""
    from ..io.dataset import Dataset

    layout = Layout(out)
    meshes = load_model(out, texture)
    if meshes is None:
        return {}
    ds = Dataset.open(out)
    info = write_model_view(layout.model_view, meshes, ds.views, ds.image)
    log.info("model: %s: photo %s beside the model from its camera (it sees %.0f%% of the model's area)",
             layout.model_view, info["photo"], 100 * info["model_seen_fraction"])
    return info
