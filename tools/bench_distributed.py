#!/usr/bin/env python
"""Benchmark of ``--cluster`` (Dask): the depth and fusion stages in-process against a LocalCluster on the same
cores, a projection to more workers from the measured task costs, and the memory of chunked TSDF fusion as the
scene grows.

1. **Overhead** (``--only depth``): a synthetic blob, ``--views`` sphere views (120) at ``--size`` (320x240),
   true poses; PatchMatch (the ``fast`` preset) then TSDF, once in this process (numba on all cores) and once
   on ``local:N`` (N worker processes x cores/N threads, same cores). Wall times side by side (cluster start-up
   reported apart), depth maps compared.
2. **Projection** to 8, 32 and 128 workers (one core each), on paper: the measured per-task seconds of the
   cluster run (depth: one task per view and PatchMatch round, then one consistency-filter task per view;
   fusion: one task per chunk) list-scheduled on W workers along the graph's dependencies, plus the measured
   serial parts (planning, stitching, cleaning, export) and a per-task scheduling overhead measured on the
   cluster run. Same-sized tasks are assumed to cost what they cost here (no shared-file-system slowdown).
3. **Chunked fusion memory** (``--only memory``): 40 views' rendered depth with the world scaled by ``--scales``
   (1,2,4: 8x and 64x the scene's volume) fused at one fixed voxel size in chunks of ``--chunk-voxels`` (64),
   the chunk tasks on one single-threaded worker process: the largest grid and worker peak of any chunk task,
   against the peak of one volume (in this process; up to x2).

    python tools/bench_distributed.py [--views 120] [--size 320x240] [--workers 2] [--json out.json]
    python tools/bench_distributed.py --only memory [--scales 1,2]
"""
from __future__ import annotations

import argparse
import heapq
import json
import os
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from photorecon import progress
from photorecon.depth.mvs import MVS_PRESETS, MVSConfig, run_mvs
from photorecon.distributed import ClusterConfig, DaskExecutor, make_executor
from photorecon.fusion import FusionConfig, fuse, load_frames, tsdf_fuse, tsdf_fuse_chunked
from photorecon.io.colmap_text import SparseModel, write_colmap_text
from photorecon.io.dataset import Dataset
from photorecon.mesh import CleanConfig, clean
from photorecon.metrics import mesh_metrics
from photorecon.resources import measure
from photorecon.synthetic import SynthConfig, synthesize
from photorecon.tasks import IN_PROCESS


class Recording:
    """Wraps an executor and keeps every task graph it runs (keys and dependencies) with its results."""

    def __init__(self, inner):
        self.inner, self.graphs = inner, []
        self.distributed = inner.distributed

    @property
    def workers(self):
        return self.inner.workers

    def run(self, fn, tasks, shared=None, desc="", unit="view"):
        t0 = time.perf_counter()
        res = self.inner.run(fn, tasks, shared, desc, unit)
        self.graphs.append({"desc": desc, "tasks": list(tasks), "results": res, "wall": time.perf_counter() - t0})
        return res

    def close(self):
        self.inner.close()


def simulate(graph: dict, workers: int, overhead: float) -> float:
    """Makespan of the graph's tasks (measured seconds + ``overhead`` each) list-scheduled on ``workers``
    workers in submission order, each task starting when its dependencies are done and a worker is free."""
    done: dict[str, float] = {}
    free = [0.0] * workers
    heapq.heapify(free)
    for t in graph["tasks"]:
        ready = max((done[d] for d in t.deps), default=0.0)
        w = heapq.heappop(free)
        start = max(w, ready)
        end = start + graph["results"][t.key].get("seconds", 0.0) + overhead
        done[t.key] = end
        heapq.heappush(free, end)
    return max(done.values(), default=0.0)


def _fusion(ds, ex, cfg):
    t0 = time.perf_counter()
    frames = load_frames(ds, cfg)
    mesh = fuse(frames, cfg, ds.model.points, ex, ds, Path(tempfile.mkdtemp(prefix="bench_fw_")))
    mesh = clean(mesh, CleanConfig())
    return mesh, time.perf_counter() - t0


