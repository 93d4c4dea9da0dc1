#!/usr/bin/env python
"""Benchmark of texturing: fidelity on synthetic scenes and time.

Fidelity: ``photorecon synth`` renders a scene (sphere rig, 640x480); its true depth maps are fused (TSDF, true
poses) into a vertex-coloured mesh, decimated to ``--faces`` faces (Open3D carries the vertex colours); the same
decimated mesh is textured from the same photos. Both are rendered *unlit* (their colours are the photos' own)
from held-out views that texturing never used (a ring at 35 degrees elevation between the rig's cameras) and
compared with the true renders: PSNR over the object's pixels (the truth's mask). Scenes: blob, room and the
Stanford bunny shipped in ``photorecon/data/bunny.ply``. A second row per scene
uses the true surface (subdivided to at least ``--faces`` faces) with vertex colours averaged from the photos,
to separate texture from geometry error. Target: textured >= vertex-coloured + 3 dB.

Time: texturing 30 views of 640x480 and a 300k-face mesh (the blob's fused mesh decimated), end to end
(visibility, view selection, exposure, charts, baking, export of OBJ/MTL/PNG + GLB). Target <= 30 s on 2 cores.

Seams: on the fused mesh of each scene, the colour step across chart borders (``seams.seam_steps``: the texture
sampled one texel either side of each edge between faces with different photos, mean absolute RGB difference
0-255, minus the same across edges inside charts: the ``excess`` step) and the held-out PSNR, without and with
seam levelling, for the photos as rendered and for the photos scaled by a random gain per view and channel
(``--gains``: +-20% by default), exposure correction on and off.

Where the error lies: each fidelity row also splits the squared error by region (``error_regions``: near
occlusion boundaries, where the geometry is off, the rest) and ``--error-maps DIR`` writes the renders and their
error images.

Real photos, held out (``--real``): a capture of ``../shared/data`` is reconstructed (``photorecon reconstruct
--poses``, the defaults) from its given cameras with some photos left out (herz-jesu-p8: the 3rd and 6th of 8;
entry-p10: the 4th and 7th of 10; each walnut ring: the 6th of 12), and three results are rendered unlit from each
left-out camera: (a) ``mesh.ply`` with its vertex colours, (b) the full ``mesh.ply`` textured the way ``photorecon
texture`` does it (``texture_mesh``, no simplification, a 4096 atlas; its GLB as that command writes it), (c) the
default ``model.glb`` (mapped back into the reconstruction's frame with the inverse of report.json's
``texture.frame.model_from_reconstruction``). PSNR against the real photo over the pixels all three cover, after
one least-squares gain per RGB channel (fitted on those pixels: exposure differences do not count); ``covered``:
each result's share of the photo's pixels. Seam score of (b) and (c): ``seams.seam_steps``'s ``excess`` (colour
step across chart borders minus the step inside charts, RGB 0-255), charts being the atlas's UV islands. One
picture per capture in ``--out``: left-out photo | model.glb render. Reconstructions are kept in ``--out`` and
reused by a later run with the same settings.

    python tools/bench_texture.py [--views 30] [--faces 30000] [--json out.json] [--only fidelity|time]
                                  [--scenes blob,room,bunny] [--error-maps DIR] [--gains 0.2]
    python tools/bench_texture.py --real [--only herz,entry,walnut1..4] [--out DIR] [--json FILE]
                                  [--max-size N] [--data ../shared/data]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from photorecon import progress
from photorecon.demo import BUNNY  # the decimated Stanford bunny shipped in photorecon/data
from photorecon.fusion import FusionConfig, fuse, load_frames
from photorecon.io.dataset import Dataset
from photorecon.layout import Layout
from photorecon.mesh import CleanConfig, clean, load_mesh, simplify
from photorecon.resources import peak_bytes, reset_peak
from photorecon.render import Renderer
from photorecon.synthetic import SynthConfig, make_views, synthesize
from photorecon.mesh.seams import seam_steps
from photorecon.mesh.texture import TextureConfig, export_textured, texture_mesh



def psnr(pred: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    err = (pred[mask].astype(np.float64) - truth[mask].astype(np.float64)) ** 2
    return float(10 * np.log10(255.0 ** 2 / max(err.mean(), 1e-12)))


def error_regions(truth, textured, vertex) -> dict:
    """Where the squared error of one held-out render lies: ``edge`` (within 2 px of the truth's occlusion
    boundaries and silhouette), ``geometry`` (elsewhere, where the mesh's depth is > 0.5% off the truth's or the
    mesh is missing) and ``rest``. Per region: pixel count and summed squared error (mean over RGB) of the
    textured and the vertex-coloured render."""
    import cv2

    m, d = truth.mask, truth.depth
    jump = 0.02 * float(np.median(d[m])) if m.any() else 0.0
    edge = np.zeros_like(m)
    gy, gx = np.abs(np.diff(d, axis=0)) > jump, np.abs(np.diff(d, axis=1)) > jump
    edge[:-1] |= gy
    edge[1:] |= gy
    edge[:, :-1] |= gx
    edge[:, 1:] |= gx
    edge |= m != cv2.erode(m.astype(np.uint8), np.ones((3, 3))).astype(bool)
    edge = cv2.dilate(edge.astype(np.uint8), np.ones((5, 5))).astype(bool) & m
    with np.errstate(invalid="ignore", divide="ignore"):
        off = (np.abs(vertex.depth - d) / np.maximum(d, 1e-9) > 0.005) | ~vertex.mask
    geo = m & ~edge & off
    rest = m & ~edge & ~geo
    e_t = ((textured.rgb.astype(np.float64) - truth.rgb) ** 2).mean(2)
    e_v = ((vertex.rgb.astype(np.float64) - truth.rgb) ** 2).mean(2)
    return {k: (int(r.sum()), float(e_t[r].sum()), float(e_v[r].sum())) for k, r in
            (("edge", edge), ("geometry", geo), ("rest", rest))}


def write_error_map(path: Path, truth, textured) -> None:
    """truth | textured | |error| x 4 (grey), side by side."""
    import cv2

    err = np.abs(textured.rgb.astype(np.float64) - truth.rgb).mean(2)
    err_img = np.repeat(np.clip(4 * err, 0, 255).astype(np.uint8)[..., None], 3, 2)
    cv2.imwrite(str(path), np.concatenate([truth.rgb, textured.rgb, err_img], 1)[..., ::-1])


def held_out_views(cfg: SynthConfig, n: int = 8):
    """A ring at 35 degrees elevation, turned by half a step: none of these is a texturing view."""
    return make_views(SynthConfig(rig="ring", views=n, elevation=35.0, radius=cfg.radius, width=cfg.width,
                                  height=cfg.height, fov=cfg.fov, up=cfg.up, jitter_deg=2.0, seed=cfg.seed + 99))


def fused_mesh(root: Path) -> tuple[trimesh.Trimesh, Dataset]:
    ds = Dataset.open(root)
    # every component kept: the room's sphere touches the floor at one point and would go as a small component
    return clean(fuse(load_frames(ds, FusionConfig()), FusionConfig(), ds.model.points),
                 CleanConfig(min_component=0.0)), ds


def texture_dataset(mesh: trimesh.Trimesh, ds: Dataset, cfg: TextureConfig, gains: np.ndarray | None = None):
    """``mesh`` textured from ``ds``'s photos, each multiplied by ``gains[k]`` (V, 3) if given."""
    views = ds.views

    def images(k):
        img = ds.image(views[k])
        if gains is None:
            return img
        return np.clip(img.astype(np.float32) * gains[k] + 0.5, 0, 255).astype(np.uint8)

    return texture_mesh(mesh, views, images, cfg, ds.mask)


