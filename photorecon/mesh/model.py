"""The textured model of a reconstruction: ``OUT/model.glb`` (and ``model.obj`` + ``model.mtl`` + ``model.png``).

``reconstruct``'s model stage (on by default, ``--texture off`` skips it) takes the cleaned, fused mesh
(``OUT/mesh.ply``, 2-5 M faces on real captures), simplifies it to a face budget (``--model-faces``,
``clean.simplify``) and textures the simplified surface from the photos with ``texture.texture_mesh`` (one photo
per face, exposure evened out, charts at up to one texel per photo pixel) in an atlas of at most ``--max-atlas``
texels a side. When the charts do not fit that atlas at one texel per pixel, ``texture_mesh`` lowers the density
until they do (``texels_per_pixel`` in the report).

``compact_atlas`` then repacks the charts into the smallest atlas that holds them (texture_mesh packs them into
rows of the full atlas width): a small model gets a small texture. ``model.glb`` embeds it as JPEG (quality
``JPEG_QUALITY``: a tenth of the PNG's size for photo content); ``model.obj`` (with ``--formats`` including obj)
refers to a lossless ``model.png``.

**The model's frame.** ``model.glb`` (and ``model.obj``) stand upright in glTF's frame (``model_frame``,
``upright.upright_frame``): +Y up, +Z towards the cameras. An object capture stands on the support plane that the
cleaning removed (report.json's ``mesh``), its base centre at the origin; an open scene's up is the east-north-up
frame's when GPS set the scale, else the cameras' up. Nothing is scaled: the model is in metres when the
reconstruction is (markers, GPS, metric cameras given), else in its units. ``OUT/mesh.ply``, ``sparse/0`` and
``transforms.json`` stay in the reconstruction's frame; report.json's ``texture.frame`` gives the rule and the 4x4
``model_from_reconstruction`` that brings them (or cameras: ``upright.apply_views``) into the model's.

**Open or closed** (``--model-surface``, ``model_surface``). An object capture's model is by default its closed
surface, the watertight companion ``mesh_closed.ply`` (``close.closed_companion``) simplified to the face budget:
what 3D printing, AR and games expect. The faces its closing added (the underside the object stood on, holes no
photo saw into: ``invented_faces``) are no photo's: they take the colours of the seen faces around them (diffused
over the mesh, as ``texture_mesh`` colours unseen faces) and form a part of their own, a second glTF primitive
(a second ``usemtl`` in model.obj) with the material ``"invented"``, which a viewer can hide or restyle. An open
scene's model is the open surface of ``OUT/mesh.ply``; report.json's ``texture.surface`` says which, and
``invented_area_share`` how much of the closed model's area was invented.

The default face budget was measured on synthetic scenes against the full mesh in pixel footprints
(docs/benchmarks.md, "Textured model: face budget").
"""
from __future__ import annotations

import io
import json
import logging
import struct
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Literal

import numpy as np
import trimesh

from ..cameras import View
from ..config_checks import check_config, expect_config
from ..errors import InputDataError, TextureError
from ..io.atomic import atomic_path
from ..layout import Layout
from ..resources import available_bytes
from .atlas import _merge_boxes, shelf_pack
from .surface import carry_marks, cleaning_facts, model_surface
from .texture import TextureConfig, texture_mesh
from .upright import Upright, upright_frame

log = logging.getLogger("photorecon")

DEFAULT_MODEL_FACES = 150_000  # docs/benchmarks.md, "Textured model": <= 15% of the demo's CPU, shape kept
JPEG_QUALITY = 90
MATERIAL_NAME = "photorecon_model"
INVENTED_MATERIAL = "invented"  # the closed model's faces no photo saw, a part of their own


@dataclass
class ModelConfig:
    """Settings of ``reconstruct``'s model stage (``OUT/model.glb``; the texturing itself: ``TextureConfig``)."""

    CLI_PREFIX = "model"

    model_faces: int = field(default=DEFAULT_MODEL_FACES, metadata={"help": "faces of the textured model OUT/model.glb: the mesh is simplified to about this many before texturing (0 = every face of OUT/mesh.ply)", "range": (4, 2_000_000_000), "also": (0,)})
    max_atlas: int = field(default=8192, metadata={"help": "largest side of the model's texture atlas, texels (charts that do not fit at one texel per photo pixel are packed at a lower density)", "range": (256, 16384)})
    model_surface: Literal["auto", "open", "closed"] = field(default="auto", metadata={"help": "auto: closed for an object capture (it has mesh_closed.ply), else open; open: the surface of OUT/mesh.ply; closed: the watertight surface, its faces no photo saw (the underside, holes) a part of their own with the material \"invented\", coloured from the faces around them"})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.config_checks)


