#!/usr/bin/env python
"""Benchmark of structure from motion: photorecon's SfM stage next to plain pycolmap (default options) on
the same images in the same run. Sets: a synthetic textured blob (40 sphere views, 640x480) and, when
../shared/data/herz-jesu-p8 is present, its 8 real photos (max image size 1600) with the given K and
self-calibrated. Accuracy after Sim3 alignment to the ground-truth cameras.

    python tools/bench_sfm.py [--views 40] [--json out.json] [--skip-plain]

``--large`` instead: the matching and mapping choices for large sets (``--matching``, ``--mapper``) on
``--large-views`` (200) synthetic views at ``--large-size`` (320x240, small so that it runs in minutes), saved
as JPEGs that carry EXIF GPS (camera centres at ``--metres-per-unit`` 10 m per scene unit around a point in
Switzerland, with ``--gps-noise`` 1.5 m of Gaussian noise per axis). Sets: ``ring`` (an ordered capture: a
walk around the object, file names in capture order) and ``sphere`` (unordered: a Fibonacci sphere, where
consecutive names are far apart). Each choice against exhaustive + incremental on the same features:
matching and mapping seconds, image pairs matched, registered views, errors after Sim3 alignment.

    python tools/bench_sfm.py --large [--large-views 200] [--large-sets ring,sphere] [--json out.json]
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
from photorecon.poses.sfm import SfMConfig, run_sfm
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


LARGE_CHOICES = [("exhaustive", "incremental"), ("exhaustive", "global"), ("sequential", "incremental"),
                 ("sequential", "global"), ("spatial", "incremental"), ("spatial", "global")]


def geotagged_set(rig: str, n: int, size: str, root: Path, metres_per_unit: float, noise_m: float) -> tuple[Path, list]:
    """``n`` views of the blob on ``rig`` as JPEGs with EXIF GPS (noisy camera centres); the true views."""
    from photorecon.io.images import read_image
    from photorecon.poses.scale import geodetic_from_enu
    from photorecon.testing import write_gps_jpeg

    w, h = (int(x) for x in size.lower().split("x"))
    synth = root / f"{rig}_synth"
    res = synthesize(SynthConfig(scene="blob", rig=rig, views=n, width=w, height=h, points=500, seed=4,
                                 elevation=20.0, jitter_pos=0.01), synth, overwrite=True)
    photos = root / f"{rig}_photos"
    photos.mkdir(exist_ok=True)
    rng = np.random.default_rng(11)
    origin = (46.5197, 6.6323, 400.0)
    for v in res.views:
        enu = v.center * metres_per_unit + rng.normal(scale=noise_m, size=3)
        lla = geodetic_from_enu(enu, origin)[0]
        write_gps_jpeg(photos / f"{v.name}.jpg", lla, read_image(synth / "images" / v.image_file))
    return photos, read_model(synth / "sparse" / "0").views


def _pairs_matched(database: Path) -> int:
    import pycolmap

    db = pycolmap.Database.open(str(database))
    try:
        return int(db.num_matched_image_pairs())
    finally:
        db.close()


def run_large(args, tmp: Path) -> list[dict]:
    rows = []
    for rig in args.large_sets.split(","):
        photos, ref = geotagged_set(rig, args.large_views, args.large_size, tmp, args.metres_per_unit, args.gps_noise)
        out = tmp / f"{rig}_out"  # one output folder: extraction is shared, matching shared across mappers
        match_s, extract_s = {}, None
        for matching, mapper in LARGE_CHOICES:
            cfg = SfMConfig(matching=matching, mapper=mapper, exhaustive_max=0, min_registered=0.0,
                            sequential_overlap=args.sequential_overlap, spatial_neighbors=args.spatial_neighbors,
                            spatial_ignore_z=rig == "ring")
            label = f"{matching} + {mapper}"
            t0 = time.perf_counter()
            try:
                res = run_sfm(photos, out, cfg)
                views = read_model(out / "colmap" / "sparse").views
            except Exception as exc:  # report, do not hide
                print(f"{rig} {label}: failed: {exc}")
                rows.append({"set": f"{rig}-{len(ref)}", "method": label, "registered": 0, "of": len(ref),
                             "seconds": {"total": time.perf_counter() - t0}})
                continue
            if "extraction" not in res.cached:
                extract_s = res.seconds["extraction"]
            if "matching" not in res.cached:
                match_s[matching] = res.seconds["matching"]
            secs = {"extraction": extract_s, "matching": match_s[matching], "mapping": res.seconds["mapping"]}
            r = row(f"{rig}-{len(ref)}", label, secs, views, ref)
            r["pairs"] = _pairs_matched(out / "colmap" / "database.db")
            r["rot_max_deg"] = pose_metrics(views, ref)["rot_max_deg"]
            rows.append(r)
            print(f"{r['set']} {label}: match {secs['matching']:.1f} s, map {secs['mapping']:.1f} s, "
                  f"{r['registered']}/{r['of']}, {r['rot_mean_deg']:.3f} deg, {r['center_mean_rel_pct']:.3f} %", flush=True)
    return rows


def print_large(rows: list[dict]) -> None:
    base = {r["set"]: r for r in rows if r["method"] == "exhaustive + incremental" and r["registered"]}
    print("| set | matching + mapper | pairs | match s | map s | match + map s (vs exhaustive + incremental) "
          "| registered | rot. err. mean / max deg | centre err. % spread |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if not r["registered"]:
            print(f"| {r['set']} | {r['method']} | | | | | failed | | |")
            continue
        s = r["seconds"]
        mm = s["matching"] + s["mapping"]
        b = base.get(r["set"])
        ratio = f" ({mm / (b['seconds']['matching'] + b['seconds']['mapping']):.2f}x)" if b else ""
        print(f"| {r['set']} | {r['method']} | {r['pairs']:,} | {s['matching']:.1f} | {s['mapping']:.1f} | "
              f"{mm:.1f}{ratio} | {r['registered']}/{r['of']} | {r['rot_mean_deg']:.3f} / {r['rot_max_deg']:.2f} | "
              f"{r['center_mean_rel_pct']:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--large", action="store_true", help="matching / mapping choices on a large geotagged set")
    ap.add_argument("--large-views", type=int, default=200)
    ap.add_argument("--large-size", default="320x240")
    ap.add_argument("--large-sets", default="ring,sphere")
    ap.add_argument("--metres-per-unit", type=float, default=10.0)
    ap.add_argument("--gps-noise", type=float, default=1.5, help="GPS error, metres (sigma per axis)")
    ap.add_argument("--sequential-overlap", type=int, default=10)
    ap.add_argument("--spatial-neighbors", type=int, default=20)
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--json")
    ap.add_argument("--skip-plain", action="store_true")
    args = ap.parse_args()
    progress.set_enabled(False)
    if args.large:
        with tempfile.TemporaryDirectory() as t:
            rows = run_large(args, Path(t))
        print_large(rows)
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=2))
        return
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
