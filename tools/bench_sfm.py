#!/usr/bin/env python
"""Benchmark of structure from motion: photorecon's SfM stage next to plain pycolmap (default options) on
the same images in the same run. Sets: a synthetic textured blob (40 sphere views, 640x480) and, when
../shared/data/herz-jesu-p8 is present, its 8 real photos (max image size 1600) with the given K and
self-calibrated. Accuracy after Sim3 alignment to the ground-truth cameras.

    python tools/bench_sfm.py [--views 40] [--json out.json] [--skip-plain]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from photorecon import progress
from photorecon.cameras import Intrinsics, View
from photorecon.io.dataset import read_model
from photorecon.metrics import pose_metrics
from photorecon.io.colmap import read_colmap_binary
from photorecon.sfm import SfMConfig, run_sfm
from photorecon.synthetic import SynthConfig, synthesize

HERZ = Path(__file__).resolve().parents[1] / "../shared/data/herz-jesu-p8"



def plain_pycolmap(images_dir: str | Path, work: str | Path) -> dict:
    """Reference run of pycolmap with its default options: seconds per stage and the largest model."""
    import pycolmap

    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    db = work / "database.db"
    secs = {}
    t0 = time.perf_counter()
    pycolmap.extract_features(str(db), str(images_dir))
    secs["extraction"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    pycolmap.match_exhaustive(str(db))
    secs["matching"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    (work / "sparse").mkdir(exist_ok=True)
    recs = pycolmap.incremental_mapping(str(db), str(images_dir), str(work / "sparse"))
    secs["mapping"] = time.perf_counter() - t0
    if not recs:
        return {"seconds": secs, "model": None}
    best = work / "best"
    best.mkdir(exist_ok=True)
    max(recs.values(), key=lambda r: r.num_reg_images()).write_binary(str(best))
    return {"seconds": secs, "model": read_colmap_binary(best)}

def herz_jesu_reference(root: Path) -> list[View]:
    """Ground-truth cameras of Herz-Jesu-P8 (R = camera-to-world rotation, C = centre; P = K [R^T | -R^T C])."""
    views = []
    for f in sorted((root / "gt_dense_cameras").glob("*.camera")):
        v = np.array(f.read_text().split(), float)  # K (9), distortion (3), R (9), C (3), width height
        K, R, C, (w, h) = v[0:9].reshape(3, 3), v[12:21].reshape(3, 3), v[21:24], v[24:26]
        T = np.eye(4)
        T[:3, :3] = R.T
        T[:3, 3] = -R.T @ C
        views.append(View(f.name.split(".")[0], Intrinsics.from_K(K, int(w), int(h)), T))
    return views


def row(name, method, secs, views, ref):
    n = len(ref)
    if views is None:
        return {"set": name, "method": method, "seconds": secs, "registered": 0, "of": n}
    m = pose_metrics(views, ref)
    return {"set": name, "method": method, "seconds": secs, "total_s": sum(secs.values()), "registered": m["registered"],
            "of": n, "rot_mean_deg": m["rot_mean_deg"], "center_mean_rel_pct": 100 * m["center_mean_rel"]}


def run_set(name, images, ref, cfgs: dict, tmp: Path, skip_plain: bool) -> list[dict]:
    rows = []
    if not skip_plain:
        p = plain_pycolmap(images, tmp / f"{name}_plain")
        rows.append(row(name, "plain pycolmap", p["seconds"], p["model"].views if p["model"] else None, ref))
    for label, cfg in cfgs.items():
        out = tmp / f"{name}_{label}"
        t0 = time.perf_counter()
        try:
            res = run_sfm(images, out, cfg)
            secs = {k: res.seconds[k] for k in ("extraction", "matching", "mapping")}
            views = read_model(out / "colmap" / "sparse").views  # distorted model: same images as plain
        except Exception as exc:  # report, do not hide
            print(f"{name} {label}: failed: {exc}")
            secs, views = {"total": time.perf_counter() - t0}, None
        rows.append(row(name, label, secs, views, ref))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--json")
    ap.add_argument("--skip-plain", action="store_true")
    args = ap.parse_args()
    progress.set_enabled(False)
    rows = []
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        synth = tmp / "blob"
        synthesize(SynthConfig(scene="blob", views=args.views), synth, overwrite=True)
        ref = read_model(synth / "sparse" / "0").views
        rows += run_set("blob-40", synth / "images", ref, {"photorecon": SfMConfig()}, tmp, args.skip_plain)
        if HERZ.is_dir():
            ref = herz_jesu_reference(HERZ)
            rows += run_set("herz-jesu-p8", HERZ / "images", ref,
                            {"photorecon K given": SfMConfig(intrinsics=str(HERZ / "images" / "K.txt")),
                             "photorecon self-cal": SfMConfig()}, tmp, args.skip_plain)
    print(f"{'set':13} {'method':20} {'extract':>8} {'match':>7} {'map':>7} {'total':>7} {'reg':>6} {'rot deg':>8} {'ctr %spread':>11}")
    for r in rows:
        s = r["seconds"]
        if r["registered"] == 0:
            print(f"{r['set']:13} {r['method']:20} failed")
            continue
        print(f"{r['set']:13} {r['method']:20} {s['extraction']:8.1f} {s['matching']:7.1f} {s['mapping']:7.1f} "
              f"{r['total_s']:7.1f} {r['registered']:>3}/{r['of']:<2} {r['rot_mean_deg']:8.4f} {r['center_mean_rel_pct']:11.4f}")
    plain = {r["set"]: r for r in rows if r["method"] == "plain pycolmap" and r["registered"]}
    for r in rows:
        if r["method"] != "plain pycolmap" and r["set"] in plain and r["registered"]:
            r["time_ratio_vs_plain"] = r["total_s"] / plain[r["set"]]["total_s"]
            print(f"{r['set']} {r['method']}: {r['time_ratio_vs_plain']:.2f}x the time of plain pycolmap")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
