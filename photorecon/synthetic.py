"""Synthetic scenes with ground truth: procedural or loaded meshes, camera rigs, datasets rendered with
``render.Renderer`` (CPU ray casting; see render.py for the pixel convention and shading).

Output layout of ``write_dataset`` (the interface of every later stage)::

    DIR/images/NAME.png        8-bit RGB
    DIR/depth/NAME.npy         float32 z-depth in scene units, 0 where no surface
    DIR/depth/NAME.png         colour-mapped preview
    DIR/masks/NAME.png         255 where a surface was hit (= depth > 0)
    DIR/sparse/0/              COLMAP text model (cameras, images, points3D with visibility)
    DIR/transforms.json        NeRF convention (camera-to-world, OpenGL axes), nerfstudio-readable
    DIR/gt_mesh.ply            ground-truth mesh in the cameras' world frame
    DIR/scene.json             normalisation (world = (input - center) / scale), rig and render settings
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh

from .cameras import Intrinsics, View, look_at_views, ring_positions, sphere_positions
from .conventions import Y_UP_FROM_Z_UP
from .errors import BadArgumentError, InputDataError
from .io.atomic import atomic_write_json
from .io.colmap_text import SparseModel, write_colmap_text
from .io.images import write_depth, write_image
from .io.nerf import write_transforms
from .io.output import output_folder
from .layout import Layout
from .mesh import export, load_mesh
from .progress import bar
from .render import Renderer, SolidNoise
from .config_checks import check_config

log = logging.getLogger("photorecon")

SCENES = ("blob", "knot", "room", "relief")


@dataclass
class SynthConfig:
    """Settings of ``photorecon synth``."""

    scene: Literal["blob", "knot", "room", "relief"] = field(default="blob", metadata={"help": "built-in procedural scene (relief: a unit sphere with bumps 2 thousandths of its radius high, under one pixel footprint at the default rig)"})
    mesh: str | None = field(default=None, metadata={"help": "mesh file (OBJ, PLY, GLB, STL, OFF) instead of --scene", "metavar": "FILE"})
    rig: Literal["sphere", "ring", "hemisphere", "stereo", "pair"] = field(default="sphere", metadata={"help": "camera placement: sphere, ring or hemisphere around the scene; stereo = a rectified pair (--baseline apart along x); pair = two cameras --baseline apart looking at the centre (--views ignored)"})
    baseline: float = field(default=0.3, metadata={"help": "stereo and pair rigs: distance between the two cameras, scene units", "range": (0.0, 1e9), "exclusive_min": True})
    views: int = field(default=40, metadata={"help": "number of views", "range": (1, 100_000)})
    width: int = field(default=640, metadata={"help": "image width, pixels", "range": (16, 16384)})
    height: int = field(default=480, metadata={"help": "image height, pixels", "range": (16, 16384)})
    fov: float = field(default=50.0, metadata={"help": "horizontal field of view, degrees", "range": (0.0, 179.0), "exclusive_min": True})
    radius: float = field(default=3.0, metadata={"help": "camera distance from the scene centre, scene units", "range": (0.0, 1e9), "exclusive_min": True})
    elevation: float = field(default=20.0, metadata={"help": "ring rig: elevation, degrees", "range": (-90.0, 90.0)})
    up: Literal["z", "y"] = field(default="z", metadata={"help": "world up axis of the rig (y for y-up meshes)"})
    jitter_deg: float = field(default=0.0, metadata={"help": "random rotation added to each camera, degrees", "range": (0.0, 180.0)})
    jitter_pos: float = field(default=0.0, metadata={"help": "random camera offset, fraction of the radius", "range": (0.0, 10.0)})
    background: Literal["color", "texture"] = field(default="color", metadata={"help": "plain or textured backdrop"})
    points: int = field(default=4000, metadata={"help": "surface points sampled for the sparse COLMAP model", "range": (0, 100_000_000)})
    seed: int = field(default=0, metadata={"help": "random seed (texture, jitter, sparse points)", "range": (0, 2**31 - 1)})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.config_checks)


# --- scenes ------------------------------------------------------------------------------------------------
def make_scene(name: str, seed: int = 0) -> trimesh.Trimesh:
    """A built-in procedural scene, roughly in [-1, 1]^3, z up."""
    if name == "blob":
        m = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
        v = m.vertices
        n = SolidNoise(seed + 11, base_freq=1.2, octaves=3, channels=1)
        disp = 0.25 * (n(v)[:, 0] - 0.5)
        return trimesh.Trimesh(v * (1.0 + disp)[:, None], m.faces, process=False)
    if name == "knot":
        return _torus_knot()
    if name == "relief":
        return relief_sphere(seed)
    if name == "room":
        parts = []
        floor = trimesh.creation.box(extents=(2.4, 2.4, 0.05))
        floor.apply_translation((0, 0, -0.025))
        parts.append(floor)
        for ext, pos in [((2.4, 0.06, 0.6), (0, 1.17, 0.3)), ((0.06, 2.4, 0.6), (-1.17, 0, 0.3)),
                         ((0.06, 1.0, 0.5), (1.17, -0.7, 0.25))]:
            w = trimesh.creation.box(extents=ext)
            w.apply_translation(pos)
            parts.append(w)
        box = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
        box.apply_transform(trimesh.transformations.rotation_matrix(0.5, (0, 0, 1)))
        box.apply_translation((0.45, 0.35, 0.25))
        parts.append(box)
        sph = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
        sph.apply_translation((-0.45, -0.35, 0.3))
        parts.append(sph)
        cyl = trimesh.creation.cylinder(radius=0.15, height=0.7, sections=48)
        cyl.apply_translation((0.5, -0.5, 0.35))
        parts.append(cyl)
        # a cup-like concavity: an open box (five walls)
        for ext, pos in [((0.5, 0.5, 0.04), (-0.5, 0.5, 0.02)), ((0.5, 0.04, 0.3), (-0.5, 0.27, 0.15)),
                         ((0.5, 0.04, 0.3), (-0.5, 0.73, 0.15)), ((0.04, 0.5, 0.3), (-0.73, 0.5, 0.15)),
                         ((0.04, 0.5, 0.3), (-0.27, 0.5, 0.15))]:
            w = trimesh.creation.box(extents=ext)
            w.apply_translation(pos)
            parts.append(w)
        return trimesh.util.concatenate(parts)
    raise BadArgumentError(f"scene: expected one of {SCENES}, got {name!r}")


def relief_sphere(seed: int = 0, bumps: int = 600, height: float = 0.002, sigma: float = 0.03,
                  subdivisions: int = 7) -> trimesh.Trimesh:
    """A unit sphere with ``bumps`` Gaussian bumps (``height`` high, ``sigma`` wide, scene units) at random
    places: relief below a pixel's footprint (at the default 640-pixel, 50-degree rig, 3 units out, a pixel
    covers about 0.003 on the surface), wide enough (about 20 footprints) for the photos to show it."""
    from scipy.spatial import cKDTree

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = np.asarray(m.vertices, float)
    rng = np.random.default_rng(seed + 23)
    c = rng.normal(size=(bumps, 3))
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    r = np.zeros(len(v))
    for i, nb in enumerate(cKDTree(v).query_ball_point(c, 4 * sigma)):
        nb = np.asarray(nb, int)
        r[nb] += height * np.exp(-np.sum((v[nb] - c[i]) ** 2, axis=1) / (2 * sigma ** 2))
    return trimesh.Trimesh(v * (1.0 + r)[:, None], m.faces, process=False)


def _torus_knot(p: int = 2, q: int = 3, n_seg: int = 600, n_ring: int = 24, tube: float = 0.16) -> trimesh.Trimesh:
    t = np.linspace(0, 2 * np.pi, n_seg, endpoint=False)
    r = 2 + np.cos(q * t)
    c = np.stack([r * np.cos(p * t), r * np.sin(p * t), -np.sin(q * t)], 1) / 3.0
    tang = np.roll(c, -1, 0) - np.roll(c, 1, 0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    ref = np.array([0.0, 0.0, 1.0])
    nrm = np.cross(tang, ref)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    bin_ = np.cross(tang, nrm)
    a = np.linspace(0, 2 * np.pi, n_ring, endpoint=False)
    verts = (c[:, None] + tube * (np.cos(a)[None, :, None] * nrm[:, None] + np.sin(a)[None, :, None] * bin_[:, None]))
    verts = verts.reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_seg), np.arange(n_ring), indexing="ij")
    i2, j2 = (i + 1) % n_seg, (j + 1) % n_ring
    a0, a1, a2, a3 = i * n_ring + j, i2 * n_ring + j, i2 * n_ring + j2, i * n_ring + j2
    faces = np.concatenate([np.stack([a0, a1, a2], -1).reshape(-1, 3), np.stack([a0, a2, a3], -1).reshape(-1, 3)])
    return trimesh.Trimesh(verts, faces, process=False)


def normalize_mesh(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray, float]:
    """Centre on the vertex mean and scale so the largest absolute coordinate is 1 (as the article does).
    Returns (mesh, center, scale) with ``world = (input - center) / scale``."""
    v = np.asarray(mesh.vertices, float)
    center = v.mean(0)
    scale = float(np.abs(v - center).max())
    if not scale > 0:
        raise InputDataError("the mesh is a single point; nothing to render")
    out = mesh.copy()
    out.vertices = (v - center) / scale
    return out, center, scale


# --- cameras -----------------------------------------------------------------------------------------------
def make_views(cfg: SynthConfig) -> list[View]:
    if cfg.views < 1:
        raise BadArgumentError(f"--views: expected at least 1 view, got {cfg.views}")
    if cfg.width < 1 or cfg.height < 1:
        raise BadArgumentError(f"image size: expected positive width and height, got {cfg.width}x{cfg.height}")
    intr = Intrinsics.from_fov(cfg.width, cfg.height, cfg.fov)
    if cfg.rig in ("stereo", "pair"):
        return _two_views(cfg, intr)
    if cfg.rig == "ring":
        pos = ring_positions(cfg.views, cfg.radius, cfg.elevation)
    else:
        pos = sphere_positions(cfg.views, cfg.radius, hemisphere=cfg.rig == "hemisphere")
    up = np.array([0.0, 0.0, 1.0])
    if cfg.up == "y":  # rotate the z-up placement into a y-up world
        pos = pos @ Y_UP_FROM_Z_UP.T
        up = np.array([0.0, 1.0, 0.0])
    rng = np.random.default_rng(cfg.seed + 7)
    if cfg.jitter_pos > 0:
        pos = pos + rng.normal(size=pos.shape) * cfg.jitter_pos * cfg.radius
    views = []
    for i, T in enumerate(look_at_views(pos, (0, 0, 0), up)):
        if cfg.jitter_deg > 0:
            from scipy.spatial.transform import Rotation

            J = np.eye(4)
            J[:3, :3] = Rotation.from_rotvec(rng.normal(size=3) * np.radians(cfg.jitter_deg) / np.sqrt(3)).as_matrix()
            T = J @ T
        views.append(View(f"view_{i:03d}", intr, T, image_file=f"view_{i:03d}.png"))
    return views


def _two_views(cfg: SynthConfig, intr: Intrinsics) -> list[View]:
    """Two cameras ``cfg.baseline`` apart along the image x axis of a camera at ``cfg.radius`` and
    ``cfg.elevation`` degrees looking at the centre: one orientation (``stereo``: a rectified pair, disparity =
    fx * baseline / depth) or each looking at the centre (``pair``)."""
    if not cfg.baseline > 0:
        raise BadArgumentError(f"--baseline: expected > 0, got {cfg.baseline}")
    up = np.array([0.0, 1.0, 0.0]) if cfg.up == "y" else np.array([0.0, 0.0, 1.0])
    centre = ring_positions(1, cfg.radius, cfg.elevation)[0] @ (Y_UP_FROM_Z_UP.T if cfg.up == "y" else np.eye(3))
    T = look_at_views([centre], (0, 0, 0), up)[0]
    x_axis = T[0, :3]  # the image x axis in the world
    pos = [centre - 0.5 * cfg.baseline * x_axis, centre + 0.5 * cfg.baseline * x_axis]
    views = []
    for i, p in enumerate(pos):
        if cfg.rig == "stereo":
            Ti = T.copy()
            Ti[:3, 3] = -T[:3, :3] @ p
        else:
            Ti = look_at_views([p], (0, 0, 0), up)[0]
        views.append(View(f"view_{i:03d}", intr, Ti, image_file=f"view_{i:03d}.png"))
    return views


# --- the dataset -------------------------------------------------------------------------------------------
@dataclass
class SynthResult:
    root: Path
    views: list[View]
    mesh: trimesh.Trimesh
    seconds_per_view: float


def synthesize(cfg: SynthConfig, out: str | Path, overwrite: bool = False) -> SynthResult:
    """Render ``cfg`` into ``out`` (see the module docstring for the layout). Returns the views and mesh.

    Inputs are validated before anything is written; ``out`` goes through the output guard (``io.output``:
    new, empty or synth's own, else ``OutputError`` unless ``overwrite``); a failed run leaves none of its files."""
    if cfg.mesh:
        src = load_mesh(cfg.mesh)
        source = str(cfg.mesh)
    else:
        src = make_scene(cfg.scene, cfg.seed)
        source = f"scene:{cfg.scene}"
    mesh, center, scale = normalize_mesh(src)
    views = make_views(cfg)
    renderer = Renderer(mesh, cfg.seed, cfg.background)
    with output_folder(out, overwrite, inputs=(cfg.mesh,) if cfg.mesh else (), command="synth",
                       resumable=False) as out:
        layout = Layout(out)
        for d in (layout.images, layout.depth, layout.masks, layout.sparse):
            d.mkdir(parents=True, exist_ok=True)
        t_render = 0.0
        for view in bar(views, desc="render"):
            t0 = time.perf_counter()
            r = renderer.render(view)
            t_render += time.perf_counter() - t0
            write_image(layout.image(f"{view.name}.png"), r.rgb)
            write_depth(layout.depth, view.name, r.depth)
            write_image(layout.mask(view.name), (r.mask * 255).astype(np.uint8))
        sparse = sparse_model_from_surface(renderer, views, cfg.points, cfg.seed)
        write_colmap_text(sparse, layout.sparse)
        write_transforms(views, layout.transforms, world="none", depth_dir=layout.depth.name, mask_dir=layout.masks.name)
        export(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), layout.gt_mesh)
        info = {"source": source, "normalization": {"center": center.tolist(), "scale": scale,
                                                    "formula": "world = (input - center) / scale"},
                "config": asdict(cfg), "appearance": renderer.appearance.kind,
                "bbox_diagonal": float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0])),
                "render_seconds_per_view": t_render / len(views)}
        atomic_write_json(layout.scene, info)
        log.info("synth: %d views of %s (%s texture) written to %s", len(views), source, renderer.appearance.kind, out)
        return SynthResult(out, views, mesh, t_render / len(views))


