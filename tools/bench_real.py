#!/usr/bin/env python
"""Real photos, given cameras: PatchMatch MVS (the defaults) -> TSDF -> cleaning, on ../shared/data.

* walnuts/<capture> (12-camera ring, 1280x1024, COLMAP cameras without points, reference.ply in metres):
  accuracy, completeness and F-score at 0.5, 1 and 2 mm against the reference cloud (result samples more
  than 5 mm outside the reference's box are left out of accuracy: the platform and cables behind the nut).
* herz-jesu-p8, entry-p10 (3072x2048 facades, Strecha ground-truth cameras): the fraction of each image's
  pixels whose depth at least two other views confirm, and the fused mesh's face count.

Per dataset: MVS seconds per view (JIT warm-up excluded: it runs first on a tiny scene), peak memory, and a
preview PNG (the mesh from outside and from the input cameras) in --out. Prints a table; --json writes it.

    python tools/bench_real.py [--only walnut1,herz] [--out bench_real] [--json real.json] [--max-size 1600]
        [--planar-prior | --no-planar-prior] [--data ../shared/data]
"""
from __future__ import annotations

import argparse
import ast
import json
import sys
import tempfile
import time
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from photorecon import progress
from photorecon.depth.mvs import MVSConfig, run_mvs
from photorecon.fusion import FusionConfig, fuse, load_frames
from photorecon.io.dataset import Dataset
from photorecon.mesh import CleanConfig, clean, export
from photorecon.metrics import cloud_metrics, load_reference
from photorecon.preview import render_preview
from photorecon.resources import peak_bytes, reset_peak
from photorecon.synthetic import SynthConfig, synthesize

DATA = Path(__file__).resolve().parents[1] / "../shared/data"
SETS = {
    "walnut1": "walnuts/2016_10_24__17_43_02",
    "walnut2": "walnuts/2016_10_25__12_57_06",
    "herz": "herz-jesu-p8",
    "entry": "entry-p10",
}
TAUS = (0.0005, 0.001, 0.002)


def warm_up() -> float:
    """Compile (or load from numba's cache) every PatchMatch kernel on a tiny scene; returns seconds."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as t:
        synthesize(SynthConfig(scene="blob", views=6, width=96, height=72, points=300), t, overwrite=True)
        run_mvs(Dataset.open(t), Path(t) / "d", MVSConfig(n_sources=2, pm_levels=2, pm_iterations=1,
                                                          pm_fine_iterations=1, min_consistent=0))
    return time.perf_counter() - t0


def run_one(name: str, root: Path, out: Path, cfg: MVSConfig, fusion: dict | None = None) -> dict:
    ds = Dataset.open(root)
    work = out / name
    work.mkdir(parents=True, exist_ok=True)
    reset_peak()
    t0 = time.perf_counter()
    rep = run_mvs(ds, work / "depth", cfg)
    t_mvs = time.perf_counter() - t0
    peak_mvs = peak_bytes() / 2**20
    confirmed = [v["valid_fraction"] for v in rep["per_view"].values()]
    t1 = time.perf_counter()
    dsd = Dataset.open(root, depth_dir=work / "depth")
    fc = FusionConfig(**{"trunc_voxels": 3.0, **(fusion or {})})
    mesh = clean(fuse(load_frames(dsd, fc), fc, dsd.model.points), CleanConfig())
    t_fuse = time.perf_counter() - t1
    export(mesh, work / "mesh.ply")
    render_preview(mesh, work / "preview.png", cameras=ds.views)
    row = {"dataset": name, "views": len(ds.views), "depth_maps": rep["views"],
           "size": rep["per_view"][next(iter(rep["per_view"]))]["size"],
           "sparse_points": rep["sparse_points"], "triangulated": rep["triangulated"],
           "triangulation_s": rep["triangulation_seconds"], "mvs_s_per_view": rep["seconds_per_view"],
           "mvs_total_s": t_mvs, "mvs_peak_mb": round(peak_mvs),
           "confirmed_2_views_mean": float(np.mean(confirmed)), "confirmed_2_views_min": float(np.min(confirmed)),
           "fusion_s": t_fuse, "voxel": mesh.metadata.get("voxel_size"), "faces": len(mesh.faces),
           "skipped": rep["skipped"]}
    ref = root / "reference.ply"
    if ref.is_file():
        m = cloud_metrics(mesh, load_reference(ref), TAUS, crop_margin=0.005)
        for s in m.thresholds:
            mm = f"{s.tau * 1000:g}mm"
            row[f"acc@{mm}"], row[f"comp@{mm}"], row[f"F@{mm}"] = s.precision, s.recall, s.fscore
        row["accuracy_median_mm"] = m.accuracy_median * 1000
        row["completeness_median_mm"] = m.completeness_median * 1000
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(SETS), help="comma-separated: " + ", ".join(SETS))
    ap.add_argument("--out", default="bench_real", help="output folder (depth maps, meshes, previews)")
    ap.add_argument("--json", help="write the rows as JSON here")
    ap.add_argument("--max-size", type=int, default=None, help="override MVSConfig.max_size")
    ap.add_argument("--planar-prior", action=argparse.BooleanOptionalAction, default=None,
                    help="override MVSConfig.planar_prior")
    ap.add_argument("--data", default=str(DATA), help="the shared data folder (default: ../shared/data)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="override any MVSConfig or FusionConfig setting, e.g. --set pm_radius=5 --set normal_sdf=0.2 "
                         "(repeatable)")
    args = ap.parse_args()
    progress.set_enabled(False)
    over = {k: v for k, v in (("max_size", args.max_size), ("planar_prior", args.planar_prior)) if v is not None}
    fusion_fields = {f.name for f in fields(FusionConfig)}
    fusion = {}
    for item in args.set:
        name, _, value = item.partition("=")
        (fusion if name.strip() in fusion_fields else over)[name.strip()] = ast.literal_eval(value.strip())
    cfg = MVSConfig(**over)
    warm = warm_up()
    print(f"numba warm-up (compile or cache load): {warm:.1f} s", flush=True)
    rows = []
    for name in args.only.split(","):
        root = Path(args.data) / SETS[name]
        if not root.is_dir():
            print(f"{name}: {root} not found, skipped", file=sys.stderr)
            continue
        row = run_one(name, root, Path(args.out), cfg, fusion)
        rows.append(row)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}), flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps({"warm_up_s": warm, "config": asdict(cfg), "fusion": fusion, "rows": rows}, indent=1))
    cols = ["dataset", "size", "mvs_s_per_view", "mvs_peak_mb", "confirmed_2_views_mean", "faces",
            "acc@1mm", "comp@1mm", "F@0.5mm", "F@1mm", "F@2mm"]
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.3g}" if isinstance(r.get(c), float) else str(r.get(c, "")) for c in cols) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
