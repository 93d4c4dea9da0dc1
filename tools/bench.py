#!/usr/bin/env python
"""End-to-end benchmark: every stage on the built-in synthetic scenes, reconstructed from their images alone
(SfM poses, MVS depth, TSDF fusion), one table of seconds, peak memory and accuracy against the truth.

    python tools/bench.py [--scenes blob,knot,room] [--views 30] [--width 512 --height 384] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from photorecon import progress
from photorecon.metrics import evaluate_reconstruction
from photorecon.pipeline import reconstruct
from photorecon.resources import peak_bytes, reset_peak
from photorecon.synthetic import SynthConfig, synthesize


def run_scene(scene: str, args, tmp: Path) -> dict:
    data = tmp / scene
    reset_peak()
    t0 = time.perf_counter()
    res = synthesize(SynthConfig(scene=scene, views=args.views, width=args.width, height=args.height), data,
                     overwrite=True)
    synth = {"seconds": time.perf_counter() - t0, "peak_mb": peak_bytes() / 2**20}
    out = tmp / f"{scene}_rec"
    rep = reconstruct(data / "images", out)
    pm, mm = evaluate_reconstruction(out, data)
    st = rep["stages"]
    return {"scene": scene, "views": args.views, "size": f"{args.width}x{args.height}",
            "render_s_per_view": res.seconds_per_view, "synth": synth,
            "poses": st["poses"], "depth": st["depth"], "fusion": st["fusion"],
            "registered": pm["registered"], "rot_mean_deg": pm["rot_mean_deg"],
            "center_mean_pct_spread": 100 * pm["center_mean_rel"],
            "depth_maps": rep["depth"]["views"],
            "fscore_1pct": mm.fscore, "fscore_0.5pct": mm.fscore_half, "chamfer_pct_diag": 100 * mm.chamfer / mm.diagonal,
            "faces": rep["mesh"]["faces"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="blob,knot,room")
    ap.add_argument("--views", type=int, default=30)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--height", type=int, default=384)
    ap.add_argument("--json")
    args = ap.parse_args()
    progress.set_enabled(False)
    rows = []
    with tempfile.TemporaryDirectory() as t:
        for scene in args.scenes.split(","):
            try:
                rows.append(run_scene(scene.strip(), args, Path(t)))
            except Exception as exc:  # a scene that fails is reported, not hidden
                rows.append({"scene": scene, "error": f"{type(exc).__name__}: {exc}"})
            print(json.dumps(rows[-1], default=str), flush=True)
            if args.json:  # after every scene: a long run that is stopped keeps what it measured
                Path(args.json).write_text(json.dumps(rows, indent=1, default=str))
    print(f"{'scene':6} {'synth s':>7} {'poses s':>7} {'depth s':>7} {'fuse s':>7} {'peak MB':>7} {'reg':>6} "
          f"{'rot deg':>8} {'ctr %':>7} {'depths':>6} {'F@1%':>6} {'F@.5%':>6} {'Cham%':>7}")
    for r in rows:
        if "error" in r:
            print(f"{r['scene']:6} failed: {r['error']}")
            continue
        peak = max(r[k].get("peak_mb", 0) for k in ("poses", "depth", "fusion"))
        print(f"{r['scene']:6} {r['synth']['seconds']:7.1f} {r['poses']['seconds']:7.1f} {r['depth']['seconds']:7.1f} "
              f"{r['fusion']['seconds']:7.1f} {peak:7.0f} {r['registered']:>3}/{r['views']:<2} {r['rot_mean_deg']:8.4f} "
              f"{r['center_mean_pct_spread']:7.4f} {r['depth_maps']:6d} "
              f"{r['fscore_1pct']:6.3f} {r['fscore_0.5pct']:6.3f} {r['chamfer_pct_diag']:7.4f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