def seam_rows(name: str, mesh: trimesh.Trimesh, ds: Dataset, held, truths, atlas: int, spread: float) -> list[dict]:
    """Seam steps and held-out PSNR without and with seam levelling: photos as rendered (exposure correction
    on), and scaled by a random gain per view and channel within ``1 +- spread`` (exposure correction on, off)."""
    rng = np.random.default_rng(7)
    n = len(ds.views)
    gains = rng.uniform(1 - spread, 1 + spread, (n, 1)) * rng.uniform(0.97, 1.03, (n, 3))
    rows = []
    for g, exposure in ((None, True), (gains, True), (gains, False)):
        row = {"scene": name, "gains": 0.0 if g is None else spread, "exposure": exposure}
        for lev in (False, True):
            tex = texture_dataset(mesh, ds, TextureConfig(atlas_size=atlas, exposure=exposure, seam_levelling=lev), g)
            r = Renderer(tex.mesh, unlit=True)
            key = "levelled" if lev else "plain"
            row[key] = {**seam_steps(tex.mesh, tex.atlas, tex.labels),
                        "psnr": float(np.mean([psnr(r.render(v).rgb, t.rgb, t.mask) for v, t in zip(held, truths)]))}
        rows.append(row)
    return rows


def subdivided_truth(gt: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    """The true surface with at least ``faces`` faces (edges halved until there are enough)."""
    v, f = np.asarray(gt.vertices), np.asarray(gt.faces)
    edge = float(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1).max())
    while len(f) < faces:
        edge /= 1.5
        v, f = trimesh.remesh.subdivide_to_size(np.asarray(gt.vertices), np.asarray(gt.faces), edge)
    return trimesh.Trimesh(v, f, process=False)


