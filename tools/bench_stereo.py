#!/usr/bin/env python
"""Two views: synthetic rectified stereo pairs (one orientation, baseline along x) and converging pairs,
reconstructed with photorecon's defaults from the two images and their cameras (``reconstruct --poses
transforms.json``: no sparse points given, they are triangulated), against the truth, and on the rectified
pairs against OpenCV's StereoSGBM.

    python tools/bench_stereo.py [--scenes knot,room,blob] [--width 640 --height 480] [--baseline 0.3]
                                 [--rigs stereo,pair] [--contrast 1.0] [--json out.json] [--keep DIR] [--set NAME=VALUE]

Per pair and view, on the pixels both views see (from the true depth maps):
- ``within1%``: the fraction whose depth is within 1% of the truth (no depth = wrong), ``coverage`` the fraction
  with a depth;
- rectified pairs, left view, in disparity (fx * baseline / depth): ``<=2px`` the fraction within 2 px (no
  answer = wrong), ``compl`` the fraction answered, ``bad>2px`` the share of answers off by more than 2 px; for
  photorecon and for SGBM (semi-global block matching, 5x5 blocks, P1 / P2 = 8 / 32 x 25, uniqueness 10,
  speckle filter 100 px / 2, left-right check 1 px, given the true disparity range: an advantage photorecon does
  not get).
Also the faces of the fused mesh (a mesh must come out) and the seconds of the reconstruction.
"""
from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from photorecon import progress
from photorecon.io.dataset import read_model
from photorecon.metrics import covisible, disparity_scores, two_view_depth_scores
from photorecon.pipeline import StageConfigs, reconstruct
from photorecon.synthetic import SynthConfig, synthesize


def sgbm(left: np.ndarray, right: np.ndarray, dmin: float, dmax: float) -> np.ndarray:
    """OpenCV's StereoSGBM disparity of the left image (float, NaN = none) searched over [dmin, dmax]."""
    block = 5
    lo = max(0, int(np.floor(dmin)) - 2)
    num = int(np.ceil((dmax + 2 - lo) / 16)) * 16
    m = cv2.StereoSGBM_create(minDisparity=lo, numDisparities=num, blockSize=block, P1=8 * block * block,
                              P2=32 * block * block, disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100,
                              speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    d = m.compute(left, right).astype(np.float32) / 16.0
    d[d < lo] = np.nan
    return d


def run_pair(scene: str, rig: str, args, tmp: Path) -> dict:
    data = tmp / f"{scene}_{rig}"
    synthesize(SynthConfig(scene=scene, rig=rig, width=args.width, height=args.height, radius=args.radius,
                           elevation=args.elevation, baseline=args.baseline, fov=args.fov), data, overwrite=True)
    if args.contrast != 1.0:  # weak texture: both images' contrast scaled about mid-grey, kept in 8 bits
        for f in sorted((data / "images").iterdir()):
            img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED).astype(np.float32)
            cv2.imwrite(str(f), np.clip(np.round(127.5 + (img - 127.5) * args.contrast), 0, 255).astype(np.uint8))
    out = tmp / f"{scene}_{rig}_rec"
    cfgs = StageConfigs()
    cfgs.mvs = dataclasses.replace(cfgs.mvs, **args.mvs_over)
    cfgs.run.poses = str(data / "transforms.json")  # cameras only: the sparse points are triangulated
    t0 = time.perf_counter()
    rep = reconstruct(data / "images", out, cfgs, overwrite=True)
    seconds = time.perf_counter() - t0
    views = read_model(data / "sparse" / "0").views
    gt = [np.load(data / "depth" / f"{v.name}.npy") for v in views]
    row = {"scene": scene, "rig": rig, "size": f"{args.width}x{args.height}", "baseline": args.baseline,
           "seconds": seconds, "faces": rep.mesh["faces"], "depth_maps": rep.depth["views"],
           "sparse_points": rep.depth.get("sparse_points"), "views": {}}
    for a, b in ((0, 1), (1, 0)):
        va, vb = views[a], views[b]
        cov = covisible(gt[a], va, gt[b], vb)
        p = out / "depth" / f"{va.name}.npy"
        d = np.load(p) if p.is_file() else np.zeros_like(gt[a])
        if d.shape != gt[a].shape:  # depth at a smaller working resolution
            d = cv2.resize(d, gt[a].shape[::-1], interpolation=cv2.INTER_NEAREST)
        row["views"][va.name] = two_view_depth_scores(d, gt[a], cov)
        if rig == "stereo" and a == 0:
            fxb = va.intrinsics.fx * float(np.linalg.norm(va.center - vb.center))
            gt_disp = np.where(gt[a] > 0, fxb / np.maximum(gt[a], 1e-12), 0)
            ours = np.where(d > 0, fxb / np.maximum(d, 1e-12), np.nan)
            left = cv2.imread(str(data / "images" / f"{va.name}.png"), cv2.IMREAD_GRAYSCALE)
            right = cv2.imread(str(data / "images" / f"{vb.name}.png"), cv2.IMREAD_GRAYSCALE)
            t1 = time.perf_counter()
            theirs = sgbm(left, right, gt_disp[cov].min(), gt_disp[cov].max())
            row["sgbm_seconds"] = time.perf_counter() - t1
            row["disparity"] = {"photorecon": disparity_scores(ours, gt_disp, cov),
                                "sgbm": disparity_scores(theirs, gt_disp, cov)}
    row["within1"] = float(np.mean([v["within"] for v in row["views"].values()]))
    return row