@dataclass
class Model:
    mesh: trimesh.Trimesh  # TextureVisuals: uv per vertex, material image = ``atlas``
    atlas: np.ndarray  # (H, W, 3) uint8
    info: dict
    invented: np.ndarray | None = None  # (F,) bool: the closed model's faces no photo saw (None: the open model)


def model_paths(layout: Layout, formats: tuple[str, ...] | list[str]) -> list[Path]:
    """The files the model stage writes: model.glb, and with obj among ``formats`` model.obj, .mtl, .png."""
    paths = [layout.model("glb")]
    if "obj" in formats:
        paths += [layout.model("obj"), layout.model("mtl"), layout.model("png")]
    return paths


def atlas_within_memory(largest: int) -> int:
    """The largest atlas side from ``largest`` down (halving, at least 1024) whose atlas the memory holds
    (``texture.check_atlas_memory``'s estimate: 12 bytes per texel)."""
    size = int(largest)
    avail = available_bytes()
    while size > 1024 and size * size * 12 > avail:
        size //= 2
    if size < largest:
        log.warning("model: a %dx%d texture atlas (--max-atlas) needs more memory than is available (%.1f GB); "
                    "using %dx%d", largest, largest, avail / 2**30, size, size)
    return size


# --- the atlas, repacked ---------------------------------------------------------------------------------------
def compact_atlas(mesh: trimesh.Trimesh, atlas: np.ndarray, pad: int,
                  block: np.ndarray | None = None) -> tuple[trimesh.Trimesh, np.ndarray]:
    """``mesh`` (TextureVisuals into ``atlas``, (N, N, 3)) with its charts repacked into the smallest atlas
    that holds them: the texel boxes of its UV islands (faces joined by shared vertices), widened by ``pad`` + 1
    texels and merged where they overlap by more than two, shelf-packed into the narrowest width (a multiple of 4) whose rows fit
    in a square, then cropped to the height used. Each box's texels are copied as they are (no resampling);
    UVs follow their box. ``block``: (F,) bool, faces whose texels lie in one block (``texture_mesh``'s cells of
    the faces no photo sees), moved as one box (one per face would be thousands). Returns the new mesh and atlas."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    H0, W0 = atlas.shape[:2]
    uv = np.asarray(mesh.visual.uv, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    x = uv[:, 0] * W0 - 0.5  # texel coordinates (texel centre i at (i + 0.5) / N; v up)
    y = (1.0 - uv[:, 1]) * H0 - 0.5
    nv = len(uv)
    edges = np.concatenate([F[:, [0, 1]], F[:, [1, 2]]])
    _, comp = connected_components(coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(nv, nv)),
                                   directed=False)
    if block is not None and np.any(block):
        comp[F[np.asarray(block, bool)].reshape(-1)] = comp.max() + 1
        comp = np.unique(comp, return_inverse=True)[1].reshape(-1)
    n = comp.max() + 1
    box = np.empty((n, 4))
    box[:, :2] = np.inf
    box[:, 2:] = -np.inf
    np.minimum.at(box[:, 0], comp, x)
    np.minimum.at(box[:, 1], comp, y)
    np.maximum.at(box[:, 2], comp, x)
    np.maximum.at(box[:, 3], comp, y)
    # texture_mesh's rectangle of a chart holds its texel box widened by ``pad``: so does the copy (boxes that
    # overlap by a texel or two, from rounding, are copied each with its own; more overlap: one box)
    lo = np.clip(np.floor(box[:, :2]) - pad, 0, [W0 - 1, H0 - 1])
    hi = np.clip(np.ceil(box[:, 2:]) + pad, 0, [W0 - 1, H0 - 1])
    group = _merge_boxes(np.concatenate([lo, hi], 1), -1.0)
    ng = group.max() + 1
    g_lo = np.full((ng, 2), np.inf)
    g_hi = np.full((ng, 2), -np.inf)
    np.minimum.at(g_lo, group, lo)
    np.maximum.at(g_hi, group, hi)
    g_lo, g_hi = g_lo.astype(np.int64), g_hi.astype(np.int64)
    sizes = g_hi - g_lo + 1
    width = int(np.ceil(max(np.sqrt((sizes[:, 0] * sizes[:, 1]).sum()), sizes[:, 0].max()) / 4) * 4)
    while True:
        pos, used = shelf_pack(sizes, width)
        if used <= width or width >= W0:
            break
        width = min(W0, int(np.ceil(width * 1.05 / 4) * 4))
    height = min(int(np.ceil(used / 4) * 4), H0) if used <= H0 else None
    if height is None or width > W0:  # cannot happen (the boxes come from a W0 x H0 atlas); kept as it was
        return mesh, atlas
    new = np.zeros((height, width, 3), np.uint8)
    for g in range(ng):
        (x0, y0), (w, h), (px, py) = g_lo[g], sizes[g], pos[g]
        new[py:py + h, px:px + w] = atlas[y0:y0 + h, x0:x0 + w]
    shift = (pos - g_lo)[group[comp]]
    x2, y2 = x + shift[:, 0], y + shift[:, 1]
    uv2 = np.stack([(x2 + 0.5) / width, 1.0 - (y2 + 0.5) / height], 1)
    out = trimesh.Trimesh(np.asarray(mesh.vertices), F, process=False,
                          visual=trimesh.visual.TextureVisuals(uv=uv2, material=_material(new)))
    return out, new


def _material(atlas: np.ndarray, name: str = MATERIAL_NAME):
    from PIL import Image

    return trimesh.visual.material.PBRMaterial(name=name, baseColorTexture=Image.fromarray(atlas),
                                               metallicFactor=0.0, roughnessFactor=1.0)


def model_parts(mesh: trimesh.Trimesh, invented: np.ndarray | None) -> list[tuple[str, trimesh.Trimesh]]:
    """(material name, part) for the seen faces of ``mesh`` (TextureVisuals) and, when ``invented`` marks any, the
    invented ones: each part with the vertices and UVs its faces use."""
    F = np.asarray(mesh.faces, np.int64)
    sel = np.zeros(len(F), bool) if invented is None else np.asarray(invented, bool)
    parts = []
    for name, faces in ((MATERIAL_NAME, F[~sel]), (INVENTED_MATERIAL, F[sel])):
        if len(faces):
            used, inv = np.unique(faces, return_inverse=True)
            uv = np.asarray(mesh.visual.uv)[used]
            parts.append((name, trimesh.Trimesh(np.asarray(mesh.vertices)[used], inv.reshape(-1, 3), process=False,
                                                visual=trimesh.visual.TextureVisuals(uv=uv))))
    return parts


# --- building it ---------------------------------------------------------------------------------------------
def build_model(mesh: trimesh.Trimesh, views: list[View], images: Callable[[int], np.ndarray],
                cfg: ModelConfig | None = None, texture: TextureConfig | None = None,
                masks: Callable[[View], np.ndarray | None] | None = None, invented: np.ndarray | None = None) -> Model:
    """``mesh`` simplified to ``cfg.model_faces`` and textured from ``views`` (``images(k)``: the k-th view's
    photo) with the settings ``texture`` (its ``atlas_size`` and ``texture_faces`` are the model's:
    ``cfg.max_atlas``, ``cfg.model_faces``), the atlas compacted (``compact_atlas``). ``invented``: (F,) bool,
    a closed surface's faces no photo saw (``model_surface``): carried through the simplification
    (``carry_marks``), coloured from the faces around them, ``Model.invented`` of the model's faces."""
    from .clean import simplify
    from .close import close_mesh

    cfg = expect_config(cfg, ModelConfig, "cfg")
    texture = expect_config(texture, TextureConfig, "texture")
    check_config(cfg)
    faces_in = len(mesh.faces)
    t0 = time.process_time()
    if cfg.model_faces and faces_in > cfg.model_faces:
        simple = simplify(mesh, cfg.model_faces)
        log.info("model: mesh simplified from %d to %d faces", faces_in, len(simple.faces))
        if invented is not None:
            invented = carry_marks(mesh, invented, simple)
            if not simple.is_watertight and mesh.is_watertight:  # a collapse opened it: closed again, invented
                simple.face_attributes["filled"] = invented.astype(np.uint8)
                simple = close_mesh(simple)
                invented = simple.face_attributes["filled"] > 0
        mesh = simple
    cpu_simplify = time.process_time() - t0
    side = atlas_within_memory(cfg.max_atlas)
    res = texture_mesh(mesh, views, images, replace(texture, atlas_size=side, texture_faces=0), masks, invented)
    out, atlas = compact_atlas(res.mesh, res.atlas, texture.padding, block=res.labels < 0)
    info = {key: res.info[key] for key in ("faces", "vertices", "views_used", "views_blind", "unseen_faces",
                                           "inconsistent_views_dropped", "charts", "texels_per_pixel")
            if key in res.info}
    info.update(faces_in=int(faces_in), faces=int(len(out.faces)), vertices=int(len(out.vertices)),
                atlases=[[int(atlas.shape[1]), int(atlas.shape[0])]], atlas_limit=side,
                simplify_cpu_seconds=round(cpu_simplify, 2))
    if invented is not None:  # the unseen faces of the seen part apart from the invented ones
        area = np.asarray(mesh.area_faces, np.float64)
        info.update(unseen_faces=int(((res.labels < 0) & ~invented).sum()), invented_faces=int(invented.sum()),
                    invented_area_share=round(float(area[invented].sum() / max(area.sum(), 1e-300)), 4),
                    watertight=bool(mesh.is_watertight))
    return Model(out, atlas, info, invented)


