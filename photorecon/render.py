"""Ray-cast rendering of one mesh (Open3D ``RaycastingScene``), used by synthetic scenes and previews alike.

One ray per pixel centre (built from ``Intrinsics.pixel_rays``, so the pixel convention is photorecon's), exact
hit distance, triangle id and barycentrics. Rays have z = 1 in the camera, so the hit parameter *is* the
z-depth. Surfaces are coloured by the mesh's texture or vertex colours, else by a solid (3D) multi-octave noise
texture that is consistent across views, and shaded with a fixed world light (Lambertian, two-sided), so a
surface point has the same colour in every view.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from .cameras import View, invert_rigid, project
from .io.images import sample_bilinear
from .mesh import raycasting_scene


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
