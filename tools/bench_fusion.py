#!/usr/bin/env python
"""Benchmark of the fusion stage on synthetic scenes with rendered depth and true poses.

Accuracy (40 sphere views, 640x480): TSDF and grid meshes vs ground truth on `blob` and the Stanford bunny
(if ../shared/data/stanford-bunny is present), with the article's legacy pipeline (concatenated per-view
meshes, fixed 0.1 edge threshold) in the same run. Speed: TSDF fusion of 100 views at voxel = diagonal/512.
Integration, side by side (47 views, 640x480, the default footprint voxel, a confidence map per view): Open3D's
own ``integrate`` (weight 1), a numpy version of the confidence-weighted update (on the grid's storage,
``integrate_weighted_numpy`` here) and photorecon's numba kernel (``photorecon.fusion``); seconds per frame
(integration call only, and with the block selection) and peak MB, each in a fresh process; plus the numba
JIT warm-up, with an empty cache (compilation) and with the on-disk cache (``cache=True``).

    python tools/bench_fusion.py [--views 40] [--speed-views 100] [--integrate-views 47] [--json out.json]
    python tools/bench_fusion.py --only integrate      # just the integration comparison
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from photorecon import progress
from photorecon import fusion
from photorecon.fusion import DepthFrame, FusionConfig, fuse, legacy_article_fuse, load_frames
from photorecon.fusion.tsdf import _integrate_weighted
from photorecon.io.dataset import Dataset
from photorecon.mesh import clean
from photorecon.metrics import doubled_shell_fraction, mesh_metrics
from photorecon.resources import peak_bytes, reset_peak
from photorecon.synthetic import SynthConfig, synthesize

BUNNY = Path(__file__).resolve().parents[1] / "../shared/data/stanford-bunny/bun_zipper.ply"


def run_scene(name: str, cfg: SynthConfig, tmp: Path) -> list[dict]:
    root = tmp / name
    synthesize(cfg, root, overwrite=True)
    ds = Dataset.open(root)
    frames = load_frames(ds, FusionConfig())
    gt = trimesh.load(root / "gt_mesh.ply", process=False)
    rows = []
    for mesher in ("tsdf", "grid", "legacy"):
        reset_peak()
        t0 = time.perf_counter()
        if mesher == "legacy":
            mesh = legacy_article_fuse(frames)
        else:
            mesh = clean(fuse(frames, FusionConfig(mesher=mesher), ds.model.points))
        secs = time.perf_counter() - t0
        peak = peak_bytes() / 2**20
        m = mesh_metrics(mesh, gt, n_samples=100_000)
        rows.append({"scene": name, "mesher": mesher, "views": cfg.views, "seconds": secs, "peak_mb": peak,
                     "faces": len(mesh.faces), "fscore_0.5%": m.fscore_half, "fscore_1%": m.fscore,
                     "chamfer_%diag": 100 * m.chamfer / m.diagonal,
                     "doubled_shells": doubled_shell_fraction(mesh, m.tau / 2, 30_000)})
    return rows


def run_speed_subprocess(n_views: int) -> dict:
    """Run the speed measurement in a fresh process, so its peak memory is its own."""
    out = subprocess.run([sys.executable, __file__, "--speed-only", "--speed-views", str(n_views)],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_speed(n_views: int, tmp: Path) -> dict:
    root = tmp / "speed"
    synthesize(SynthConfig(scene="blob", views=n_views, points=1000), root, overwrite=True)
    ds = Dataset.open(root)
    frames = load_frames(ds, FusionConfig())
    reset_peak()
    base = peak_bytes()  # the resident set now: depth maps and images loaded
    t0 = time.perf_counter()
    mesh = fuse(frames, FusionConfig(mesher="tsdf", voxels_across=512), ds.model.points)
    secs = time.perf_counter() - t0
    peak = peak_bytes()
    return {"views": n_views, "size": "640x480", "voxel": "diag/512", "seconds": secs, "target_s": 5.0,
            "peak_mb": peak / 2**20, "peak_above_inputs_mb": (peak - base) / 2**20, "target_mb": 2048,
            "faces": len(mesh.faces)}


# --- integration: Open3D vs numpy weighted vs numba weighted (photorecon) ------------------------------------
def integrate_weighted_numpy(vbg, block_coords, f: DepthFrame, voxel: float, trunc: float, depth_max: float) -> None:
    """The confidence-weighted update in numpy (over every voxel of the frame's blocks, with (N, 3)
    temporaries): the plain reference the numba kernel is compared with."""
    hm = vbg.hashmap()
    hm.activate(block_coords)
    buf, _ = hm.find(block_coords)
    xyz, vidx = vbg.voxel_coordinates_and_flattened_indices(buf)
    idx = vidx.numpy().ravel()
    T = f.view.cam_from_world
    Xc = xyz.numpy() @ T[:3, :3].T.astype(np.float32) + T[:3, 3].astype(np.float32)
    z = Xc[:, 2]
    intr = f.view.intrinsics
    H, W = f.depth.shape
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.round(intr.fx * Xc[:, 0] / z + intr.cx)
        v = np.round(intr.fy * Xc[:, 1] / z + intr.cy)
    ok = (z > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    ui, vi = u[ok].astype(np.int64), v[ok].astype(np.int64)
    d = f.depth[vi, ui]
    sdf = d - z[ok]
    good = (d > 0) & (d < depth_max) & (sdf >= -trunc)
    w_new = f.confidence[vi, ui][good].astype(np.float32)
    keep = w_new > 0
    sel = idx[ok][good][keep]
    w_new = w_new[keep]
    sdf_n = np.minimum(sdf[good][keep], trunc) / trunc
    tsdf = vbg.attribute("tsdf").numpy().reshape(-1)
    weight = vbg.attribute("weight").numpy().reshape(-1)
    color = vbg.attribute("color").numpy().reshape(-1, 3)
    w_old = weight[sel]
    w_sum = w_old + w_new
    tsdf[sel] = (tsdf[sel] * w_old + sdf_n * w_new) / w_sum
    if f.color is not None:
        c_new = f.color[vi, ui][good][keep].astype(np.float32)
        color[sel] = (color[sel] * w_old[:, None] + c_new * w_new[:, None]) / w_sum[:, None]
    weight[sel] = w_sum


def _with_confidence(frames: list[DepthFrame]) -> list[DepthFrame]:
    """MVS-like confidence maps: smooth values in (0, 1], a few zeros (fixed seed)."""
    rng = np.random.default_rng(0)
    out = []
    for f in frames:
        H, W = f.depth.shape
        coarse = rng.random((H // 16 + 2, W // 16 + 2)).astype(np.float32)
        conf = np.kron(coarse, np.ones((16, 16), np.float32))[:H, :W]
        conf[conf < 0.05] = 0
        out.append(DepthFrame(f.view, f.depth, f.color, conf))
    return out


def run_integrate(method: str, root: Path) -> dict:
    """Time one integration method over the dataset at ``root`` (in this process: run it in a fresh one)."""
    import open3d as o3d
    import open3d.core as o3c

    ds = Dataset.open(root)
    frames = _with_confidence(load_frames(ds, FusionConfig()))
    cfg = FusionConfig()
    voxel, n_blocks = fusion.tsdf_voxel_size(frames, cfg)
    trunc = cfg.trunc_voxels * voxel
    depth_max = float(max(f.depth.max() for f in frames)) * 1.01 + trunc
    warm = None
    if method == "numba":  # compile (or load from the cache) on a tiny frame first: reported apart
        t0 = time.perf_counter()
        _integrate_weighted(*_tiny_grid_args())
        warm = time.perf_counter() - t0
    inputs = [(f, o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(f.depth))),
               o3d.t.geometry.Image(o3c.Tensor(f.color.astype(np.float32) / 255.0)),
               o3c.Tensor(f.view.intrinsics.K, o3c.float64),
               o3c.Tensor(np.ascontiguousarray(f.view.cam_from_world), o3c.float64)) for f in frames]
    reset_peak()
    base = peak_bytes()
    vbg = o3d.t.geometry.VoxelBlockGrid(("tsdf", "weight", "color"), (o3c.float32, o3c.float32, o3c.float32),
                                        ((1), (1), (3)), voxel, 16, n_blocks, o3c.Device("CPU:0"))
    t_blocks = t_int = 0.0
    for f, depth, color, K, T in inputs:
        t0 = time.perf_counter()
        coords = vbg.compute_unique_block_coordinates(depth, K, T, 1.0, depth_max, float(cfg.trunc_voxels))
        t1 = time.perf_counter()
        if method == "open3d":
            vbg.integrate(coords, depth, color, K, K, T, 1.0, depth_max, float(cfg.trunc_voxels))
        elif method == "numpy":
            integrate_weighted_numpy(vbg, coords, f, voxel, trunc, depth_max)
        else:
            _integrate_weighted(vbg, coords, f, voxel, trunc, depth_max)
        t2 = time.perf_counter()
        t_blocks += t1 - t0
        t_int += t2 - t1
    t0 = time.perf_counter()
    mesh = vbg.extract_triangle_mesh(weight_threshold=cfg.weight_threshold)
    t_ext = time.perf_counter() - t0
    peak = peak_bytes()
    n = len(frames)
    return {"method": method, "views": n, "size": f"{frames[0].depth.shape[1]}x{frames[0].depth.shape[0]}",
            "voxel": voxel, "blocks_estimated": n_blocks, "active_blocks": int(vbg.hashmap().size()),
            "integrate_s_per_frame": t_int / n, "with_blocks_s_per_frame": (t_int + t_blocks) / n,
            "extract_s": t_ext, "peak_mb": peak / 2**20, "peak_above_inputs_mb": (peak - base) / 2**20,
            "triangles": int(mesh.triangle.indices.shape[0]), "jit_first_call_s": warm}


def _tiny_grid_args():
    import open3d as o3d
    import open3d.core as o3c

    from photorecon.cameras import Intrinsics, View

    intr = Intrinsics(32, 24, 30.0, 30.0, 15.5, 11.5)
    f = DepthFrame(View("tiny", intr, np.eye(4)), np.full((24, 32), 1.0, np.float32),
                   np.full((24, 32, 3), 100, np.uint8), np.ones((24, 32), np.float32))
    vbg = o3d.t.geometry.VoxelBlockGrid(("tsdf", "weight", "color"), (o3c.float32, o3c.float32, o3c.float32),
                                        ((1), (1), (3)), 0.05, 16, 100, o3c.Device("CPU:0"))
    coords = vbg.compute_unique_block_coordinates(o3d.t.geometry.Image(o3c.Tensor(f.depth)),
                                                  o3c.Tensor(intr.K, o3c.float64), o3c.Tensor(np.eye(4)), 1.0, 3.0, 2.0)
    return vbg, coords, f, 0.05, 0.1, 3.0


def run_warmup() -> dict:
    """The numba kernel's first call (the tiny frame) in this process, then a second call."""
    args = _tiny_grid_args()
    t0 = time.perf_counter()
    _integrate_weighted(*args)
    first = time.perf_counter() - t0
    args = _tiny_grid_args()
    t0 = time.perf_counter()
    _integrate_weighted(*args)
    return {"first_call_s": first, "second_call_s": time.perf_counter() - t0}