# --- the model's frame ------------------------------------------------------------------------------------------
def model_frame(mesh: trimesh.Trimesh, views: list[View], fusion: dict | None = None,
                scale: dict | None = None) -> Upright:
    """The upright frame of the model of ``mesh`` (the cleaned mesh, in the reconstruction's frame) seen by
    ``views``: ``upright.upright_frame`` given what the fusion stage recorded (``fusion``, report.json's
    ``mesh``: the scene the cleaning detected, the support plane it removed, the voxel size; the mesh's own
    ``metadata`` where ``fusion`` lacks them) and the poses stage's ``scale`` (report.json's ``poses.scale``:
    units "metre": the model's units are metres; method "gps": the world is east-north-up, its +Z up for an
    open scene). The support plane must be the cleaning's: the cleaned mesh has lost it, and the cameras' up
    is wrong for a rig whose cameras hang upside down."""
    fusion = fusion if isinstance(fusion, dict) else {}
    scale = scale if isinstance(scale, dict) else {}
    meta = cleaning_facts(mesh, fusion)
    bare = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    bare.metadata = meta
    units = "metres" if scale.get("units") == "metre" else "scene units (the reconstruction's, not metric)"
    known_up = None
    if scale.get("method") == "gps":
        known_up = (np.array([0.0, 0.0, 1.0]), "GPS up",
                    "up of the east-north-up frame the photos' GPS positions aligned the reconstruction to")
    return upright_frame(bare, views, units=units, known_up=known_up)


