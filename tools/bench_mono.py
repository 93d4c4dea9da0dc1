#!/usr/bin/env python
"""Benchmark of monocular-depth inference and alignment on onnxruntime (2 threads by default), with models
built on the spot (photorecon.testing; no downloaded weights): the test suite's oracle model (256x256) and a
random-weight convolutional encoder-decoder of roughly MiDaS v2.1 small's compute (~1.8 GMAC at 256x256).

    python tools/bench_mono.py [--threads 2] [--runs 20] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from photorecon.depth.align import fit_scale_shift
from photorecon.depth.mono import MonoConfig, MonoModel
from photorecon.testing import conv_net, oracle_model


def time_model(path: Path, threads: int, runs: int, image=(480, 640)) -> dict:
    m = MonoModel(path, MonoConfig(preset="midas_small", threads=threads))
    img = (np.random.default_rng(0).random(image + (3,)) * 255).astype(np.uint8)
    m.predict([img])  # warm-up
    x = m.preprocess(img)[None].astype(np.float32)
    t_inf, t_full = [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        m.session.run(None, {m.input_name: x})
        t_inf.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        m.predict([img])
        t_full.append(time.perf_counter() - t0)
    return {"input": list(m.fixed), "inference_ms": 1000 * float(np.median(t_inf)),
            "with_pre_post_ms": 1000 * float(np.median(t_full)), "providers": m.providers}


def time_alignment(runs: int, n_points: int = 1000) -> float:
    rng = np.random.default_rng(1)
    z = rng.uniform(1, 5, n_points)
    p = (1 / z - 0.1) / 2.0
    bad = rng.random(n_points) < 0.2
    p[bad] = rng.uniform(p.min(), p.max(), bad.sum())  # 20% outliers
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fit_scale_shift(p, 1 / z)
        ts.append(time.perf_counter() - t0)
    return 1000 * float(np.median(ts))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--json")
    args = ap.parse_args()
    rows = {}
    with tempfile.TemporaryDirectory() as t:
        rows["oracle (test model)"] = time_model(oracle_model(Path(t) / "oracle.onnx"), args.threads, args.runs)
        rows["MiDaS-small-sized, random weights"] = time_model(conv_net(Path(t) / "convnet.onnx", size=256),
                                                               args.threads, args.runs)
    align_ms = time_alignment(args.runs)
    print(f"{'model':36} {'input':>9} {'infer ms':>9} {'+pre/post ms':>13}   (640x480 images, {args.threads} threads)")
    for k, r in rows.items():
        print(f"{k:36} {'x'.join(map(str, r['input'])):>9} {r['inference_ms']:9.1f} {r['with_pre_post_ms']:13.1f}")
    print(f"alignment (robust scale/shift fit, 1000 points): {align_ms:.1f} ms per image")
    if args.json:
        Path(args.json).write_text(json.dumps({"models": rows, "alignment_ms": align_ms, "threads": args.threads}, indent=2))


if __name__ == "__main__":
    main()
