#!/usr/bin/env python
"""Benchmark of the mappers on one matched capture: photorecon's incremental mapping (``mapping.map_model``,
with its relaxed retries) on 1 and on 2 threads, its global mapping (GLOMAP) and pycolmap's hierarchical
mapping, each on its own copy of the same ``database.db`` (the features and verified matches of a ``photorecon
sfm`` run), each ``--repeats`` times. Per run: photos registered, rotation error (degrees: mean, median, photos
over 5) and mean camera-centre error (% of the reference cameras' spread) after Sim3 alignment to the reference
cameras (``photorecon.metrics.pose_metrics``), process CPU seconds (user + system, all threads) and wall seconds; per
mapper, whether its runs gave the same poses (largest difference of the cam_from_world matrices, in the
model's own frame). What ``--mapper auto`` / ``--global-min`` should choose rests on these figures.

The capture defaults to ``gold_cape`` (../shared/data/gold_cape, or $PHOTORECON_DATA/gold_cape): run
``photorecon sfm -o OUT gold_cape/images`` once, then

    python tools/bench_mappers.py OUT [--reference gold_cape/reference] [--mappers incremental1,incremental2,global,hierarchical]
                                      [--repeats 2] [--leaf-max 60] [--keep DIR] [--json out.json]

Mappers: ``incrementalN`` (photorecon's incremental options, N threads; photorecon maps on 1), ``global``
(photorecon's GLOMAP options, all threads), ``hierarchical`` (photorecon's hierarchical mapping,
``mapping.map_model``: pycolmap.hierarchical_mapping with the incremental options on 1 thread per cluster,
clusters of at most ``--leaf-max`` photos mapped by as many workers as there are cores, then merged; incremental
mapping instead when it registers too few). Run on a quiet host: wall seconds on a shared one say little, CPU
seconds less so.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from photorecon.io.dataset import read_model
from photorecon.metrics import pose_metrics
from photorecon.poses import mapping
from photorecon.poses.sfm import SfMConfig

DATA = Path(os.environ.get("PHOTORECON_DATA", Path(__file__).resolve().parents[1] / "../shared/data"))


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run_mapper(name: str, database: Path, images: Path, work: Path, leaf_max: int) -> Path:
    """One run of mapper ``name`` on a copy of ``database``; returns the model's folder (COLMAP binary)."""
    db = work / "database.db"
    shutil.copyfile(database, db)
    model = work / "model"
    cfg = SfMConfig()
    if name.startswith("incremental"):
        threads = int(name[len("incremental"):] or 1)
        saved, mapping.MAPPER_THREADS = mapping.MAPPER_THREADS, threads
        try:
            mapping.map_model(db, images, model, cfg, False, "incremental")
        finally:
            mapping.MAPPER_THREADS = saved
    elif name == "global":
        mapping.map_model(db, images, model, cfg, False, "global")
    elif name == "hierarchical":
        saved, mapping.HIERARCHICAL_LEAF_MAX = mapping.HIERARCHICAL_LEAF_MAX, leaf_max
        try:
            mapping.map_model(db, images, model, cfg, False, "hierarchical")
        finally:
            mapping.HIERARCHICAL_LEAF_MAX = saved
    else:
        raise SystemExit(f"--mappers: unknown mapper {name!r} (incrementalN, global, hierarchical)")
    return model


def pose_difference(a: list, b: list) -> float:
    """Largest difference between the cam_from_world matrices of the views the two runs share (inf when
    they registered different photos)."""
    pa, pb = {v.name: v.cam_from_world[:3] for v in a}, {v.name: v.cam_from_world[:3] for v in b}
    if set(pa) != set(pb):
        return float("inf")
    return max(float(np.abs(pa[k] - pb[k]).max()) for k in pa)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sfm_out", type=Path, help="a photorecon sfm output folder (its colmap/database.db and colmap/images)")
    ap.add_argument("--reference", type=Path, default=DATA / "gold_cape" / "reference", help="reference cameras (any camera format photorecon reads)")
    ap.add_argument("--mappers", default="incremental1,incremental2,global,hierarchical")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--leaf-max", type=int, default=mapping.HIERARCHICAL_LEAF_MAX,
                    help="hierarchical: most photos per cluster")
    ap.add_argument("--keep", type=Path, metavar="DIR", help="keep each run's model as DIR/MAPPER_RUN")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    colmap = a.sfm_out / "colmap"
    database, images = colmap / "database.db", colmap / "images"
    for p in (database, images):
        if not p.exists():
            raise SystemExit(f"{p}: not found; run photorecon sfm -o {a.sfm_out} PHOTOS first")
    reference = read_model(a.reference).views
    rows = []
    print(f"{'mapper':14} {'run':>3} {'registered':>10} {'rot deg':>8} {'median':>8} {'>5 deg':>6} {'centre %':>8} "
          f"{'CPU s':>7} {'wall s':>7}")
    for name in a.mappers.split(","):
        views = []
        for k in range(a.repeats):
            with tempfile.TemporaryDirectory(prefix="bench_mappers") as tmp:
                c0, t0 = _cpu(), time.perf_counter()
                model = run_mapper(name, database, images, Path(tmp), a.leaf_max)
                cpu, wall = _cpu() - c0, time.perf_counter() - t0
                est = read_model(model).views if any(model.iterdir()) else []
                if a.keep:
                    shutil.copytree(model, a.keep / f"{name}_{k}", dirs_exist_ok=True)
            m = pose_metrics(est, reference) if len(est) >= 3 else None
            row = {"mapper": name, "run": k, "registered": len(est), "cpu_s": round(cpu, 1), "wall_s": round(wall, 1),
                   "rot_mean_deg": m and round(m["rot_mean_deg"], 4), "rot_median_deg": m and round(m["rot_median_deg"], 4),
                   "rot_over_5deg": m and sum(v["rot_deg"] > 5 for v in m["per_image"].values()),
                   "center_mean_pct": m and round(100 * m["center_mean_rel"], 3)}
            rows.append(row)
            views.append(est)
            nan = float("nan")
            print(f"{name:14} {k:>3} {len(est):>10} {m['rot_mean_deg'] if m else nan:>8.4f} "
                  f"{m['rot_median_deg'] if m else nan:>8.4f} {row['rot_over_5deg'] if m else '-':>6} "
                  f"{100 * m['center_mean_rel'] if m else nan:>8.3f} {cpu:>7.1f} {wall:>7.1f}", flush=True)
        if len(views) > 1:
            diff = max(pose_difference(views[0], v) for v in views[1:])
            rows.append({"mapper": name, "same_poses": diff == 0.0, "max_pose_difference": diff})
            print(f"{name:14} runs give {'the same poses' if diff == 0 else f'poses up to {diff:.2e} apart'}")
    if a.json:
        a.json.write_text(json.dumps({"cpus": os.cpu_count(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
