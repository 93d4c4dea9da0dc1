#!/usr/bin/env python
"""Depth views chosen by coverage (``--depth-views auto``) against every view (``all``) on a redundant synthetic
capture: one object, many views, the cameras given (the synthetic model, with its sparse points), so the two
runs differ only in the depth stage. Per setting: depth maps computed, the depth stage's CPU seconds and peak
memory, the fusion's, the mesh's faces, and F-score / chamfer against the ground-truth mesh.

    python tools/bench_depth_views.py [--scene blob] [--views 80] [--width 320 --height 240] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import replace
from pathlib import Path

from photorecon import progress
from photorecon.metrics import evaluate_reconstruction
from photorecon.pipeline import ReconstructConfig, StageConfigs, reconstruct
from photorecon.synthetic import SynthConfig, synthesize


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="blob")
    ap.add_argument("--rig", default="sphere")
    ap.add_argument("--views", type=int, default=80)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--modes", default="auto,all")
    ap.add_argument("--data", help="keep the synthetic scene here (reused when present)")
    ap.add_argument("--json")
    args = ap.parse_args()
    progress.set_enabled(False)
    rows = []
    with tempfile.TemporaryDirectory() as t:
        data = Path(args.data) if args.data else Path(t) / "data"
        if not (data / "scene.json").is_file():
            synthesize(SynthConfig(scene=args.scene, rig=args.rig, views=args.views, width=args.width,
                                   height=args.height), data, overwrite=True)
        for mode in args.modes.split(","):
            d = StageConfigs()
            cfgs = replace(d, run=ReconstructConfig(poses=str(data / "sparse" / "0"), formats="ply"),
                           mvs=replace(d.mvs, depth_views=mode))
            out = Path(t) / f"rec_{mode}"
            rep = reconstruct(data / "images", out, cfgs)
            _, mm = evaluate_reconstruction(out, data)
            st = rep["stages"]
            row = {"mode": mode, "views": args.views, "size": f"{args.width}x{args.height}",
                   "depth_views": rep["depth"].get("depth_views"), "depth_maps": rep["depth"]["views"],
                   "depth_cpu_s": st["depth"].get("cpu_seconds"), "depth_s": st["depth"]["seconds"],
                   "depth_peak_mb": st["depth"]["peak_mb"], "fusion_cpu_s": st["fusion"].get("cpu_seconds"),
                   "fusion_peak_mb": st["fusion"]["peak_mb"], "faces": rep["mesh"]["faces"],
                   "fscore_1pct": mm.fscore, "fscore_0.5pct": mm.fscore_half,
                   "chamfer_pct_diag": 100 * mm.chamfer / mm.diagonal}
            rows.append(row)
            print(json.dumps(row), flush=True)
    cols = ["mode", "views", "depth_maps", "depth_cpu_s", "depth_peak_mb", "fusion_cpu_s", "fusion_peak_mb", "faces",
            "fscore_1pct", "fscore_0.5pct", "chamfer_pct_diag"]
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.4g}" if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
