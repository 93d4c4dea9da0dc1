#!/usr/bin/env python
"""Benchmark of the CPU multi-view stereo stage.

1. Speed: one 640x480 reference view, 4 source views, 128 depth hypotheses (fresh process: its own peak memory).
2. Synthetic blob, 40 sphere views at 640x480, true poses: depth error < 1% on surviving pixels, surviving
   fraction of true surface pixels, fused TSDF F-score at 0.5% of the diagonal.
3. The same with SfM poses (photorecon sfm), the mesh Sim3-aligned through the cameras for evaluation.
4. Herz-Jesu-P8 (if ../shared/data is present): SfM with the given K, MVS, TSDF; writes a preview PNG and
   reports the mean reprojection consistency.

    python tools/bench_mvs.py [--json out.json] [--out bench_out] [--skip-herz] [--skip-sfm]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from photorecon import progress
from photorecon.depth.mvs import MVSConfig, run_mvs
from photorecon.fusion import FusionConfig, fuse, load_frames
from photorecon.io.dataset import Dataset
from photorecon.mesh import clean, export
from photorecon.metrics import align_cameras, depth_metrics, mesh_metrics
from photorecon.preview import render_preview
from photorecon.resources import peak_bytes, reset_peak
from photorecon.sfm import SfMConfig, run_sfm
from photorecon.synthetic import SynthConfig, synthesize

HERZ = Path(__file__).resolve().parents[1] / "../shared/data/herz-jesu-p8"
FUSE = FusionConfig(trunc_voxels=3.0)


def speed_probe() -> dict:
    """Runs in a child process: plane sweep of one 640x480 view with 4 sources, 128 depths."""
    from photorecon.depth.mvs import _gray, depth_range, plane_sweep, select_sources

    with tempfile.TemporaryDirectory() as t:
        synthesize(SynthConfig(scene="blob", views=40, points=3000), t, overwrite=True)
        ds = Dataset.open(t)
        cfg = MVSConfig()
        ref = ds.views[10]
        srcs = select_sources(ds.model, ref, cfg)
        imgs = [(_gray(ds.image(s)), s) for s in srcs]
        zmin, zmax = depth_range(ds.model, ref)
        g = _gray(ds.image(ref))
        plane_sweep(g, ref, imgs, zmin, zmax, MVSConfig(n_depths=8))  # warm-up
        reset_peak()
        base = peak_bytes()  # the resident set now: inputs loaded
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            plane_sweep(g, ref, imgs, zmin, zmax, cfg)
            times.append(time.perf_counter() - t0)
        return {"size": "640x480", "sources": len(srcs), "depths": cfg.n_depths, "seconds_median": float(np.median(times)),
                "target_s": 2.0, "peak_mb": peak_bytes() / 2**20, "peak_above_inputs_mb": (peak_bytes() - base) / 2**20}


def evaluate_depth(ds, depth_dir, gt_dir) -> dict:
    within, cover = [], []
    for v in ds.views:
        p = Path(depth_dir) / f"{v.name}.npy"
        if not p.is_file():
            cover.append(0.0)
            continue
        m = depth_metrics(np.load(p), np.load(Path(gt_dir) / f"{v.name}.npy"))
        within.append(m["within"])
        cover.append(m["coverage"])
    return {"within_1pct": float(np.mean(within)), "coverage": float(np.mean(cover))}


def fuse_eval(ds, gt_path, sim3=None) -> dict:
    mesh = clean(fuse(load_frames(ds, FUSE), FUSE, ds.model.points))
    if sim3 is not None:
        s, R, t = sim3
        mesh.vertices = s * np.asarray(mesh.vertices) @ R.T + t
    m = mesh_metrics(mesh, trimesh.load(gt_path, process=False), n_samples=100_000)
    return {"fscore_0.5pct": m.fscore_half, "fscore_1pct": m.fscore, "chamfer_pct_diag": 100 * m.chamfer / m.diagonal}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json")
    ap.add_argument("--out", default="bench_out", help="folder for the Herz-Jesu preview and mesh")
    ap.add_argument("--skip-herz", action="store_true")
    ap.add_argument("--skip-sfm", action="store_true")
    ap.add_argument("--probe", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    progress.set_enabled(False)
    if args.probe:
        print(json.dumps(speed_probe()))
        return
    res = {}
    p = subprocess.run([sys.executable, __file__, "--probe"], capture_output=True, text=True, check=True)
    res["speed"] = json.loads(p.stdout.strip().splitlines()[-1])
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        data = tmp / "blob"
        synthesize(SynthConfig(scene="blob", views=40), data, overwrite=True)
        ds = Dataset.open(data)
        t0 = time.perf_counter()
        rep = run_mvs(ds, tmp / "mvs_true", MVSConfig())
        res["true_poses"] = {"seconds": time.perf_counter() - t0, "seconds_per_view": rep["seconds_per_view"],
                             **evaluate_depth(ds, tmp / "mvs_true", data / "depth"),
                             **fuse_eval(Dataset.open(data, tmp / "mvs_true"), data / "gt_mesh.ply"),
                             "consistency": rep["consistency"]}
        if not args.skip_sfm:
            run_sfm(data / "images", tmp / "sfm", SfMConfig())
            sds = Dataset.open(tmp / "sfm")
            rep = run_mvs(sds, tmp / "sfm" / "depth", MVSConfig())
            sim3 = align_cameras(sds.views, ds.views)
            res["sfm_poses"] = {"seconds_per_view": rep["seconds_per_view"], **fuse_eval(sds, data / "gt_mesh.ply", sim3),
                                "consistency": rep["consistency"]}
        if not args.skip_herz and HERZ.is_dir():
            out = Path(args.out)
            out.mkdir(parents=True, exist_ok=True)
            run_sfm(HERZ / "images", tmp / "herz", SfMConfig(intrinsics=str(HERZ / "images" / "K.txt")))
            hds = Dataset.open(tmp / "herz")
            reset_peak()
            t0 = time.perf_counter()
            rep = run_mvs(hds, tmp / "herz" / "depth", MVSConfig())
            mesh = clean(fuse(load_frames(hds, FUSE), FUSE, hds.model.points))
            export(mesh, out / "herz_jesu_mesh.ply")
            render_preview(mesh, out / "herz_jesu_preview.png", cameras=hds.views, size=480)
            res["herz_jesu"] = {"views": rep["views"], "seconds": time.perf_counter() - t0,
                                "seconds_per_view": rep["seconds_per_view"], "consistency": rep["consistency"],
                                "faces": len(mesh.faces), "peak_mb": peak_bytes() / 2**20,
                                "preview": str(out / "herz_jesu_preview.png")}
    s = res["speed"]
    print(f"speed: {s['size']} reference, {s['sources']} sources, {s['depths']} depths: {s['seconds_median']:.2f} s "
          f"(target {s['target_s']} s), peak memory of the process {s['peak_mb']:.0f} MB")
    print(f"{'set':22} {'s/view':>7} {'<1% err':>8} {'coverage':>9} {'F@0.5%':>7} {'F@1%':>7} {'Chamfer%':>9} {'reproj px':>9}")
    for k in ("true_poses", "sfm_poses"):
        if k in res:
            r = res[k]
            print(f"{'blob-40 ' + k.replace('_', ' '):22} {r['seconds_per_view']:7.2f} {r.get('within_1pct', float('nan')):8.4f} "
                  f"{r.get('coverage', float('nan')):9.4f} {r['fscore_0.5pct']:7.4f} {r['fscore_1pct']:7.4f} "
                  f"{r['chamfer_pct_diag']:9.4f} {r['consistency'].get('mean_reprojection_px', float('nan')):9.3f}")
    if "herz_jesu" in res:
        h = res["herz_jesu"]
        print(f"herz-jesu-p8: {h['views']} depth maps, {h['seconds_per_view']:.2f} s/view, mean reprojection "
              f"consistency {h['consistency'].get('mean_reprojection_px', float('nan')):.3f} px, "
              f"{100 * h['consistency'].get('kept_fraction', 0):.1f}% of depths consistent; preview {h['preview']}")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