def photo_vertex_colors(mesh: trimesh.Trimesh, ds: Dataset) -> trimesh.Trimesh:
    """The mesh with vertex colours from the photos: each vertex's mean colour over the views that see it."""
    from photorecon.io.images import sample_bilinear

    r = Renderer(mesh)
    V = np.asarray(mesh.vertices)
    acc, n = np.zeros((len(V), 3)), np.zeros(len(V))
    for view in ds.views:
        vis, uv = r.visible(V, view, np.asarray(mesh.vertex_normals), rel_tol=2e-3, min_cos=0.1)
        acc[vis] += sample_bilinear(ds.image(view), uv[vis])
        n[vis] += 1
    col = np.where(n[:, None] > 0, acc / np.maximum(n, 1)[:, None], 128)
    return trimesh.Trimesh(V, mesh.faces, vertex_colors=np.clip(col + 0.5, 0, 255).astype(np.uint8), process=False)


def fidelity(name: str, cfg: SynthConfig, faces: int, tmp: Path, atlas: int, maps: Path | None = None,
             spread: float = 0.2) -> tuple[list[dict], list[dict]]:
    """Two rows: the fused mesh (TSDF of the true depth, decimated, its own vertex colours) and the true surface
    (subdivided, vertex colours averaged from the photos), each textured too; and the fused mesh's seam rows
    (``seam_rows``)."""
    root = tmp / name
    synthesize(cfg, root, overwrite=True)
    full, ds = fused_mesh(root)
    gt = load_mesh(Layout(root).gt_mesh)
    truth_r = Renderer(gt, cfg.seed, cfg.background)
    held = held_out_views(cfg)
    truths = [truth_r.render(v) for v in held]
    rows, seams = [], []
    for geometry, mesh in (("fused", simplify(full, faces)), ("true", photo_vertex_colors(subdivided_truth(gt, faces), ds))):
        t0 = time.perf_counter()
        tex = texture_dataset(mesh, ds, TextureConfig(atlas_size=atlas))
        secs = time.perf_counter() - t0
        r_tex, r_vc = Renderer(tex.mesh, unlit=True), Renderer(mesh, unlit=True)
        renders = [(r_tex.render(v), r_vc.render(v)) for v in held]
        p_tex = [psnr(a.rgb, t.rgb, t.mask) for (a, _), t in zip(renders, truths)]
        p_vc = [psnr(b.rgb, t.rgb, t.mask) for (_, b), t in zip(renders, truths)]
        regions = {}
        for (a, b), t in zip(renders, truths):
            for k, (n, et, ev) in error_regions(t, a, b).items():
                acc = regions.setdefault(k, [0, 0.0, 0.0])
                acc[0] += n
                acc[1] += et
                acc[2] += ev
        total = sum(v[0] for v in regions.values())
        if maps is not None:
            maps.mkdir(parents=True, exist_ok=True)
            for i, ((a, _), t) in enumerate(zip(renders, truths)):
                write_error_map(maps / f"{name}_{geometry}_{i}.png", t, a)
        row = {"scene": name, "geometry": geometry, "views": cfg.views, "size": f"{cfg.width}x{cfg.height}",
               "faces": len(mesh.faces), "psnr_textured": float(np.mean(p_tex)), "psnr_vertex": float(np.mean(p_vc)),
               "gain_db": float(np.mean(p_tex) - np.mean(p_vc)), "texture_seconds": secs,
               "charts": tex.info["charts"], "texels_per_pixel": tex.info["texels_per_pixel"],
               "unseen_faces": tex.info["unseen_faces"],
               # per region: share of the object's pixels, and the textured / vertex-coloured squared error
               # summed there over the object's pixels (the three add up to each render's mean squared error)
               "error_regions": {k: {"pixels": n / total, "mse_textured": et / total, "mse_vertex": ev / total}
                                 for k, (n, et, ev) in regions.items()}}
        if geometry == "fused":
            r_full = Renderer(full, unlit=True)
            row["psnr_vertex_full"] = float(np.mean([psnr(r_full.render(v).rgb, t.rgb, t.mask) for v, t in zip(held, truths)]))
            row["full_faces"] = len(full.faces)
            seams = seam_rows(name, mesh, ds, held, truths, atlas, spread)
        rows.append(row)
    return rows, seams