def frame_info(frame: Upright) -> dict:
    """report.json's ``texture.frame``: the rule and the 4x4 ``model_from_reconstruction``."""
    d = frame.to_dict()
    info = {"rule": d["rule"], "reason": d["reason"], "units": d["units"], "up": "+Y", "forward": "+Z",
            "model_from_reconstruction": d.pop("model_from_world"),
            "reconstruction_frame": ["mesh.ply", "sparse/0", "transforms.json"]}
    if "support_plane" in d:
        info["support_plane"] = d["support_plane"]
    return info


# --- files -----------------------------------------------------------------------------------------------------
def _encode(atlas: np.ndarray, fmt: str) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    if fmt == "JPEG":
        Image.fromarray(atlas).save(buf, format="JPEG", quality=JPEG_QUALITY, subsampling=0)
    else:
        Image.fromarray(atlas).save(buf, format="PNG", optimize=False, compress_level=3)
    return buf.getvalue()


def model_glb(mesh: trimesh.Trimesh, atlas: np.ndarray, invented: np.ndarray | None = None) -> bytes:
    """``mesh`` as GLB with ``atlas`` embedded as JPEG (trimesh writes the geometry and material around a
    1x1 stand-in image, whose bytes are then replaced: trimesh itself embeds PNG, or JPEG at quality 75). With
    ``invented`` faces: one glTF mesh of two primitives (``model_parts``), the second with the material
    ``"invented"``; both materials show the one atlas."""
    scene = trimesh.Scene()
    for name, part in model_parts(mesh, invented):
        part.visual.material = _material(np.zeros((1, 1, 3), np.uint8), name)
        scene.add_geometry(part, geom_name=name)
    glb = trimesh.exchange.gltf.export_glb(scene)
    return replace_glb_images(glb, {0: (_encode(atlas, "JPEG"), "image/jpeg")}, edit=_one_mesh)


