"""Synthetic scenes with ground truth: procedural or loaded meshes, camera rigs, CPU ray-cast rendering.

Rendering uses Open3D's ``RaycastingScene``: one ray per pixel centre (built from ``Intrinsics.pixel_rays``,
so the pixel convention is photorecon's), exact hit distance, triangle id and barycentrics. Rays have z = 1
in the camera, so the hit parameter *is* the z-depth. Surfaces are coloured by the mesh's texture or vertex
colours, else by a solid (3D) multi-octave noise texture that is consistent across views, and shaded with a
fixed world light (Lambertian, two-sided), so a surface point has the same colour in every view.

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

import cv2
import numpy as np
import trimesh

from .cameras import Intrinsics, View, invert_rigid, look_at_views, ring_positions, sphere_positions
from .errors import BadArgumentError, InputDataError
from .io.atomic import atomic_write_json
from .io.colmap_text import SparseModel, write_colmap_text
from .io.images import sample_bilinear, write_depth, write_image
from .io.nerf import write_transforms
from .io.output import prepare_output
from .mesh import export
from .progress import bar

log = logging.getLogger("photorecon")

SCENES = ("blob", "knot", "room")
MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf", ".stl", ".off")


@dataclass
class SynthConfig:
    """Settings of ``photorecon synth``."""

    scene: Literal["blob", "knot", "room"] = field(default="blob", metadata={"help": "built-in procedural scene"})
    mesh: str | None = field(default=None, metadata={"help": "mesh file (OBJ, PLY, GLB, STL, OFF) instead of --scene"})
    rig: Literal["sphere", "ring", "hemisphere"] = field(default="sphere", metadata={"help": "camera placement"})
    views: int = field(default=40, metadata={"help": "number of views"})
    width: int = field(default=640, metadata={"help": "image width in pixels"})
    height: int = field(default=480, metadata={"help": "image height in pixels"})
    fov: float = field(default=50.0, metadata={"help": "horizontal field of view, degrees"})
    radius: float = field(default=3.0, metadata={"help": "camera distance from the scene centre (scene units)"})
    elevation: float = field(default=20.0, metadata={"help": "ring rig: elevation in degrees"})
    up: Literal["z", "y"] = field(default="z", metadata={"help": "world up axis of the rig (y for y-up meshes)"})
    jitter_deg: float = field(default=0.0, metadata={"help": "random rotation added to each camera, degrees"})
    jitter_pos: float = field(default=0.0, metadata={"help": "random camera offset, fraction of the radius"})
    background: Literal["color", "texture"] = field(default="color", metadata={"help": "plain or textured backdrop"})
    points: int = field(default=4000, metadata={"help": "surface points sampled for the sparse COLMAP model"})
    seed: int = field(default=0, metadata={"help": "random seed (texture, jitter, sparse points)"})


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


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """Load a mesh file as one ``Trimesh`` (scenes are concatenated), keeping texture/vertex colours.

    Raises ``InputDataError`` naming the file when it is missing, unreadable or has no faces.
    """
    path = Path(path)
    if not path.is_file():
        raise InputDataError(f"{path}: no such mesh file")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputDataError(f"{path}: unsupported mesh format {path.suffix!r}; expected one of {MESH_SUFFIXES}")
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise InputDataError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)] if loaded.geometry else []
        loaded = trimesh.util.concatenate(geoms) if geoms else None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputDataError(f"{path}: the mesh has no faces; a triangle mesh is needed to render")
    return loaded


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


# --- texture -----------------------------------------------------------------------------------------------
class SolidNoise:
    """Multi-octave 3D value noise in [0, 1]: a periodic random lattice per octave, trilinear with smoothstep."""

    def __init__(self, seed: int = 0, base_freq: float = 4.0, octaves: int = 5, channels: int = 3,
                 lattice: int = 64, gain: float = 0.75):
        rng = np.random.default_rng(seed)
        self.tables = [rng.random((lattice, lattice, lattice, channels), dtype=np.float32) for _ in range(octaves)]
        self.shifts = rng.random((octaves, 3)) * lattice
        self.freqs = [base_freq * 2.0 ** k for k in range(octaves)]
        amps = np.array([gain ** k for k in range(octaves)])
        self.amps = amps / amps.sum()
        self.L = lattice

    def __call__(self, points: np.ndarray) -> np.ndarray:
        pts = np.asarray(points, np.float32)
        out = np.zeros((len(pts), self.tables[0].shape[-1]), np.float32)
        L = self.L
        for table, shift, f, a in zip(self.tables, self.shifts, self.freqs, self.amps):
            flat = table.reshape(L * L * L, -1)
            q = pts * np.float32(f) + shift.astype(np.float32)
            i0 = np.floor(q)
            w = q - i0
            w = w * w * (3 - 2 * w)
            i0 = i0.astype(np.int64) % L
            i1 = (i0 + 1) % L
            acc = np.zeros_like(out)
            for dx in (0, 1):
                ix = (i1[:, 0] if dx else i0[:, 0]) * (L * L)
                wx = w[:, 0] if dx else 1 - w[:, 0]
                for dy in (0, 1):
                    ixy = ix + (i1[:, 1] if dy else i0[:, 1]) * L
                    wxy = wx * (w[:, 1] if dy else 1 - w[:, 1])
                    for dz in (0, 1):
                        idx = ixy + (i1[:, 2] if dz else i0[:, 2])
                        acc += np.take(flat, idx, axis=0) * (wxy * (w[:, 2] if dz else 1 - w[:, 2]))[:, None]
            out += np.float32(a) * acc
        return out


class Appearance:
    """Surface albedo at hit points: the mesh's texture (UV) or vertex colours if present, else solid noise."""

    def __init__(self, mesh: trimesh.Trimesh, seed: int = 0, plain: bool = False):
        self.faces = np.asarray(mesh.faces)
        self.kind = "noise"
        self.plain = plain
        vis = mesh.visual
        self.uv = self.image = self.vcolors = None
        if isinstance(vis, trimesh.visual.TextureVisuals) and vis.uv is not None:
            img = getattr(vis.material, "image", None) or getattr(vis.material, "baseColorTexture", None)
            if img is not None and len(vis.uv) == len(mesh.vertices):
                self.uv = np.asarray(vis.uv, np.float64)
                self.image = np.asarray(img.convert("RGB"), np.float32) / 255.0
                self.kind = "texture"
        if self.kind == "noise" and vis.kind == "vertex":
            vc = np.asarray(vis.vertex_colors)[:, :3].astype(np.float32) / 255.0
            if vc.std() > 1e-3:  # trimesh fills in a flat default colour; that is not a real colour
                self.vcolors = vc
                self.kind = "vertex"
        self.noise = SolidNoise(seed)

    def albedo(self, points: np.ndarray, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
        """(N, 3) float32 in [0, 1] for hit ``points`` on triangles ``tri`` with barycentrics (N, 3)."""
        if self.kind == "texture":
            uv = np.einsum("nk,nkc->nc", bary, self.uv[self.faces[tri]])
            h, w = self.image.shape[:2]
            # OBJ / glTF: v up, texel i's centre at (i + 0.5) / size
            x = np.clip(np.mod(uv[:, 0], 1.0) * w - 0.5, 0, w - 1).astype(np.float32)
            y = np.clip((1 - np.mod(uv[:, 1], 1.0)) * h - 0.5, 0, h - 1).astype(np.float32)
            return sample_bilinear(self.image, np.stack([x, y], 1))
        if self.kind == "vertex":
            return np.einsum("nk,nkc->nc", bary.astype(np.float32), self.vcolors[self.faces[tri]])
        if self.plain:
            return np.full((len(points), 3), 0.75, np.float32)
        n = self.noise(points)
        # stretch contrast around the mean so SIFT sees strong gradients at every scale
        return np.clip(0.5 + 2.2 * (n - 0.5), 0.03, 1.0)


# --- rendering ---------------------------------------------------------------------------------------------
@dataclass
class Render:
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 z-depth, 0 = no surface
    mask: np.ndarray  # (H, W) bool
    triangle: np.ndarray  # (H, W) int64, -1 = none
    normal: np.ndarray  # (H, W, 3) float32 world normals (zero where no surface)


LIGHT_DIR = np.array([0.4, -0.3, 0.85]) / np.linalg.norm([0.4, -0.3, 0.85])


class Renderer:
    """Ray-casts one mesh; ``render(view)`` gives RGB, z-depth, mask, triangle ids and normals.
    ``unlit``: colours as stored (texture or vertex colours baked from photos already hold their light)."""

    def __init__(self, mesh: trimesh.Trimesh, seed: int = 0, background: str = "color",
                 background_color=(0.08, 0.08, 0.1), backdrop_radius: float = 8.0, plain: bool = False,
                 soft_light: bool = False, unlit: bool = False):
        import open3d as o3d

        self.mesh = mesh
        from .mesh import raycasting_scene

        self.scene = raycasting_scene(mesh)
        self.o3d = o3d
        self.appearance = Appearance(mesh, seed, plain)
        self.face_normals = np.asarray(mesh.face_normals, np.float32)
        self.vertex_normals = np.asarray(mesh.vertex_normals, np.float32)
        self.background = background
        self.background_color = np.asarray(background_color, np.float32)
        self.backdrop = SolidNoise(seed + 101, base_freq=1.5, octaves=4)
        self.backdrop_radius = backdrop_radius
        # soft light for colours that already carry shading; none at all (unlit) for photo textures
        self.ambient = 1.0 if unlit else 0.65 if soft_light else 0.35

    def cast(self, origins: np.ndarray, dirs: np.ndarray) -> dict:
        rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
        ans = self.scene.cast_rays(self.o3d.core.Tensor(rays))
        return {k: ans[k].numpy() for k in ("t_hit", "primitive_ids", "primitive_uvs")}

    def render(self, view: View) -> Render:
        intr = view.intrinsics
        H, W = intr.height, intr.width
        rays_cam = intr.pixel_rays(intr.pixel_grid().reshape(-1, 2))  # z = 1
        world_from_cam = invert_rigid(view.cam_from_world)
        dirs = rays_cam @ world_from_cam[:3, :3].T
        origin = world_from_cam[:3, 3]
        hit = self.cast(np.broadcast_to(origin, dirs.shape), dirs)
        t = hit["t_hit"]
        ok = np.isfinite(t)
        depth = np.where(ok, t, 0).astype(np.float32)
        tri = np.where(ok, hit["primitive_ids"].astype(np.int64), -1)
        rgb = np.empty((H * W, 3), np.float32)
        normal = np.zeros((H * W, 3), np.float32)
        if ok.any():
            p = origin + dirs[ok] * t[ok, None].astype(np.float64)
            uvb = hit["primitive_uvs"][ok].astype(np.float64)
            bary = np.stack([1 - uvb[:, 0] - uvb[:, 1], uvb[:, 0], uvb[:, 1]], 1)
            alb = self.appearance.albedo(p, tri[ok], bary)
            n = self.face_normals[tri[ok]]
            normal[ok] = n
            # smooth shading where the surface is smooth; face normals across creases (boxes)
            ns = np.einsum("nk,nkc->nc", bary.astype(np.float32), self.vertex_normals[self.mesh.faces[tri[ok]]])
            ns /= np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-12)
            n = np.where((np.einsum("nc,nc->n", ns, n) > 0.95)[:, None], ns, n)
            shade = self.ambient + (1 - self.ambient) * np.abs(n @ LIGHT_DIR.astype(np.float32))
            rgb[ok] = alb * shade[:, None]
        miss = ~ok
        if miss.any():
            if self.background == "texture":
                d = dirs[miss] / np.linalg.norm(dirs[miss], axis=1, keepdims=True)
                # ray / sphere(0, R): |o + s d| = R, s > 0
                b = d @ origin
                c = origin @ origin - self.backdrop_radius ** 2
                s = -b + np.sqrt(np.maximum(b * b - c, 0))
                rgb[miss] = 0.15 + 0.6 * self.backdrop(origin + d * s[:, None])
            else:
                rgb[miss] = self.background_color
        img = (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8).reshape(H, W, 3)
        return Render(img, depth.reshape(H, W), ok.reshape(H, W), tri.reshape(H, W), normal.reshape(H, W, 3))

    def visible(self, points: np.ndarray, view: View, normals: np.ndarray | None = None, rel_tol: float = 1e-3,
                min_cos: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
        """Which ``points`` (on the surface) are seen in ``view``: (mask (N,), pixels (N, 2)). With ``normals``,
        grazing observations (|cos(normal, ray)| < ``min_cos``) are dropped, as a feature detector would."""
        from .cameras import project

        uv, z = project(points, view.intrinsics, view.cam_from_world)
        W, H = view.intrinsics.size
        with np.errstate(invalid="ignore"):
            inside = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < H - 0.5)
        vis = np.zeros(len(points), bool)
        if inside.any():
            c = view.center
            d = points[inside] - c
            t = self.cast(np.broadcast_to(c, d.shape), d)["t_hit"]
            ok = np.abs(t - 1.0) < rel_tol
            if normals is not None:
                cos = np.einsum("nc,nc->n", normals[inside], d) / np.linalg.norm(d, axis=1)
                ok &= np.abs(cos) >= min_cos
            vis[inside] = ok
        return vis, uv


