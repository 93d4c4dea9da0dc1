#!/usr/bin/env python
"""Meshers side by side on real depth maps: TSDF (confidence-weighted, the default) vs screened Poisson from the
depth maps' oriented points (COLMAP's stereo_fusion idea: fuse depth into a point cloud first, then mesh it) vs
per-view grids merged, on the walnuts' PatchMatch depth maps, against the reference point cloud.

The depth maps come from ``tools/bench_real.py --out DIR`` (DIR/walnut1/depth, DIR/walnut2/depth): this script
only fuses, cleans and evaluates, so the meshers see the same depth.

    python tools/bench_meshers.py --depth-from /tmp/bench_real [--only walnut1] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from photorecon import progress
from photorecon.fusion import FusionConfig, fuse, load_frames
from photorecon.io.dataset import Dataset
from photorecon.mesh import CleanConfig, clean
from photorecon.metrics import cloud_metrics, load_reference
from photorecon.resources import peak_bytes, reset_peak

DATA = Path(__file__).resolve().parents[1] / "../shared/data"
SETS = {"walnut1": "walnuts/2016_10_24__17_43_02", "walnut2": "walnuts/2016_10_25__12_57_06"}
TAUS = (0.0005, 0.001, 0.002)
MESHERS = ("tsdf", "poisson", "grid")


def run(name: str, root: Path, depth: Path, mesher: str) -> dict:
    ds = Dataset.open(root, depth_dir=depth)
    fc = FusionConfig(mesher=mesher, trunc_voxels=3.0)
    reset_peak()
    t0 = time.perf_counter()
    mesh = clean(fuse(load_frames(ds, fc), fc, ds.model.points), CleanConfig())
    seconds = time.perf_counter() - t0
    row = {"dataset": name, "mesher": mesher, "seconds": seconds, "peak_mb": round(peak_bytes() / 2**20),
           "faces": len(mesh.faces)}
    m = cloud_metrics(mesh, load_reference(root / "reference.ply"), TAUS, crop_margin=0.005)
    for s in m.thresholds:
        mm = f"{s.tau * 1000:g}mm"
        row[f"acc@{mm}"], row[f"comp@{mm}"], row[f"F@{mm}"] = s.precision, s.recall, s.fscore
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--depth-from", required=True, help="bench_real.py's --out folder (NAME/depth inside)")
    ap.add_argument("--only", default="walnut1,walnut2", help="comma-separated: walnut1, walnut2")
    ap.add_argument("--meshers", default=",".join(MESHERS), help="comma-separated: tsdf, poisson, grid")
    ap.add_argument("--data", default=str(DATA), help="the shared data folder (default: ../shared/data)")
    ap.add_argument("--json", help="write the rows as JSON here")
    a = ap.parse_args()
    progress.set_enabled(False)
    rows = []
    for name in a.only.split(","):
        depth = Path(a.depth_from) / name / "depth"
        if not depth.is_dir():
            print(f"bench_meshers: {depth} not found: run tools/bench_real.py --out {a.depth_from} first",
                  file=sys.stderr)
            return 2
        for mesher in a.meshers.split(","):
            rows.append(run(name, Path(a.data) / SETS[name], depth, mesher))
            r = rows[-1]
            print(f"{name:8s} {mesher:8s} {r['seconds']:7.1f} s {r['peak_mb']:6d} MB {r['faces']:>10,d} faces  "
                  + "  ".join(f"acc/comp/F@{t * 1000:g}mm {r[f'acc@{t * 1000:g}mm']:.3f}/"
                              f"{r[f'comp@{t * 1000:g}mm']:.3f}/{r[f'F@{t * 1000:g}mm']:.3f}" for t in TAUS),
                  flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
