"""The textured model (``OUT/model.glb``) as report.html's 3D view shows it.

``load_model`` reads model.glb and moves it back into the reconstruction's frame, the frame of mesh.ply and of the
cameras, by the inverse of report.json's ``texture.frame.model_from_reconstruction``: the page's two meshes (the
textured model and the vertex-coloured mesh) and the camera frusta then share one frame, the first view and the
cameras' up (model.glb itself is not touched). A model.glb from before the model had a frame of its own (no
``frame`` in report.json) was written in the reconstruction's frame and is taken as it is.

``model_payload`` is what the page embeds of it: the geometry as zlib-compressed base64 (uint32 faces, uint16
positions quantised over the bounding box, uint16 UVs in image order: (0, 0) the atlas's top-left corner, as
WebGL's ``texImage2D`` lays an image out), one group of faces per atlas, and each atlas as JPEG (base64) downscaled
to ``PAGE_ATLAS_SIDE`` a side at most. What it adds to the page: about 12 bytes per face and 10 per vertex before
zlib (which keeps about 60% of them), the atlas at most 2048 x 2048 at JPEG quality ``PAGE_JPEG_QUALITY``
(about 1.4 MB for photo content), all of it a third more as base64. On a 119-photo capture (150,000 faces,
159,000 vertices, an 8180 x 7796 atlas) that is 2.0 MB of geometry and 1.4 MB of JPEG, 4.5 MB in the page, whose
vertex-coloured mesh takes 2.9 MB (2026-11-29). A model over ``PAGE_MAX_FACES`` faces (``--model-faces``) is
not embedded: the page says so.
"""
from __future__ import annotations

import base64
import logging
import zlib
from pathlib import Path

import numpy as np
import trimesh

from ..layout import Layout

log = logging.getLogger("photorecon")

PAGE_ATLAS_SIDE = 2048  # the largest side of an atlas in the page (all atlases together: at most this squared)
PAGE_JPEG_QUALITY = 85
FILL_TEXELS = 8  # empty texels next to the charts take their colour this far out: no dark seams from mipmaps


def model_to_reconstruction(texture: dict | None) -> np.ndarray:
    """The 4x4 that takes model.glb's points back into the reconstruction's frame (identity without a frame)."""
    frame = (texture or {}).get("frame") if isinstance(texture, dict) else None
    m = frame.get("model_from_reconstruction") if isinstance(frame, dict) else None
    if m is None:
        return np.eye(4)
    m = np.asarray(m, np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError("report.json's texture.frame.model_from_reconstruction is no 4x4 matrix")
    return np.linalg.inv(m)


def load_model(out: str | Path, texture: dict | None) -> list[trimesh.Trimesh] | None:
    """OUT/model.glb's textured parts (one per atlas), in the reconstruction's frame (``texture``: report.json's
    ``texture`` section, for its frame); None when there is no model.glb."""
    path = Layout(out).model("glb")
    if not path.is_file():
        return None
    back = model_to_reconstruction(texture)
    scene = trimesh.load(path, process=False)
    if not isinstance(scene, trimesh.Scene):
        scene = trimesh.Scene(scene)
    meshes = []
    for node in scene.graph.nodes_geometry:  # each part with its node's transform; materials shared, not copied
        to_scene, name = scene.graph[node]
        g = scene.geometry[name]
        if not isinstance(g, trimesh.Trimesh) or not len(g.faces):
            continue
        if not isinstance(g.visual, trimesh.visual.TextureVisuals) or g.visual.uv is None or _image(g) is None:
            continue
        m = trimesh.Trimesh(g.vertices, g.faces, process=False,
                            visual=trimesh.visual.TextureVisuals(uv=g.visual.uv, material=g.visual.material))
        m.apply_transform(back @ to_scene)
        meshes.append(m)
    if not meshes:
        raise ValueError(f"{path.name} holds no textured mesh")
    return _by_atlas(meshes)


def _by_atlas(meshes: list[trimesh.Trimesh]) -> list[trimesh.Trimesh]:
    """The parts that show one atlas joined into one mesh (a closed model's seen and invented parts share theirs:
    the page and model_view.png take it once)."""
    groups: dict[int, list[trimesh.Trimesh]] = {}
    for m in meshes:
        groups.setdefault(id(_image(m)), []).append(m)
    out = []
    for parts in groups.values():
        start = np.cumsum([0] + [len(m.vertices) for m in parts])
        out.append(parts[0] if len(parts) == 1 else trimesh.Trimesh(
            np.concatenate([m.vertices for m in parts]), np.concatenate([m.faces + s for m, s in zip(parts, start)]),
            process=False, visual=trimesh.visual.TextureVisuals(uv=np.concatenate([m.visual.uv for m in parts]),
                                                                material=parts[0].visual.material)))
    return out


def _image(mesh: trimesh.Trimesh):
    mat = mesh.visual.material
    return getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)


def atlas_image(mesh: trimesh.Trimesh) -> np.ndarray:
    """The mesh's atlas as (H, W, 3) uint8."""
    return np.asarray(_image(mesh).convert("RGB"))


