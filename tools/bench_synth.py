#!/usr/bin/env python
"""Benchmark: CPU rendering speed of synthetic scenes (target: <= 0.3 s per 640x480 view, texture included).

    python tools/bench_synth.py [--views 10] [--json out.json] [--bunny ../shared/data/stanford-bunny/bun_zipper.ply]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from photorecon.mesh import load_mesh
from photorecon.render import Renderer
from photorecon.synthetic import SynthConfig, make_scene, make_views, normalize_mesh


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=10)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--bunny", default=str(Path(__file__).resolve().parents[1] / "../shared/data/stanford-bunny/bun_zipper.ply"))
    ap.add_argument("--json", help="write the figures to this JSON file")
    args = ap.parse_args()
    scenes = {name: make_scene(name) for name in ("blob", "knot", "room")}
    if Path(args.bunny).is_file():
        scenes["bunny"] = load_mesh(args.bunny)
    rows = []
    for name, mesh in scenes.items():
        for background in ("color", "texture"):
            m, _, _ = normalize_mesh(mesh)
            r = Renderer(m, 0, background)
            views = make_views(SynthConfig(views=args.views, width=args.width, height=args.height))
            r.render(views[0])  # warm-up
            times = []
            for v in views:
                t0 = time.perf_counter()
                out = r.render(v)
                times.append(time.perf_counter() - t0)
            rows.append({"scene": name, "background": background, "faces": len(m.faces),
                         "size": f"{args.width}x{args.height}", "mean_s": float(np.mean(times)),
                         "max_s": float(np.max(times)), "coverage": float(out.mask.mean()),
                         "target_s": 0.3, "meets_target": bool(np.mean(times) <= 0.3)})
    print(f"{'scene':8} {'backdrop':9} {'faces':>7} {'size':>8} {'mean s':>7} {'max s':>7} {'target':>7}")
    for r in rows:
        print(f"{r['scene']:8} {r['background']:9} {r['faces']:7d} {r['size']:>8} {r['mean_s']:7.3f} {r['max_s']:7.3f} "
              f"{'ok' if r['meets_target'] else 'MISS':>7}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
