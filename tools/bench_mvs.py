#!/usr/bin/env python
"""Benchmark of the CPU multi-view stereo stage: PatchMatch (default) against the plane sweep.

1. speed: 9 views of a textured blob at 1600x1067 (each view has the other 8 as sources), true poses;
   seconds per view after the numba warm-up (reported apart), peak memory of the whole run.
2. accuracy, true poses: room and knot, 30 sphere views at 512x384 (as tools/bench.py): fraction of the
   surviving depths within 1% of the truth and coverage of the true surface pixels; PatchMatch (with and
   without the planar prior) and sweep.
3. what the multi-scale geometric consistency buys (ACMM): the room with PatchMatch at one level without
   the geometric term, and with it.
4. memory (only when asked: --only memory): peak of 50 views at 1600x1067, 8 sources each.

    python tools/bench_mvs.py [--json out.json] [--only speed,accuracy,ablation,memory]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path

from photorecon import progress
from photorecon.depth.mvs import MVSConfig, run_mvs
from photorecon.io.dataset import Dataset
from photorecon.resources import peak_bytes, reset_peak
from photorecon.synthetic import SynthConfig, synthesize
from photorecon.testing import depth_scores


def warm_up() -> float:
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as t:
        synthesize(SynthConfig(scene="blob", views=6, width=96, height=72, points=300), t, overwrite=True)
        run_mvs(Dataset.open(t), Path(t) / "d", MVSConfig(n_sources=2, pm_levels=2, pm_iterations=1,
                                                          pm_fine_iterations=1, min_consistent=0))
    return time.perf_counter() - t0


def scores(ds: Dataset, out: Path, root: Path) -> tuple[float, float]:
    """(within 1%, coverage) of the depth maps in ``out`` against the truth in ``root``."""
    return depth_scores(ds, out, root)[:2]


def _round_seconds(rep: dict, n: int) -> dict:
    """Wall seconds per view of each task kind (pm0 = PatchMatch's coarsest round, ..., filter), from the task times."""
    out: dict[str, float] = {}
    for key, s in rep.get("task_seconds", {}).items():
        kind = key.partition(":")[0]
        out[kind] = out.get(kind, 0.0) + s / n
    return {k: round(v, 2) for k, v in out.items()}


def run(ds, root, out, cfg) -> dict:
    reset_peak()
    t0, c0 = time.perf_counter(), time.process_time()
    rep = run_mvs(ds, out, cfg)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    w, c = scores(ds, out, root)
    # cpu_s_per_view: CPU seconds of this process (all its threads) per view; on a CPU shared with other work
    # cpu / 2 is what 2 free cores would need at best, wall seconds are inflated by the others
    return {"seconds": dt, "s_per_view": dt / len(ds.views), "cpu_s_per_view": cpu / len(ds.views),
            "within_1pct": w, "coverage": c, "round_s_per_view": _round_seconds(rep, len(ds.views)),
            "peak_mb": round(peak_bytes() / 2**20), "views": rep["views"]}


def speed(tmp: Path) -> list[dict]:
    root = tmp / "speed"
    synthesize(SynthConfig(scene="blob", rig="ring", views=9, width=1600, height=1067, elevation=15, points=4000), root,
               overwrite=True)
    ds = Dataset.open(root)
    rows = []
    for label, cfg in (("patchmatch (defaults)", MVSConfig()),
                       ("sweep (128 planes)", MVSConfig(method="sweep", min_confidence=0.5))):
        r = run(ds, root, tmp / "speed_out", cfg)
        rows.append({"section": "speed 1600x1067, 8 sources", "method": label, **r})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def memory(tmp: Path) -> list[dict]:
    """Peak memory of run_mvs on 50 views of 1600x1067 (8 sources each). What is held (images, depth maps,
    normals, costs of every view) does not depend on the iterations, so they are cut to one per round to
    keep the run short; the seconds of this row are therefore not the defaults' speed."""
    root = Path(tempfile.gettempdir()) / "bench_mvs_memory50_1600x1067"  # synthesized once, kept for the next run
    if not (root / "scene.json").is_file():
        synthesize(SynthConfig(scene="blob", rig="sphere", views=50, width=1600, height=1067, points=6000), root,
                   overwrite=True)
    ds = Dataset.open(root)
    cfg = MVSConfig(pm_iterations=1, pm_fine_iterations=1, pm_final_iterations=1)
    r = run(ds, root, tmp / "memory50_out", cfg)
    row = {"section": "memory, 50 views 1600x1067, 8 sources (1 iteration per round)", "method": "patchmatch", **r}
    print(json.dumps(row), flush=True)
    return [row]


def accuracy(tmp: Path) -> list[dict]:
    rows = []
    for scene in ("room", "knot"):
        root = tmp / scene
        synthesize(SynthConfig(scene=scene, views=30, width=512, height=384, points=3000), root, overwrite=True)
        ds = Dataset.open(root)
        for label, cfg in (("patchmatch", MVSConfig()), ("patchmatch + planar prior", MVSConfig(planar_prior=True)),
                           ("patchmatch + hole fill", MVSConfig(fill_gaps="on")),
                           ("patchmatch, 1 consistent view", MVSConfig(min_consistent=1)),
                           ("sweep", MVSConfig(method="sweep", min_confidence=0.5, min_consistent=1))):
            r = run(ds, root, tmp / f"{scene}_out_{len(rows)}", cfg)
            rows.append({"section": "true poses, 30 views 512x384", "scene": scene, "method": label, **r})
            print(json.dumps(rows[-1]), flush=True)
    return rows


def ablation(tmp: Path) -> list[dict]:
    root = tmp / "room"
    if not root.is_dir():
        synthesize(SynthConfig(scene="room", views=30, width=512, height=384, points=3000), root, overwrite=True)
    ds = Dataset.open(root)
    rows = []
    for label, cfg in (("1 level, photometric only", MVSConfig(pm_levels=1, pm_iterations=6, geom_consistency=False)),
                       ("3 levels, photometric only", MVSConfig(geom_consistency=False)),
                       ("3 levels + geometric consistency (default)", MVSConfig())):
        r = run(ds, root, tmp / f"abl_{len(rows)}", cfg)
        rows.append({"section": "room ablation", "method": label, **r})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write the results here")
    ap.add_argument("--only", default="speed,accuracy,ablation")
    args = ap.parse_args()
    progress.set_enabled(False)
    warm = warm_up()
    print(f"numba warm-up (compile, or load from the cache): {warm:.1f} s", flush=True)
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as t:
        for part in args.only.split(","):
            rows += {"speed": speed, "accuracy": accuracy, "ablation": ablation, "memory": memory}[part](Path(t))
            if args.json:
                Path(args.json).write_text(json.dumps({"warm_up_s": warm, "defaults": asdict(MVSConfig()), "rows": rows}, indent=1))
    print("\n| section | scene | method | s/view | CPU s/view | within 1% | coverage | peak MB |\n|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['section']} | {r.get('scene', 'blob')} | {r['method']} | {r['s_per_view']:.1f} | {r['cpu_s_per_view']:.1f} | "
              f"{r['within_1pct']:.3f} | {r['coverage']:.3f} | {r['peak_mb']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