# --- cameras -----------------------------------------------------------------------------------------------
def make_views(cfg: SynthConfig) -> list[View]:
    if cfg.views < 1:
        raise BadArgumentError(f"--views: expected at least 1 view, got {cfg.views}")
    if cfg.width < 1 or cfg.height < 1:
        raise BadArgumentError(f"image size: expected positive width and height, got {cfg.width}x{cfg.height}")
    intr = Intrinsics.from_fov(cfg.width, cfg.height, cfg.fov)
    if cfg.rig == "ring":
        pos = ring_positions(cfg.views, cfg.radius, cfg.elevation)
    else:
        pos = sphere_positions(cfg.views, cfg.radius, hemisphere=cfg.rig == "hemisphere")
    up = np.array([0.0, 0.0, 1.0])
    if cfg.up == "y":  # rotate the z-up placement into a y-up world: (x, y, z) -> (x, z, -y), a rotation
        pos = pos[:, [0, 2, 1]] * [1, 1, -1]
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
        views.append(View(f"view_{i:03d}", intr, T, extra={"image_file": f"view_{i:03d}.png"}))
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

    Inputs are validated before anything is written; ``out`` must be empty, new, or a photorecon output
    (else ``OutputError``, unless ``overwrite``)."""
    if cfg.mesh:
        src = load_mesh(cfg.mesh)
        source = str(cfg.mesh)
    else:
        src = make_scene(cfg.scene, cfg.seed)
        source = f"scene:{cfg.scene}"
    mesh, center, scale = normalize_mesh(src)
    views = make_views(cfg)
    renderer = Renderer(mesh, cfg.seed, cfg.background)
    out = prepare_output(out, overwrite, inputs=(cfg.mesh,) if cfg.mesh else ())
    for d in ("images", "depth", "masks", "sparse/0"):
        (out / d).mkdir(parents=True, exist_ok=True)
    t_render = 0.0
    for view in bar(views, desc="render"):
        t0 = time.perf_counter()
        r = renderer.render(view)
        t_render += time.perf_counter() - t0
        write_image(out / "images" / f"{view.name}.png", r.rgb)
        write_depth(out / "depth", view.name, r.depth)
        write_image(out / "masks" / f"{view.name}.png", (r.mask * 255).astype(np.uint8))
    sparse = sparse_model_from_surface(renderer, views, cfg.points, cfg.seed)
    write_colmap_text(sparse, out / "sparse" / "0")
    write_transforms(views, out / "transforms.json", world="none", depth_dir="depth", mask_dir="masks")
    export(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), out / "gt_mesh.ply")
    info = {"source": source, "normalization": {"center": center.tolist(), "scale": scale,
                                                "formula": "world = (input - center) / scale"},
            "config": asdict(cfg), "appearance": renderer.appearance.kind,
            "bbox_diagonal": float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0])),
            "render_seconds_per_view": t_render / len(views)}
    atomic_write_json(out / "scene.json", info)
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