def timing(views: int, faces: int, tmp: Path, atlas: int) -> dict:
    root = tmp / "time_blob"
    synthesize(SynthConfig(scene="blob", views=views, width=640, height=480), root, overwrite=True)
    full, ds = fused_mesh(root)
    mesh = simplify(full, faces)
    stages = {}
    reset_peak()
    c0 = time.process_time()
    t0 = time.perf_counter()
    tex = texture_dataset(mesh, ds, TextureConfig(atlas_size=atlas))
    stages["texture"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    export_textured(tex.mesh, tmp / "time_out")
    stages["export"] = time.perf_counter() - t1
    total = time.perf_counter() - t0
    cpu = time.process_time() - c0
    return {"views": views, "size": "640x480", "faces": len(mesh.faces), "atlas": atlas,
            "texture_seconds": stages["texture"], "export_seconds": stages["export"], "total_seconds": total, "cpu_seconds": cpu,
            "peak_mb": peak_bytes() / 2**20, "charts": tex.info["charts"],
            "texels_per_pixel": tex.info["texels_per_pixel"]}


# --- real photos, held out (--real) ------------------------------------------------------------------------------
REAL = {  # name: (folder under --data, its cameras, 0-based indices of the photos left out)
    "herz": ("herz-jesu-p8", "gt_dense_cameras", (2, 5)),
    "entry": ("entry-p10", "gt_dense_cameras", (3, 6)),
    "walnut1": ("walnuts/2016_10_24__17_43_02", "sparse/0", (5,)),
    "walnut2": ("walnuts/2016_10_25__12_57_06", "sparse/0", (5,)),
    "walnut3": ("walnuts/2016_10_24__17_44_40", "sparse/0", (5,)),
    "walnut4": ("walnuts/2016_10_25__12_10_52", "sparse/0", (5,)),
}


def held_out_input(src: Path, cams: str, held: tuple[int, ...], work: Path):
    """``work``/input/images (copies of the kept photos) and ``work``/input/cameras (their cameras, COLMAP text);
    returns (kept views, left-out views, the photo folder)."""
    import shutil

    from photorecon.io.cameras import read
    from photorecon.io.cameras.colmap_text import write_colmap_text
    from photorecon.io.cameras.model import SparseModel

    views = sorted(read(src / cams).views, key=lambda v: v.name)
    out_views = [views[i] for i in held]
    kept = [v for i, v in enumerate(views) if i not in held]
    images = work / "input" / "images"
    images.mkdir(parents=True, exist_ok=True)
    for v in kept:  # copies: reconstruct refuses links that lead out of the image folder
        f = v.image_file or v.name
        if not (images / f).is_file():
            shutil.copy2(src / "images" / f, images / f)
    cams_dir = work / "input" / "cameras"
    with tempfile.TemporaryDirectory(dir=work) as td:  # rewritten only when changed: a later run reuses the stages
        write_colmap_text(SparseModel(kept), td)
        if not cams_dir.is_dir() or any((Path(td) / f.name).read_bytes() != f.read_bytes() for f in cams_dir.iterdir()):
            shutil.rmtree(cams_dir, ignore_errors=True)
            shutil.copytree(td, cams_dir)
    return kept, out_views, src / "images"


def in_reconstruction_frame(given_kept, recon_views, held):
    """The left-out cameras in the reconstruction's frame: the similarity that takes the kept cameras' given
    centres onto the reconstruction's applied to them (the identity when the reconstruction kept the given
    frame, as with --poses and no scale source)."""
    from dataclasses import replace as dc_replace

    from photorecon.transform import umeyama

    by_name = {v.name: v for v in recon_views}
    a = np.array([v.center for v in given_kept])
    b = np.array([by_name[v.name].center for v in given_kept])
    if np.abs(a - b).max() <= 1e-6 * max(np.ptp(a, axis=0).max(), 1e-12):
        return held
    s, R, t = umeyama(a, b)
    out = []
    for v in held:
        Rc, tc = v.cam_from_world[:3, :3], v.cam_from_world[:3, 3]
        T = np.eye(4)
        T[:3, :3] = Rc @ R.T
        T[:3, 3] = s * tc - Rc @ R.T @ t
        out.append(dc_replace(v, cam_from_world=T))
    return out


def uv_islands(mesh: trimesh.Trimesh) -> np.ndarray:
    """Per face, the UV island it lies in (faces joined by shared vertices: one island per atlas chart)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    F = np.asarray(mesh.faces, np.int64)
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]]])
    n = len(mesh.vertices)
    _, comp = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)
    return comp[F[:, 0]]


def load_textured(path: Path, model_from_reconstruction=None) -> tuple[trimesh.Trimesh, dict]:
    """A GLB -> (mesh in the reconstruction's frame, its seam steps over UV islands)."""
    m = trimesh.load(path, process=False, force="mesh")
    atlas = np.asarray(m.visual.material.baseColorTexture.convert("RGB"))
    steps = seam_steps(m, atlas, uv_islands(m))
    if model_from_reconstruction is not None:
        m.apply_transform(np.linalg.inv(np.asarray(model_from_reconstruction, np.float64)))
    return m, steps


def gain_psnr(render: np.ndarray, photo: np.ndarray, mask: np.ndarray) -> tuple[float, np.ndarray]:
    """PSNR of ``render`` against ``photo`` over ``mask`` after one least-squares gain per channel; the gains."""
    r = render[mask].astype(np.float64)
    p = photo[mask].astype(np.float64)
    g = (r * p).sum(0) / np.maximum((r * r).sum(0), 1e-12)
    err = (np.clip(r * g, 0, 255) - p) ** 2
    return float(10 * np.log10(255.0 ** 2 / max(err.mean(), 1e-12))), g


def side_by_side(path: Path, photo: np.ndarray, render, gain: np.ndarray, height: int = 300,
                 limit: int = 290_000) -> None:
    """``path``: photo | render (its gain applied, uncovered pixels black), ``height`` pixels high, a PNG under
    ``limit`` bytes (colours reduced to a 256-colour palette when the full-colour PNG is larger). A dark photo
    (the walnuts') is brightened for viewing, both halves by the same factor. Returns that factor."""
    import io

    import cv2
    from PIL import Image

    bright = max(1.0, 200.0 / max(float(np.percentile(photo, 99.5)), 1.0))
    photo = np.clip(photo * bright + 0.5, 0, 255).astype(np.uint8)
    img = np.where(render.mask[..., None], np.clip(render.rgb * gain * bright + 0.5, 0, 255), 0).astype(np.uint8)
    w = round(photo.shape[1] * height / photo.shape[0])
    pair = np.concatenate([cv2.resize(photo, (w, height), interpolation=cv2.INTER_AREA),
                           np.zeros((height, 4, 3), np.uint8) + 255,
                           cv2.resize(img, (w, height), interpolation=cv2.INTER_AREA)], 1)
    pic = Image.fromarray(pair)
    buf = io.BytesIO()
    pic.save(buf, format="PNG", optimize=True)
    if buf.tell() > limit:
        buf = io.BytesIO()
        pic.quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(buf, format="PNG", optimize=True)
    path.write_bytes(buf.getvalue())
    return bright


def real_capture(name: str, data: Path, out: Path, max_size: int | None) -> list[dict]:
    """The three results of one capture (``REAL[name]``), one row each."""
    import subprocess
    import sys

    from photorecon.io.images import read_image

    folder, cams, held = REAL[name]
    work = out / (name if max_size is None else f"{name}_{max_size}")
    kept, left_out, photos = held_out_input(data / folder, cams, held, work)
    recon = work / "recon"
    cmd = [sys.executable, "-m", "photorecon", "-q", "reconstruct", str(work / "input" / "images"), "-o", str(recon),
           "--poses", str(work / "input" / "cameras")] + (["--max-size", str(max_size)] if max_size else [])
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True)  # the stage runner reuses what an earlier run with the same settings wrote
    rec_s = time.perf_counter() - t0
    rep = json.loads((recon / "report.json").read_text())
    ds = Dataset.open(recon)
    left_out = in_reconstruction_frame(kept, ds.views, left_out)
    full = load_mesh(recon / "mesh.ply")
    # (b): the full mesh textured as ``photorecon texture`` does (no simplification), its GLB as that writes it
    full_glb, full_info = work / "full_textured.glb", work / "full_textured.json"
    if not (full_glb.is_file() and full_info.is_file()):
        t1 = time.perf_counter()
        tex = texture_mesh(full, ds.views, lambda k: ds.image(ds.views[k]), TextureConfig(), ds.mask)
        info = {"texture_seconds": time.perf_counter() - t1, "texels_per_pixel": tex.info["texels_per_pixel"],
                "charts": tex.info["charts"]}
        full_glb.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(tex.mesh)))
        full_info.write_text(json.dumps(info) + "\n")
        del tex
    tex_info = json.loads(full_info.read_text())
    results = {"vertex colours (mesh.ply)": (full, None, recon / "mesh.ply"),
               "full mesh textured": (*load_textured(full_glb), full_glb),
               "model.glb": (*load_textured(recon / "model.glb", rep["texture"]["frame"]["model_from_reconstruction"]),
                             recon / "model.glb")}
    renderers = {k: Renderer(m, unlit=True) for k, (m, _, _) in results.items()}
    acc = {k: [] for k in results}
    for i, view in enumerate(left_out):
        photo = read_image(photos / (view.image_file or view.name))
        renders = {k: r.render(view) for k, r in renderers.items()}
        common = np.logical_and.reduce([r.mask for r in renders.values()])
        for k, r in renders.items():
            p, g = gain_psnr(r.rgb, photo, common)
            p_own, _ = gain_psnr(r.rgb, photo, r.mask)
            acc[k].append({"view": view.name, "psnr": p, "psnr_own_pixels": p_own, "gain": g.tolist(),
                           "covered": float(r.mask.mean()), "common": float(common.mean())})
            if k == "model.glb" and i == 0:
                bright = side_by_side(out / f"texture_real_{name}.png", photo, r, g)
                if bright > 1.0:
                    print(f"{name}: texture_real_{name}.png brightened x{bright:.1f} for viewing", flush=True)
    rows = []
    for k, (m, steps, path) in results.items():
        per = acc[k]
        rows.append({"capture": name, "result": k, "faces": int(len(m.faces)), "held_out": [p["view"] for p in per],
                     "psnr": float(np.mean([p["psnr"] for p in per])),
                     "psnr_own_pixels": float(np.mean([p["psnr_own_pixels"] for p in per])),
                     "covered": float(np.mean([p["covered"] for p in per])),
                     "common": float(np.mean([p["common"] for p in per])), "per_view": per,
                     "seam": steps, "file": path.name, "file_mb": path.stat().st_size / 2**20,
                     "max_size": max_size, "reconstruct_seconds": rec_s,
                     **({"full": tex_info} if k == "full mesh textured" else {}),
                     **({"model": {key: rep["texture"].get(key) for key in ("faces_in", "texels_per_pixel",
                                                                             "atlases", "charts")}}
                        if k == "model.glb" else {})})
    return rows