def bench_depth(args, work: Path) -> dict:
    w, h = (int(x) for x in args.size.lower().split("x"))
    data = work / "data"
    synthesize(SynthConfig(scene="blob", views=args.views, width=w, height=h, points=4000, seed=1), data, overwrite=True)
    ds = Dataset.open(data)
    mvs_cfg = MVSConfig(**MVS_PRESETS["fast"])
    fcfg = FusionConfig(trunc_voxels=3.0, chunk_voxels=args.chunk_voxels if args.chunk_voxels else None)
    out = {"views": args.views, "size": args.size, "workers": args.workers, "cores": os.cpu_count()}
    # warm-up (imports, numba's on-disk cache) on a separate 6-view set, in this process and later on every
    # worker, so that neither side pays a first compile or import inside the timing
    warm = work / "warm_data"
    synthesize(SynthConfig(scene="blob", views=6, width=w, height=h, points=500, seed=2), warm, overwrite=True)
    run_mvs(Dataset.open(warm), work / "warm_a", mvs_cfg)
    t0 = time.perf_counter()
    rep_a = run_mvs(ds, work / "a", mvs_cfg)
    t_depth_a = time.perf_counter() - t0
    mesh_a, t_fuse_a = _fusion(Dataset.open(data, work / "a"), IN_PROCESS, FusionConfig(trunc_voxels=3.0))
    t0 = time.perf_counter()
    ex = Recording(make_executor(ClusterConfig(f"local:{args.workers}")))
    t_start = time.perf_counter() - t0
    try:
        for _ in range(args.workers):  # each worker: PatchMatch, the filter and a fusion chunk once
            run_mvs(Dataset.open(warm), work / "warm_b", mvs_cfg, ex)
        _fusion(Dataset.open(warm, work / "warm_b"), ex, fcfg)
        ex.graphs.clear()
        t0 = time.perf_counter()
        rep_b = run_mvs(ds, work / "b", mvs_cfg, ex)
        t_depth_b = time.perf_counter() - t0
        mesh_b, t_fuse_b = _fusion(Dataset.open(data, work / "b"), ex, fcfg)
    finally:
        ex.close()
    worst = 0.0
    for p in sorted((work / "a").glob("*.npy")):
        if p.name.count(".") == 1:
            da, db = np.load(p), np.load(work / "b" / p.name)
            ok = da > 0
            worst = max(worst, float(np.abs(da[ok] - db[ok]).max() / da[ok].max()) if ok.any() else 0.0)
    diag = float(np.linalg.norm(mesh_a.bounds[1] - mesh_a.bounds[0]))
    f = mesh_metrics(mesh_b, mesh_a, tau=0.005 * diag, n_samples=100_000).fscore
    depth_g, fusion_g = ex.graphs[0], ex.graphs[-1]
    n_tasks = len(depth_g["tasks"]) + len(fusion_g["tasks"])
    busy = sum(r.get("seconds", 0.0) for g in (depth_g, fusion_g) for r in g["results"].values())
    graph_wall = depth_g["wall"] + fusion_g["wall"]
    overhead = max(0.0, (graph_wall * args.workers - busy) / n_tasks)  # idle worker-seconds per task
    serial = (t_depth_b - depth_g["wall"]) + (t_fuse_b - fusion_g["wall"])
    proj = {}
    for W in (args.workers, 8, 32, 128):
        proj[W] = serial + simulate(depth_g, W, overhead) + simulate(fusion_g, W, overhead)
    secs = lambda g, pre: [r["seconds"] for k, r in g["results"].items() if k.startswith(pre)]  # noqa: E731
    out.update({
        "in_process": {"depth_s": t_depth_a, "fusion_s": t_fuse_a, "total_s": t_depth_a + t_fuse_a},
        "cluster": {"startup_s": t_start, "depth_s": t_depth_b, "fusion_s": t_fuse_b, "total_s": t_depth_b + t_fuse_b,
                    "depth_tasks": len(depth_g["tasks"]), "fusion_tasks": len(fusion_g["tasks"])},
        "overhead": (t_depth_b + t_fuse_b) / (t_depth_a + t_fuse_a) - 1.0,
        "depth_overhead": t_depth_b / t_depth_a - 1.0,
        "depth_max_rel_diff": worst, "mesh_fscore_0.5pct": f, "views_in": rep_a["views"], "views_cluster": rep_b["views"],
        "task_seconds": {"patchmatch_round_mean": float(np.mean(secs(depth_g, "pm"))),
                         "patchmatch_round_max": float(np.max(secs(depth_g, "pm"))),
                         "filter_mean": float(np.mean(secs(depth_g, "filter"))),
                         "fusion_chunk_mean": float(np.mean(secs(fusion_g, ""))),
                         "fusion_chunk_max": float(np.max(secs(fusion_g, "")))},
        "serial_s": serial, "overhead_per_task_s": overhead, "busy_s": busy,
        "projection_s": {str(k): v for k, v in proj.items()},
    })
    return out


def _scaled_copy(src: Path, dst: Path, s: float) -> Path:
    """The dataset with the world scaled by ``s``: same images, depth x s, camera centres and points x s."""
    shutil.copytree(src / "images", dst / "images")
    if (src / "masks").is_dir():
        shutil.copytree(src / "masks", dst / "masks")
    (dst / "depth").mkdir()
    for p in (src / "depth").glob("*.npy"):
        np.save(dst / "depth" / p.name, np.load(p) * s)
    m = Dataset.open(src).model
    views = []
    for v in m.views:
        T = v.cam_from_world.copy()
        T[:3, 3] *= s
        views.append(replace(v, cam_from_world=T))
    write_colmap_text(SparseModel(views, m.points * s, m.colors, m.point_ids, m.errors, m.observations), dst / "sparse" / "0")
    return dst