def _value(text: str):
    """A --set value: a Python literal (1, 0.5, True), else the text itself (a choice such as off)."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="knot,room,blob")
    ap.add_argument("--rigs", default="stereo,pair")
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--baseline", type=float, default=0.3, help="scene units (the scenes are about 2 across)")
    ap.add_argument("--radius", type=float, default=2.6, help="camera distance from the scene centre")
    ap.add_argument("--elevation", type=float, default=35.0, help="degrees")
    ap.add_argument("--fov", type=float, default=50.0, help="horizontal field of view, degrees")
    ap.add_argument("--contrast", type=float, default=1.0,
                    help="scale both images' contrast about mid-grey by this factor (e.g. 0.1: weak texture)")
    ap.add_argument("--json")
    ap.add_argument("--keep", help="keep the datasets and reconstructions in this folder")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="override an MVSConfig setting, e.g. --set fill_gaps=off (repeatable)")
    args = ap.parse_args()
    args.mvs_over = {k.strip(): _value(v.strip()) for k, _, v in (s.partition("=") for s in args.set)}
    progress.set_enabled(False)
    rows = []
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(args.keep or t)
        tmp.mkdir(parents=True, exist_ok=True)
        for scene in args.scenes.split(","):
            for rig in args.rigs.split(","):
                try:
                    rows.append(run_pair(scene.strip(), rig.strip(), args, tmp))
                except Exception as exc:  # a pair that fails is reported, not hidden
                    rows.append({"scene": scene, "rig": rig, "error": f"{type(exc).__name__}: {exc}"})
                print(json.dumps(rows[-1], default=str), flush=True)
                if args.json:
                    Path(args.json).write_text(json.dumps(rows, indent=1, default=str))
    print(f"\n{'scene':6} {'rig':6} {'within1%':>8} {'cover':>6} {'faces':>7} {'sec':>6} | "
          f"{'ours<=2px':>9} {'compl':>6} {'bad>2px':>7} | {'sgbm<=2px':>9} {'compl':>6} {'bad>2px':>7}")
    for r in rows:
        if "error" in r:
            print(f"{r['scene']:6} {r['rig']:6} failed: {r['error']}")
            continue
        cover = np.mean([v["coverage"] for v in r["views"].values()])
        line = f"{r['scene']:6} {r['rig']:6} {r['within1']:8.3f} {cover:6.3f} {r['faces']:7d} {r['seconds']:6.1f} |"
        if "disparity" in r:
            o, s = r["disparity"]["photorecon"], r["disparity"]["sgbm"]
            line += (f" {o['within']:9.3f} {o['completeness']:6.3f} {o['bad']:7.3f} |"
                     f" {s['within']:9.3f} {s['completeness']:6.3f} {s['bad']:7.3f}")
        print(line)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2, default=str))


if __name__ == "__main__":
    main()
