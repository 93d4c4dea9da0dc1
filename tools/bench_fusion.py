#!/usr/bin/env python
"""Benchmark of the fusion stage on synthetic scenes with rendered depth and true poses.

Accuracy (40 sphere views, 640x480): TSDF and grid meshes vs ground truth on `blob` and the Stanford bunny
(if ../shared/data/stanford-bunny is present), with the article's legacy pipeline (concatenated per-view
meshes, fixed 0.1 edge threshold) in the same run. Speed: TSDF fusion of 100 views at voxel = diagonal/512.

    python tools/bench_fusion.py [--views 40] [--speed-views 100] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import trimesh

from photorecon import progress
from photorecon.fusion import FusionConfig, fuse, legacy_article_fuse, load_frames
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
    import subprocess
    import sys

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--speed-views", type=int, default=100)
    ap.add_argument("--json", help="write the figures to this JSON file")
    ap.add_argument("--speed-only", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    progress.set_enabled(False)
    if args.speed_only:
        with tempfile.TemporaryDirectory() as t:
            print(json.dumps(run_speed(args.speed_views, Path(t))))
        return
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        rows = run_scene("blob", SynthConfig(scene="blob", views=args.views), tmp)
        if BUNNY.is_file():
            rows += run_scene("bunny", SynthConfig(mesh=str(BUNNY), up="y", views=args.views), tmp)
    speed = run_speed_subprocess(args.speed_views)
    print(f"{'scene':6} {'mesher':7} {'views':>5} {'sec':>7} {'peakMB':>7} {'faces':>9} {'F@0.5%':>7} {'F@1%':>7} "
          f"{'Chamfer%':>9} {'doubled':>8}")
    for r in rows:
        print(f"{r['scene']:6} {r['mesher']:7} {r['views']:5d} {r['seconds']:7.2f} {r['peak_mb']:7.0f} {r['faces']:9d} "
              f"{r['fscore_0.5%']:7.4f} {r['fscore_1%']:7.4f} {r['chamfer_%diag']:9.4f} {r['doubled_shells']:8.4f}")
    print(f"\nTSDF speed: {speed['views']} views {speed['size']} at {speed['voxel']}: {speed['seconds']:.2f} s "
          f"(target {speed['target_s']} s), peak {speed['peak_mb']:.0f} MB "
          f"({speed['peak_above_inputs_mb']:.0f} MB above the loaded inputs; target {speed['target_mb']} MB)")
    if args.json:
        Path(args.json).write_text(json.dumps({"accuracy": rows, "speed": speed}, indent=2))


if __name__ == "__main__":
    main()