def _one_mesh(doc: dict) -> None:
    """trimesh's glTF of several geometries (a node and a mesh each) made one mesh of their primitives, every
    material on the first texture (the one atlas)."""
    meshes, nodes = doc.get("meshes", []), doc.get("nodes", [])
    if len(meshes) > 1 and all("children" not in nd for nd in nodes) and len(doc.get("scenes", [])) == 1:
        meshes[0]["primitives"] = [prim for m in meshes for prim in m["primitives"]]
        del meshes[1:]
        doc["nodes"] = [nd for nd in nodes if nd.get("mesh", 0) == 0][:1]
        doc["scenes"][0]["nodes"] = [0]
    for mat in doc.get("materials", []):
        if "baseColorTexture" in mat.get("pbrMetallicRoughness", {}):
            mat["pbrMetallicRoughness"]["baseColorTexture"]["index"] = 0
        if mat.get("name") == INVENTED_MATERIAL:
            mat["extras"] = {"photorecon": "faces no photo saw (the closing of the surface): coloured from the "
                                           "seen faces around them"}
    doc["textures"], doc["images"] = doc.get("textures", [])[:1], doc.get("images", [])[:1]


def replace_glb_images(glb: bytes, images: dict[int, tuple[bytes, str]],
                       edit: Callable[[dict], None] | None = None) -> bytes:
    """``glb`` with image ``i``'s bytes and MIME type replaced by ``images[i]``; every buffer view moved to its
    new offset (4-byte aligned) in the one binary chunk. ``edit``: changes the JSON document first."""
    n = struct.unpack_from("<I", glb, 12)[0]
    doc = json.loads(glb[20:20 + n])
    if edit is not None:
        edit(doc)
    bin_len = struct.unpack_from("<I", glb, 20 + n)[0]
    data = glb[28 + n:28 + n + bin_len]
    by_view = {}
    for i, (payload, mime) in images.items():
        img = doc["images"][i]
        by_view[img["bufferView"]] = payload
        img["mimeType"] = mime
    new = bytearray()
    for k, bv in enumerate(doc["bufferViews"]):
        start = bv.get("byteOffset", 0)
        chunk = by_view.get(k, data[start:start + bv["byteLength"]])
        new += b"\0" * (-len(new) % 4)
        bv["byteOffset"], bv["byteLength"] = len(new), len(chunk)
        new += chunk
    new += b"\0" * (-len(new) % 4)
    doc["buffers"][0]["byteLength"] = len(new)
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    total = 12 + 8 + len(js) + 8 + len(new)
    return (struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(js), 0x4E4F534A) + js
            + struct.pack("<II", len(new), 0x004E4942) + bytes(new))


def _obj_text(mesh: trimesh.Trimesh, invented: np.ndarray | None, mtl_name: str) -> str:
    """model.obj: the vertices and UVs (one UV per vertex), then the faces of each part (``model_parts``) after
    its ``usemtl``."""
    a2s = trimesh.util.array_to_string
    F = np.asarray(mesh.faces, np.int64)
    sel = np.zeros(len(F), bool) if invented is None else np.asarray(invented, bool)
    lines = [f"mtllib {mtl_name}", "v " + a2s(np.asarray(mesh.vertices), col_delim=" ", row_delim="\nv ", digits=8),
             "vt " + a2s(np.asarray(mesh.visual.uv), col_delim=" ", row_delim="\nvt ", digits=8)]
    for name, faces in ((MATERIAL_NAME, F[~sel]), (INVENTED_MATERIAL, F[sel])):
        if len(faces):
            lines += [f"usemtl {name}", "f " + a2s(faces + 1, col_delim=" ", row_delim="\nf ", value_format="{}/{}")]
    return "\n".join(lines) + "\n"