def _child(args: list[str], env: dict | None = None) -> dict:
    out = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True, check=True,
                         env={**os.environ, **(env or {})})
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_integrate_compare(n_views: int, tmp: Path) -> dict:
    root = tmp / "integrate"
    synthesize(SynthConfig(scene="blob", views=n_views, points=1000), root, overwrite=True)
    cache = tmp / "numba_cache"  # a fresh numba cache: the first process compiles, the second loads
    warm = {"cold_cache": _child(["--warmup-only"], {"NUMBA_CACHE_DIR": str(cache)}),
            "on_disk_cache": _child(["--warmup-only"], {"NUMBA_CACHE_DIR": str(cache)})}
    rows = [_child(["--integrate-only", m, "--data", str(root)], {"NUMBA_CACHE_DIR": str(cache)})
            for m in ("open3d", "numpy", "numba")]
    return {"rows": rows, "warmup": warm}


def print_integrate(res: dict) -> None:
    rows = res["rows"]
    r0 = rows[0]
    print(f"\nTSDF integration, {r0['views']} views {r0['size']}, voxel {r0['voxel']:.4g} (default: footprint), "
          f"{r0['active_blocks']} blocks; each method in a fresh process")
    print(f"{'method':28} {'integrate s/frame':>17} {'+blocks s/frame':>15} {'x Open3D':>8} {'extract s':>9} "
          f"{'peakMB':>7} {'above inputs':>12}")
    names = {"open3d": "Open3D integrate (weight 1)", "numpy": "weighted, numpy",
             "numba": "weighted, numba (photorecon)"}
    for r in rows:
        print(f"{names[r['method']]:28} {r['integrate_s_per_frame']:17.4f} {r['with_blocks_s_per_frame']:15.4f} "
              f"{r['integrate_s_per_frame'] / r0['integrate_s_per_frame']:8.2f} {r['extract_s']:9.2f} "
              f"{r['peak_mb']:7.0f} {r['peak_above_inputs_mb']:12.0f}")
    w = res["warmup"]
    print(f"numba JIT warm-up (first call, tiny frame): {w['cold_cache']['first_call_s']:.2f} s with an empty cache "
          f"(compilation), {w['on_disk_cache']['first_call_s']:.3f} s from the on-disk cache "
          f"(a later call: {w['on_disk_cache']['second_call_s'] * 1000:.1f} ms)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--speed-views", type=int, default=100)
    ap.add_argument("--integrate-views", type=int, default=47)
    ap.add_argument("--only", choices=("accuracy", "speed", "integrate"), help="run one part only")
    ap.add_argument("--json", help="write the figures to this JSON file")
    ap.add_argument("--speed-only", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--integrate-only", choices=("open3d", "numpy", "numba"), help=argparse.SUPPRESS)
    ap.add_argument("--data", help=argparse.SUPPRESS)
    ap.add_argument("--warmup-only", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    progress.set_enabled(False)
    if args.speed_only:
        with tempfile.TemporaryDirectory() as t:
            print(json.dumps(run_speed(args.speed_views, Path(t))))
        return
    if args.integrate_only:
        print(json.dumps(run_integrate(args.integrate_only, Path(args.data))))
        return
    if args.warmup_only:
        print(json.dumps(run_warmup()))
        return
    results: dict = {}
    if args.only in (None, "accuracy"):
        with tempfile.TemporaryDirectory() as t:
            tmp = Path(t)
            rows = run_scene("blob", SynthConfig(scene="blob", views=args.views), tmp)
            if BUNNY.is_file():
                rows += run_scene("bunny", SynthConfig(mesh=str(BUNNY), up="y", views=args.views), tmp)
        results["accuracy"] = rows
        print(f"{'scene':6} {'mesher':7} {'views':>5} {'sec':>7} {'peakMB':>7} {'faces':>9} {'F@0.5%':>7} {'F@1%':>7} "
              f"{'Chamfer%':>9} {'doubled':>8}")
        for r in rows:
            print(f"{r['scene']:6} {r['mesher']:7} {r['views']:5d} {r['seconds']:7.2f} {r['peak_mb']:7.0f} "
                  f"{r['faces']:9d} {r['fscore_0.5%']:7.4f} {r['fscore_1%']:7.4f} {r['chamfer_%diag']:9.4f} "
                  f"{r['doubled_shells']:8.4f}")
    if args.only in (None, "speed"):
        speed = results["speed"] = run_speed_subprocess(args.speed_views)
        print(f"\nTSDF speed: {speed['views']} views {speed['size']} at {speed['voxel']}: {speed['seconds']:.2f} s "
              f"(target {speed['target_s']} s), peak {speed['peak_mb']:.0f} MB "
              f"({speed['peak_above_inputs_mb']:.0f} MB above the loaded inputs; target {speed['target_mb']} MB)")
    if args.only in (None, "integrate"):
        with tempfile.TemporaryDirectory() as t:
            results["integrate"] = run_integrate_compare(args.integrate_views, Path(t))
        print_integrate(results["integrate"])
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