def sparse_model_from_surface(renderer: Renderer, views: list[View], n_points: int, seed: int = 0) -> SparseModel:
    """Sample surface points area-uniformly; keep those seen in >= 2 views, with their exact projections."""
    mesh = renderer.mesh
    if n_points > 0:
        pts, face = trimesh.sample.sample_surface(mesh, n_points, seed=seed)
        normals = np.asarray(mesh.face_normals)[face]
    else:
        pts, normals = np.zeros((0, 3)), np.zeros((0, 3))
    pts = np.asarray(pts, float)
    vis_all = []
    uv_all = []
    for v in views:
        vis, uv = renderer.visible(pts, v, normals)
        vis_all.append(vis)
        uv_all.append(uv)
    vis_all = np.array(vis_all).reshape(len(views), len(pts))
    keep = vis_all.sum(0) >= 2
    ids = np.arange(1, keep.sum() + 1)
    idx = np.flatnonzero(keep)
    obs = {}
    for k, v in enumerate(views):
        sel = vis_all[k, idx]
        obs[v.name] = (uv_all[k][idx][sel], ids[sel])
    colors = (np.clip(renderer.appearance.albedo(pts[idx], np.zeros(len(idx), np.int64),
                                                 np.tile([1.0, 0, 0], (len(idx), 1))), 0, 1) * 255).astype(np.uint8) \
        if renderer.appearance.kind == "noise" else np.full((len(idx), 3), 128, np.uint8)
    return SparseModel(views, pts[idx], colors, ids, np.zeros(len(idx)), obs)