def shrink_atlas(atlas: np.ndarray, scale: float, fill: int = FILL_TEXELS) -> np.ndarray:
    """``atlas`` resized by ``scale`` (<= 1) averaging the charts' texels only (the packer leaves the rest black),
    then the empty texels within ``fill`` of a chart given their neighbours' colour: bilinear filtering and
    mipmaps next to a chart's edge blend chart colours, not the black around it. Works in uint8 (an 8192 atlas
    as floats would take 800 MB)."""
    import cv2

    H, W = atlas.shape[:2]
    w, h = max(1, int(round(W * scale))), max(1, int(round(H * scale)))
    r, g, b = cv2.split(atlas)
    used = cv2.compare(cv2.bitwise_or(cv2.bitwise_or(r, g), b), 0, cv2.CMP_GT)  # 255 on a chart (numpy: 10x slower)
    if (w, h) != (W, H):
        small = cv2.resize(atlas, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32)
        cover = cv2.resize(used, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32)
    else:
        small, cover = atlas.astype(np.float32), used.astype(np.float32)
    valid = cover >= 128  # at least half a chart's: its average over the chart's part within 1 level in 255
    col = np.where(valid[..., None], small * (255.0 / np.maximum(cover, 1.0))[..., None], 0.0)
    for _ in range(fill):
        if valid.all():
            break
        v = valid.astype(np.float32)
        num = cv2.boxFilter(col * v[..., None], -1, (3, 3), normalize=False)
        den = cv2.boxFilter(v, -1, (3, 3), normalize=False)
        grow = ~valid & (den > 0)
        col[grow] = num[grow] / den[grow, None]
        valid = valid | grow
    return np.clip(col + 0.5, 0, 255).astype(np.uint8)


def _jpeg(rgb: np.ndarray) -> bytes:
    import cv2

    # 4:4:4, as model.glb's: chroma at half resolution doubles the error on fine colour texture (+14% of bytes)
    params = [cv2.IMWRITE_JPEG_QUALITY, PAGE_JPEG_QUALITY,
              cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(rgb[:, :, ::-1]), params)
    if not ok:
        raise ValueError("the atlas could not be encoded as JPEG")
    return data.tobytes()


def model_payload(meshes: list[trimesh.Trimesh], max_faces: int, max_side: int = PAGE_ATLAS_SIDE) -> dict:
    """The textured model's page data: ``meta`` (counts, quantisation, per group its first face, face count and
    atlas; per atlas its size in the page and in model.glb; ``bytes``: what it adds to the page) and ``data``
    (base64 of zlib(faces uint32 | positions uint16 | uv uint16)), ``textures`` (base64 JPEGs). With more than
    ``max_faces`` faces: only ``meta`` with ``skipped`` saying why."""
    n_faces = sum(len(m.faces) for m in meshes)
    if n_faces > max_faces:
        return {"meta": {"skipped": f"the textured model has {n_faces:,} faces, over the page's {max_faces:,}: "
                                    "open model.glb to see it", "faces": n_faces}}
    atlases = [atlas_image(m) for m in meshes]
    total = sum(a.shape[0] * a.shape[1] for a in atlases)
    scale = min([1.0, np.sqrt(max_side * max_side / total)] + [max_side / max(a.shape[:2]) for a in atlases])
    jpegs, sizes = [], []
    for a in atlases:
        small = shrink_atlas(a, scale)
        jpegs.append(_jpeg(small))
        sizes.append({"width": int(small.shape[1]), "height": int(small.shape[0]),
                      "model_width": int(a.shape[1]), "model_height": int(a.shape[0])})
    verts = np.concatenate([np.asarray(m.vertices, np.float64) for m in meshes])
    uv = np.concatenate([np.asarray(m.visual.uv, np.float64)[:, :2] for m in meshes])
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])
    faces = np.concatenate([np.asarray(m.faces, np.int64) + o for m, o in zip(meshes, offsets)]).astype("<u4")
    lo, hi = verts.min(0), verts.max(0)
    step = max(float((hi - lo).max()), 1e-12) / 65535.0
    q = np.clip(np.round((verts - lo) / step), 0, 65535).astype("<u2")
    # UVs as model.glb reads in trimesh (v up) turned to image order (v down): WebGL's first texture row is t = 0
    img_uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], 1)
    quv = np.clip(np.round(img_uv * 65535), 0, 65535).astype("<u2")
    blob = zlib.compress(faces.tobytes() + q.tobytes() + quv.tobytes(), 6)
    data = base64.b64encode(blob).decode("ascii")
    textures = [base64.b64encode(j).decode("ascii") for j in jpegs]
    starts = np.cumsum([0] + [len(m.faces) for m in meshes])
    meta = {"faces": int(len(faces)), "vertices": int(len(verts)), "offset": lo.tolist(), "step": step,
            "groups": [{"start": int(s), "count": int(len(m.faces)), "texture": i}
                       for i, (s, m) in enumerate(zip(starts, meshes))],
            "textures": sizes, "bytes": len(data) + sum(len(t) for t in textures)}
    return {"meta": meta, "data": data, "textures": textures}
