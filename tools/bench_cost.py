#!/usr/bin/env python
"""What a reconstruction costs on real photos: ``photorecon reconstruct --poses`` (defaults) on the shared
captures, in CPU seconds (user + system of all threads: what counts on a shared machine) beside wall seconds.

* walnut1 / walnut2: a 12-camera ring at 1280x1024 (COLMAP cameras, no points: the depth stage triangulates
  SIFT matches with the cameras held fixed first); F@0.5/1/2 mm against the reference cloud, as
  ``tools/bench_real.py`` scores it.
* herz / entry: Strecha facades at 3072x2048 with their ground-truth cameras, depth at 1600 px; the fraction
  of pixels with a depth that survived the multi-view filter (``depth_valid``).

Per capture: CPU and wall seconds of the whole run and of each stage (report.json), CPU seconds per view and per
megapixel-source (views x sources x working-resolution megapixels: comparable across captures), the depth
stage's triangulation seconds, peak memory per stage. ``--profile`` runs it under cProfile with a CPU-time
clock and writes the top functions by their own CPU time to OUT/NAME/profile.txt (numba kernels count as
their Python call). The numba kernels come from their cache (``photorecon warmup`` runs first).

    python tools/bench_cost.py [--only walnut1,herz] [--data ../shared/data] [--out bench_cost] [--json cost.json]
        [--profile] [-- EXTRA RECONSTRUCT FLAGS]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

DATA = Path(__file__).resolve().parents[1] / "../shared/data"
SETS = {
    "walnut1": ("walnuts/2016_10_24__17_43_02", "images", "sparse/0"),
    "walnut2": ("walnuts/2016_10_25__12_57_06", "images", "sparse/0"),
    "herz": ("herz-jesu-p8", "images", "gt_dense_cameras"),
    "entry": ("entry-p10", "images", "gt_dense_cameras"),
}


def _child_profile(argv: list[str], out: Path) -> int:
    import cProfile
    import pstats

    from photorecon.cli import main

    prof = cProfile.Profile(time.process_time)
    rc = prof.runcall(main, argv)
    with open(out, "w") as fh:
        st = pstats.Stats(prof, stream=fh)
        st.sort_stats("tottime").print_stats(40)
        st.sort_stats("cumulative").print_stats(40)
    return rc or 0


def run_one(name: str, data: Path, out: Path, extra: list[str], profile: bool) -> dict:
    sub, images, cams = SETS[name]
    root = data / sub
    work = out / name
    argv = ["-q", "reconstruct", str(root / images), "--poses", str(root / cams), "-o", str(work), "--overwrite",
            "--force", *extra]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    work.mkdir(parents=True, exist_ok=True)
    if profile:
        cmd = [sys.executable, __file__, "--child-profile", str(work / "profile.txt"), "--", *argv]
    else:
        cmd = [sys.executable, "-m", "photorecon", *argv]
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE, text=True)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    err = p.stderr.read()
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"{name}: reconstruct failed:\n{err[-3000:]}")
    rep = json.loads((work / "report.json").read_text())
    depth_files = sorted(p for p in (work / "depth").glob("*.npy") if p.name.count(".") == 1)
    shape = np.load(depth_files[0], mmap_mode="r").shape
    valid = float(np.mean([(np.load(p) > 0).mean() for p in depth_files]))
    views = rep["depth"]["views"]
    n_sources = rep.get("parameters", {}).get("mvs", {}).get("n_sources")
    mp = shape[0] * shape[1] / 1e6
    cpu = ru.ru_utime + ru.ru_stime
    stages = rep["stages"]
    row = {"dataset": name, "views": views, "depth_size": f"{shape[1]}x{shape[0]}", "sources": n_sources,
           "cpu_s": round(cpu, 1), "wall_s": round(wall, 1), "peak_mb": round(ru.ru_maxrss / 1024),
           "cpu_s_per_view": round(cpu / views, 1),
           "cpu_s_per_mp_source": round(cpu / (views * (n_sources or 1) * mp), 3) if n_sources else None,
           "depth_cpu_s_per_view": round(stages["depth"].get("cpu_seconds", float("nan")) / views, 1),
           "triangulation_s": rep["depth"].get("triangulation_seconds"),
           "stages": {k: {x: v.get(x) for x in ("seconds", "cpu_seconds", "peak_mb")} for k, v in stages.items()},
           "faces": rep["mesh"].get("faces"), "depth_valid": round(valid, 4)}
    ref = root / "reference.ply"
    if ref.is_file():
        import trimesh

        from bench_real import TAUS
        from photorecon.metrics import cloud_metrics, load_reference

        mesh = trimesh.load(work / "mesh.ply", process=False)
        m = cloud_metrics(mesh, load_reference(ref), TAUS, crop_margin=0.005)
        for s in m.thresholds:
            row[f"F@{s.tau * 1000:g}mm"] = round(s.fscore, 4)
    return row


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--child-profile":
        return _child_profile(sys.argv[4:], Path(sys.argv[2]))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="walnut1,herz", help="comma-separated: " + ", ".join(SETS))
    ap.add_argument("--data", default=str(DATA), help="the shared data folder (default: ../shared/data)")
    ap.add_argument("--out", default="bench_cost", help="output folder (one reconstruct output per capture)")
    ap.add_argument("--json", help="write the rows as JSON here")
    ap.add_argument("--profile", action="store_true", help="cProfile (CPU clock) each run -> OUT/NAME/profile.txt")
    ap.add_argument("extra", nargs="*", help="after --: more reconstruct flags, e.g. -- --mvs.n-sources 6")
    args = ap.parse_args()
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "photorecon", "warmup"], check=True,
                   env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    rows = []
    for name in args.only.split(","):
        if not (Path(args.data) / SETS[name][0]).is_dir():
            print(f"{name}: {Path(args.data) / SETS[name][0]} not found, skipped", file=sys.stderr)
            continue
        rows.append(run_one(name, Path(args.data), Path(args.out), args.extra, args.profile))
        print(json.dumps(rows[-1]), flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps({"extra": args.extra, "rows": rows}, indent=1))
    cols = ["dataset", "views", "depth_size", "cpu_s", "wall_s", "cpu_s_per_view", "cpu_s_per_mp_source",
            "depth_cpu_s_per_view", "triangulation_s", "peak_mb", "faces", "depth_valid", "F@1mm"]
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(str(r.get(c, "")) for c in cols) + " |")
    for r in rows:
        print(f"{r['dataset']} stages (wall s / CPU s / peak MB): " + ", ".join(
            f"{k} {v['seconds']:.1f}/{v.get('cpu_seconds') or 0:.1f}/{v.get('peak_mb') or 0:.0f}" for k, v in r["stages"].items()))
    print(f"({time.perf_counter() - t0:.0f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