def export_model(model: Model, layout: Layout, formats: tuple[str, ...] | list[str]) -> dict:
    """Write ``model_paths(layout, formats)``, each file atomically. Returns file name -> size in bytes."""
    written = {}
    path = layout.model("glb")
    with atomic_path(path) as tmp:
        tmp.write_bytes(model_glb(model.mesh, model.atlas, model.invented))
    written[path.name] = path.stat().st_size
    if "obj" in formats:
        text = _obj_text(model.mesh, model.invented, layout.model("mtl").name)
        mtl = "\n".join(f"newmtl {name}\nKa 1.000000 1.000000 1.000000\nKd 1.000000 1.000000 1.000000\n"
                        f"Ks 0.000000 0.000000 0.000000\nNs 1.000000\nillum 1\nmap_Kd {layout.model('png').name}\n"
                        for name in [MATERIAL_NAME] + [INVENTED_MATERIAL] * bool(np.any(model.invented)))
        for p, payload in ((layout.model("png"), _encode(model.atlas, "PNG")), (layout.model("mtl"), mtl.encode()),
                           (layout.model("obj"), text.encode())):
            with atomic_path(p) as tmp:
                tmp.write_bytes(payload)
            written[p.name] = p.stat().st_size
    return written


# --- the stage on a reconstruct output folder --------------------------------------------------------------------
def model_output(out: str | Path, cfg: ModelConfig | None = None, texture: TextureConfig | None = None,
                 formats: tuple[str, ...] | list[str] = ("glb",), mesh: trimesh.Trimesh | None = None,
                 fusion: dict | None = None, scale: dict | None = None) -> dict:
    """``reconstruct``'s model stage on its output folder ``out`` (cameras in sparse/0 or transforms.json,
    photos in images/, masks in masks/): ``mesh`` (default ``out``/mesh.ply) -> ``out``/model.glb (and
    model.obj, .mtl, .png with obj in ``formats``), in the upright frame ``model_frame`` finds from ``fusion``
    and ``scale`` (the fusion and poses stages' facts). Returns the facts for report.json's ``texture`` section,
    the frame in its ``frame``."""
    from ..io.dataset import Dataset
    from .export import load_mesh

    t0 = time.process_time()
    cfg = expect_config(cfg, ModelConfig, "cfg")
    out = Path(out)
    layout = Layout(out)
    ds = Dataset.open(out)
    if mesh is None:
        if not layout.mesh("ply").is_file():
            raise InputDataError(f"{out}: no mesh.ply to make the textured model from")
        mesh = load_mesh(layout.mesh("ply"))
    views = ds.views
    if not views:
        raise TextureError(f"{out}: no cameras: the textured model needs the views the mesh was made from")
    t1 = time.process_time()
    frame = model_frame(mesh, views, fusion, scale)  # the open mesh's: the same frame for either surface
    cpu_frame = time.process_time() - t1
    surface, invented, why = model_surface(mesh, cfg.model_surface, layout, fusion)
    log.info("model: the %s surface (%s)", "open" if invented is None else "closed", why)
    model = build_model(surface, views, lambda k: ds.image(views[k]), cfg, texture, ds.mask, invented)
    model.mesh.apply_transform(frame.model_from_world)  # textured in the photos' frame, written upright
    files = export_model(model, layout, formats)
    info = {**model.info, "surface": "open" if invented is None else "closed", "surface_reason": why,
            "files": files, "file_size": files[layout.model("glb").name],
            "frame": frame_info(frame), "frame_cpu_seconds": round(cpu_frame, 2),
            "cpu_seconds": round(time.process_time() - t0, 2)}
    w, h = info["atlases"][0]
    log.info("model: %d faces, %dx%d atlas (%.2f texels per photo pixel), %d views used -> %s (%.1f MB)",
             info["faces"], w, h, info.get("texels_per_pixel", 0.0), info.get("views_used", 0),
             layout.model("glb"), info["file_size"] / 2**20)
    return info