def real(args) -> None:
    names = args.only.split(",") if args.only else list(REAL)
    unknown = [n for n in names if n not in REAL]
    if unknown:
        raise SystemExit(f"--only: unknown capture {unknown[0]!r}; expected some of {', '.join(REAL)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    print("| capture | result | faces | PSNR dB | covered | seam score | file MB |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        for r in real_capture(name, Path(args.data), out, args.max_size):
            rows.append(r)
            seam = f"{r['seam']['excess']:.2f}" if r["seam"] else "-"
            print(f"| {name} | {r['result']} | {r['faces']:,} | {r['psnr']:.2f} | {r['covered']:.1%} | {seam} | "
                  f"{r['file_mb']:.1f} ({r['file']}) |", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"real": rows}, indent=2) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=30)
    ap.add_argument("--faces", type=int, default=30000, help="face count of both meshes in the fidelity table")
    ap.add_argument("--time-faces", type=int, default=300000)
    ap.add_argument("--atlas", type=int, default=4096)
    ap.add_argument("--only", help="fidelity or time; with --real: captures, comma-separated (herz, entry, "
                    "walnut1..walnut4; default all)")
    ap.add_argument("--real", action="store_true", help="the held-out test on real photos (../shared/data)")
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    ap.add_argument("--out", default="bench_texture_real", help="--real: reconstructions and pictures go here")
    ap.add_argument("--max-size", type=int, help="--real: reconstruct at this working size (reconstruct's "
                    "--max-size; default: its default)")
    ap.add_argument("--scenes", default="blob,room,bunny")
    ap.add_argument("--json", help="write the figures to this JSON file")
    ap.add_argument("--error-maps", help="write truth | textured | error images of the held-out views to this folder")
    ap.add_argument("--gains", type=float, default=0.2, help="seam table: photos scaled by a random gain in 1 +- this")
    args = ap.parse_args()
    progress.set_enabled(False)
    if args.real:
        return real(args)
    if args.only not in (None, "fidelity", "time"):
        ap.error("--only: fidelity or time (capture names go with --real)")
    res = {"fidelity": [], "seams": [], "time": None}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        if args.only != "time":
            print("| scene | geometry | faces | PSNR vertex colours dB | PSNR textured dB | gain dB | texture s | "
                  "charts | texels/pixel |")
            print("|---|---|---|---|---|---|---|---|---|")
            for name in args.scenes.split(","):
                if name == "bunny":
                    if not BUNNY.is_file():
                        print(f"(bunny skipped: {BUNNY} not found)")
                        continue
                    cfg = SynthConfig(mesh=str(BUNNY), up="y", views=args.views)
                else:
                    cfg = SynthConfig(scene=name, views=args.views)
                rows, seams = fidelity(name, cfg, args.faces, tmp, args.atlas,
                                       Path(args.error_maps) if args.error_maps else None, args.gains)
                res["seams"] += seams
                for r in rows:
                    res["fidelity"].append(r)
                    full = (f"; full fused mesh ({r['full_faces']:,} faces) with vertex colours: "
                            f"{r['psnr_vertex_full']:.2f} dB") if "full_faces" in r else ""
                    print(f"| {name} | {r['geometry']} | {r['faces']:,} | {r['psnr_vertex']:.2f} | "
                          f"{r['psnr_textured']:.2f} | **{r['gain_db']:+.2f}** | {r['texture_seconds']:.1f} | "
                          f"{r['charts']} | {r['texels_per_pixel']:.2f} |{full}", flush=True)
                    print("  squared error by region (share of pixels: textured / vertex colours): " + "; ".join(
                        f"{k} {v['pixels']:.1%}: {v['mse_textured']:.1f} / {v['mse_vertex']:.1f}"
                        for k, v in r["error_regions"].items()), flush=True)
            if res["seams"]:
                print("\n| scene | photo gains | exposure | seam step: plain / levelled | inside charts | excess: plain / "
                      "levelled | PSNR dB: plain / levelled |")
                print("|---|---|---|---|---|---|---|")
                for r in res["seams"]:
                    p, lv = r["plain"], r["levelled"]
                    print(f"| {r['scene']} | {'+-%d%%' % round(100 * r['gains']) if r['gains'] else 'none'} | "
                          f"{'on' if r['exposure'] else 'off'} | {p['seam']:.2f} / {lv['seam']:.2f} | "
                          f"{p['interior']:.2f} | {p['excess']:.2f} / **{lv['excess']:.2f}** | "
                          f"{p['psnr']:.2f} / {lv['psnr']:.2f} |", flush=True)
        if args.only != "fidelity":
            t = timing(args.views, args.time_faces, tmp, args.atlas)
            res["time"] = t
            print(f"\ntexturing {t['views']} views of {t['size']}, {t['faces']:,} faces, atlas {t['atlas']}: "
                  f"{t['texture_seconds']:.1f} s + export {t['export_seconds']:.1f} s = {t['total_seconds']:.1f} s "
                  f"(target <= 30 s; CPU time of all threads {t['cpu_seconds']:.1f} s), peak {t['peak_mb']:.0f} MB, {t['charts']} charts, "
                  f"{t['texels_per_pixel']:.2f} texels/pixel")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