def bench_memory(args, work: Path) -> dict:
    src = work / "mem_data"
    synthesize(SynthConfig(scene="blob", views=40, width=320, height=240, points=2000, seed=2), src, overwrite=True)
    base = Dataset.open(src)
    cfg0 = FusionConfig()
    frames = load_frames(base, cfg0)
    from photorecon.fusion import tsdf_voxel_size

    voxel = tsdf_voxel_size(frames, cfg0)[0] / 2  # one fixed voxel for every scale (fine: more blocks)
    rows = []
    # the chunk tasks on one worker process with one thread: its peak per task is the task's own (a worker holds
    # no frames, no earlier meshes), which this process's peak, holding both, is not
    from distributed import Client

    from photorecon.distributed import local_cluster

    cluster = local_cluster(1, cores=1)
    ex = DaskExecutor(Client(cluster), retries=0)
    ex._cluster = cluster
    try:
        for s in (float(x) for x in args.scales.split(",")):
            rows.append(_memory_row(src, work, s, voxel, args, ex))
    finally:
        ex.close()
    return {"voxel": voxel, "chunk_voxels": args.chunk_voxels or 64, "rows": rows}


def _memory_row(src: Path, work: Path, s: float, voxel: float, args, ex) -> dict:
    ds = Dataset.open(_scaled_copy(src, work / f"mem_x{int(s)}", s))
    cfg = FusionConfig(voxel_size=voxel, chunk_voxels=args.chunk_voxels or 64, memory_limit_gb=1e6)
    fr = load_frames(ds, cfg)
    stats = {}
    mesh = tsdf_fuse_chunked(ds, fr, cfg, executor=ex, work_dir=work / f"mem_w{int(s)}")
    tasks = mesh.metadata["chunk_tasks"].values()
    single_blocks = None
    if s <= 2.0:  # one volume, for contrast (x4 would need several GB)
        with measure(stats, "single"):
            m1 = tsdf_fuse(fr, cfg)
        single_blocks = len(m1.faces)
    return {"scale": s, "volume_x": s ** 3, "chunks": mesh.metadata["chunks"], "faces": len(mesh.faces),
            "max_task_grid_mb": max(t["grid_mb"] for t in tasks),
            "max_task_peak_mb": max(t["peak_mb"] for t in tasks),
            "max_task_s": max(t["seconds"] for t in tasks),
            "single_volume_peak_mb": stats.get("single", {}).get("peak_mb"),
            "single_volume_faces": single_blocks}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--views", type=int, default=120)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--chunk-voxels", type=int, default=0, help="fusion chunk size (default: the library's, 256; memory: 64)")
    ap.add_argument("--only", choices=["depth", "memory"])
    ap.add_argument("--scales", default="1,2,4", help="memory: world scales (x2 = 8x the volume)")
    ap.add_argument("--json")
    args = ap.parse_args()
    progress.set_enabled(False)
    work = Path(tempfile.mkdtemp(prefix="bench_dist_"))
    res = {}
    try:
        if args.only in (None, "depth"):
            d = res["depth"] = bench_depth(args, work)
            a, b = d["in_process"], d["cluster"]
            print(f"\n{d['views']} views {d['size']}, {d['cores']} cores: in-process vs local:{d['workers']}")
            print("| run | depth s | fusion s | total s | overhead |")
            print("|---|---|---|---|---|")
            print(f"| in-process | {a['depth_s']:.1f} | {a['fusion_s']:.1f} | {a['total_s']:.1f} | |")
            print(f"| local:{d['workers']} | {b['depth_s']:.1f} | {b['fusion_s']:.1f} | {b['total_s']:.1f} | "
                  f"{100 * d['overhead']:+.1f}% (depth {100 * d['depth_overhead']:+.1f}%; start-up {b['startup_s']:.1f} s apart) |")
            print(f"depth max rel. diff {d['depth_max_rel_diff']:.2e}, mesh F@0.5% {d['mesh_fscore_0.5pct']:.4f}, "
                  f"views {d['views_in']} / {d['views_cluster']}")
            print("task seconds:", {k: round(v, 3) for k, v in d["task_seconds"].items()},
                  f"serial {d['serial_s']:.1f} s, overhead/task {d['overhead_per_task_s'] * 1000:.0f} ms")
            print("| workers | projected s | speed-up vs in-process |")
            print("|---|---|---|")
            for k, v in d["projection_s"].items():
                print(f"| {k} | {v:.1f} | {a['total_s'] / v:.1f}x |")
        if args.only in (None, "memory"):
            m = res["memory"] = bench_memory(args, work)
            print(f"\nchunked TSDF, voxel {m['voxel']:.4g}, chunks of {m['chunk_voxels']} voxels")
            print("| scene volume | chunks | faces | max grid MB per task | max worker peak MB per task | max task s | one volume peak MB |")
            print("|---|---|---|---|---|---|---|")
            for r in m["rows"]:
                print(f"| {r['volume_x']:.0f}x | {r['chunks']} | {r['faces']:,} | {r['max_task_grid_mb']:.1f} | "
                      f"{r['max_task_peak_mb']:.0f} | {r['max_task_s']:.2f} | {r['single_volume_peak_mb'] or '-'} |")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2, default=str) + "\n")


if __name__ == "__main__":
    sys.exit(main())
