#!/usr/bin/env python
"""Benchmark of photorecon on large unordered photo sets: per stage wall and CPU seconds, peak memory, image
pairs matched (against n(n-1)/2), photos registered and pose errors after Sim3 alignment to the reference
cameras; end to end (``--e2e``) also depth views and faces.

Sets (``--only`` picks some, comma-separated):

* ``gold_cape``: ../shared/data/gold_cape (or $PHOTORECON_DATA/gold_cape), 119 real handheld photos (unordered), reference cameras in
  ``reference/`` (COLMAP text);
* ``unorderedN`` (``unordered100``, ``unordered200``, ``unordered500``; any N): N views of the synthetic blob
  on a sphere at 640x480 (``--size``), 3 degrees of rotation jitter, saved under shuffled file names
  (``photo_NNNN.png``: file order says nothing of the capture) with no GPS; rendered once into ``--data``.

Each set runs ``photorecon sfm`` (or ``photorecon reconstruct`` with ``--e2e``) as a child process with the
defaults plus ``--args`` (e.g. ``--args="--matching exhaustive"``), output under ``--work``.

    python tools/bench_scale.py --only unordered100,unordered200 [--args "..."] [--json out.json] [--e2e]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("PHOTORECON_DATA", ROOT / "../shared/data"))  # the shared benchmark data
GOLD_CAPE = DATA / "gold_cape"
DEFAULT_SETS = "gold_cape,unordered100,unordered200,unordered500"


def unordered_set(n: int, size: str, data: Path) -> tuple[Path, list]:
    """``n`` sphere views of the blob under shuffled names in ``data/unorderedN/photos``; the reference views
    (named like the photos)."""
    from photorecon.io.dataset import read_model
    from photorecon.synthetic import SynthConfig, synthesize

    w, h = (int(x) for x in size.lower().split("x"))
    root = data / f"unordered{n}_{w}x{h}"
    synth, photos = root / "synth", root / "photos"
    if not (root / "names.json").is_file():
        if not (synth / "sparse" / "0").is_dir():  # rendered before: kept
            synthesize(SynthConfig(scene="blob", rig="sphere", views=n, width=w, height=h, points=0, seed=3,
                                   jitter_deg=3.0), synth, overwrite=True)
        perm = np.random.default_rng(n).permutation(n)
        names = {}
        shutil.rmtree(photos, ignore_errors=True)
        photos.mkdir(parents=True)
        for v, p in zip(read_model(synth / "sparse" / "0").views, perm):
            names[v.name] = f"photo_{p:04d}"
            shutil.copyfile(synth / "images" / v.image_file, photos / f"{names[v.name]}.png")
        (root / "names.json").write_text(json.dumps(names))
    names = json.loads((root / "names.json").read_text())
    ref = read_model(synth / "sparse" / "0").views
    for v in ref:
        v.name = names[v.name]
    return photos, ref


def gold_cape_set() -> tuple[Path, list]:
    from photorecon.io.dataset import read_model

    return GOLD_CAPE / "images", read_model(GOLD_CAPE / "reference").views


def database_pairs(db: Path) -> tuple[int, int]:
    """(image pairs matched, image pairs verified) in a COLMAP database: every pair tried has a row of matches,
    empty where none were found."""
    import sqlite3

    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        matched = con.execute("SELECT COUNT(*) FROM matches").fetchone()[0]
        verified = con.execute("SELECT COUNT(*) FROM two_view_geometries WHERE rows > 0").fetchone()[0]
    finally:
        con.close()
    return matched, verified


def run_set(name: str, photos: Path, ref: list, out: Path, args: list[str], e2e: bool) -> dict:
    from photorecon.io.dataset import read_model
    from photorecon.metrics import pose_metrics

    shutil.rmtree(out, ignore_errors=True)
    cmd = [sys.executable, "-m", "photorecon", "-q", "reconstruct" if e2e else "sfm", str(photos), "-o", str(out), *args]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    n = len(ref)
    row = {"set": name, "photos": n, "args": " ".join(args), "mode": "e2e" if e2e else "sfm", "rc": proc.returncode,
           "wall_s": round(wall, 1), "cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 1),
           "all_pairs": n * (n - 1) // 2}
    if proc.returncode:
        row["error"] = (proc.stderr.strip().splitlines() or ["?"])[-1]
    work = out / "colmap"
    stages = {}
    for f in sorted((work / ".stages").glob("*.json")):
        s = json.loads(f.read_text())
        stages[f.stem] = {"s": round(s.get("seconds", 0), 1), "peak_mb": round(s.get("peak_mb", 0))}
    row["stages"] = stages
    row["peak_mb"] = max((s["peak_mb"] for s in stages.values()), default=None)  # the largest stage's peak
    if (work / "sfm_report.json").is_file():
        rep = json.loads((work / "sfm_report.json").read_text())
        row["matching"], row["registered"] = rep["matching"], len(rep["registered"])
    if (work / "database.db").is_file():
        row["pairs_matched"], row["pairs_verified"] = database_pairs(work / "database.db")
        row["pairs_per_photo"] = round(row["pairs_matched"] / n, 1)
    if (out / "sparse" / "0").is_dir():
        m = pose_metrics(read_model(out / "sparse" / "0").views, ref)
        row.update(registered=m["registered"], rot_mean_deg=round(m["rot_mean_deg"], 3),
                   rot_max_deg=round(m["rot_max_deg"], 3), center_mean_rel_pct=round(100 * m["center_mean_rel"], 3),
                   missing=m["missing"][:10])
    if e2e and (out / "report.json").is_file():
        rep = json.loads((out / "report.json").read_text())
        row["depth_views"] = rep.get("depth", {}).get("views")
        row["faces"] = rep.get("mesh", {}).get("faces")
        row["stage_seconds"] = {k: round(v.get("seconds", 0), 1) for k, v in rep.get("stages", {}).items()
                                if isinstance(v, dict)}
    return row


def table(rows: list[dict]) -> str:
    cols = [("set", 14), ("matching", 10), ("args", 22), ("photos", 6), ("registered", 10), ("pairs_matched", 13),
            ("pairs_per_photo", 15), ("rot_mean_deg", 12), ("center_mean_rel_pct", 19), ("wall_s", 8), ("cpu_s", 8),
            ("peak_mb", 8), ("depth_views", 11), ("faces", 9)]
    lines = ["  ".join(c.ljust(w) for c, w in cols)]
    for r in rows:
        lines.append("  ".join(str(r.get(c, "-") if r.get(c) is not None else "-")[:w].ljust(w) for c, w in cols))
        lines.append("    stages: " + ", ".join(f"{k} {v['s']} s / {v['peak_mb']} MB" for k, v in r.get("stages", {}).items())
                     + (f"; error: {r['error']}" if r.get("error") else ""))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default=DEFAULT_SETS, help=f"sets, comma-separated (default: {DEFAULT_SETS})")
    ap.add_argument("--args", default="", help="extra photorecon options, one string")
    ap.add_argument("--e2e", action="store_true", help="photorecon reconstruct instead of photorecon sfm")
    ap.add_argument("--size", default="640x480", help="synthetic image size (default: 640x480)")
    ap.add_argument("--data", type=Path, default=Path("/tmp/photorecon-bench-scale/data"), help="synthetic sets, made once")
    ap.add_argument("--work", type=Path, default=Path("/tmp/photorecon-bench-scale/out"), help="outputs")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    a = ap.parse_args()
    rows = []
    for name in a.only.split(","):
        if name == "gold_cape":
            if not GOLD_CAPE.is_dir():
                print(f"gold_cape: {GOLD_CAPE} not found, skipped")
                continue
            photos, ref = gold_cape_set()
        elif name.startswith("unordered") and name[9:].isdigit():
            photos, ref = unordered_set(int(name[9:]), a.size, a.data)
        else:
            raise SystemExit(f"--only: unknown set {name!r} (gold_cape or unorderedN)")
        rows.append(run_set(name, photos, ref, a.work / name, shlex.split(a.args), a.e2e))
        print(table(rows[-1:]), flush=True)
        if a.json:
            a.json.write_text(json.dumps(rows, indent=1))
    print()
    print(table(rows))


if __name__ == "__main__":
    main()
