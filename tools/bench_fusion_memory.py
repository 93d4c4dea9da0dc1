#!/usr/bin/env python
"""Fusion memory as the photo count grows: the fusion and preview stages of ``reconstruct`` (``load_frames`` ->
TSDF -> cleaning -> export -> preview) on one facade's depth maps, with its views repeated to N = 10, 20, 40, 80
frames (a repeated view is a new frame with the same camera and depth map: the surface stays, the input grows),
against the fusion's memory budget (``--memory-gb``, FusionConfig.memory_gb: ``--set memory_gb=1.0``).

Each N runs in a fresh process: peak resident memory of the fusion stage and of the preview stage
(``resources.measure``, as report.json has them), wall seconds and CPU seconds (user + system, all threads),
the mesh's faces, area (scene units squared: m2 on the facades), faces per m2 and per input megapixel (N x the
depth maps' megapixels), the budget, whether the frames were read one at a time (``streamed``), and a linear
projection of the fusion peak to 50 frames. ``--profile`` adds the
resident memory sampled every 20 ms, the largest value per step (frames, grid, integration, extraction,
cleaning, export, surface report, preview).

    python tools/bench_fusion_memory.py bench_real/herz --dataset ../shared/data/herz-jesu-p8 [--counts 10,20,40,80]
        [--json out.json] [--profile] [--keep-mesh DIR] [--set NAME=VALUE ...]

RESULT is a folder with depth/ (``tools/bench_real.py --out DIR`` writes DIR/herz/depth) or a ``reconstruct``
output (its own images, cameras and depth/); --dataset gives the photos and cameras when they are elsewhere.
"""
from __future__ import annotations

import argparse
import ast
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import fields, replace
from pathlib import Path


def _rss() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


class Sampler:
    """Resident memory every ``dt`` seconds, the largest value per labelled step."""

    def __init__(self, dt: float = 0.02):
        self.step, self.peaks, self.dt = "start", {}, dt
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self):
        while not self._stop.is_set():
            r = _rss()
            self.peaks[self.step] = max(self.peaks.get(self.step, 0), r)
            time.sleep(self.dt)

    def wrap(self, module, name: str, label: str | None = None):
        fn = getattr(module, name, None)
        if fn is None:  # not in this version of photorecon
            return

        def wrapped(*a, **k):
            prev, self.step = self.step, label or name
            try:
                return fn(*a, **k)
            finally:
                r = _rss()
                self.peaks[self.step] = max(self.peaks.get(self.step, 0), r)
                self.step = prev

        setattr(module, name, wrapped)

    def stop(self) -> dict:
        self._stop.set()
        self._t.join()
        return {k: round(v / 2**20) for k, v in self.peaks.items()}


def repeated_dataset(result: Path, dataset: Path | None, n: int, tmp: Path):
    """A ``Dataset`` whose views are the result's views cycled to ``n`` (repeats renamed NAME~k), their depth
    maps (and confidence, normal maps) hard-linked (else copied) into ``tmp``."""
    from photorecon.io.colmap_text import SparseModel
    from photorecon.io.dataset import Dataset

    base = Dataset.open(dataset or result, depth_dir=result / "depth")
    views = [v for v in base.views if base.has_depth(v)]
    out = []
    for i in range(n):
        v = views[i % len(views)]
        k = i // len(views)
        name = v.name if k == 0 else f"{v.name}~{k}"
        img = base.image_path(v)
        for suffix in (".npy", ".conf.npy", ".normal.npy"):
            src = result / "depth" / f"{v.name}{suffix}"
            if src.is_file():  # a hard link (a symbolic one leading out of the folder is refused), else a copy
                try:
                    os.link(src.resolve(), tmp / f"{name}{suffix}")
                except OSError:
                    shutil.copyfile(src, tmp / f"{name}{suffix}")
        out.append(replace(v, name=name, image_path=str(img)))
    model = SparseModel(out, base.model.points, base.model.colors, base.model.point_ids)
    return Dataset(base.root, model, tmp), views


def child(args) -> dict:
    import numpy as np

    from photorecon import fusion, mesh as mesh_mod, preview as preview_mod, progress, report as report_mod
    from photorecon.fusion import FusionConfig
    from photorecon.layout import Layout
    from photorecon.mesh import CleanConfig
    from photorecon.pipeline import StageConfigs
    try:
        from photorecon.pipeline import fusion_stage, preview_stage
    except ImportError:  # a photorecon without them: the same calls as its reconstruct
        from photorecon.fusion import fuse_to_files, load_frames

        def fusion_stage(ds, f, c, layout, formats, work):
            return fuse_to_files(load_frames(ds, f), f, c, layout, formats, ds.views, ds.model.points, None, ds, work)

        def preview_stage(mesh, ds, layout):
            preview_mod.render_preview(mesh, layout.preview, cameras=ds.views)
            mesh_mod.export(report_mod.decimate_for_viewer(mesh, report_mod.PAGE_MAX_FACES), layout.viewer_mesh)
    from photorecon.resources import measure

    progress.set_enabled(False)
    sampler = Sampler() if args.profile else None
    if sampler:
        from photorecon.fusion import tsdf as fusion_tsdf
        for mod, name in ((fusion, "load_frames"), (fusion_tsdf, "tsdf_voxel_size"), (fusion_tsdf, "_new_grid"),
                          (fusion_tsdf, "_integrate_frame"), (fusion_tsdf, "_extract"), (fusion_tsdf, "stitch_pieces"),
                          (fusion, "surface_report"), (mesh_mod, "clean"), (mesh_mod, "export"), (fusion, "export"),
                          (preview_mod, "render_preview"), (report_mod, "decimate_for_viewer")):
            sampler.wrap(mod, name)
        sampler.wrap(mesh_mod, "clean_open3d", "clean")
        sampler.wrap(fusion, "clean_open3d", "clean")  # fusion imports it by name
    d = StageConfigs()
    fus, cln = d.fusion, d.clean
    ff, cf = {f.name for f in fields(FusionConfig)}, {f.name for f in fields(CleanConfig)}
    for item in args.set:
        k, _, v = item.partition("=")
        k, v = k.strip(), ast.literal_eval(v.strip())
        if k in ff:
            fus = replace(fus, **{k: v})
        elif k in cf:
            cln = replace(cln, **{k: v})
        else:
            raise SystemExit(f"--set {k}: not a FusionConfig or CleanConfig field")
    with tempfile.TemporaryDirectory() as t:
        ds, base_views = repeated_dataset(Path(args.result), Path(args.dataset) if args.dataset else None,
                                          args.child, Path(t))
        out = Path(t) / "out"
        out.mkdir()
        layout = Layout(out)
        stats: dict = {}
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        with measure(stats, "fusion"):
            mesh, info = fusion_stage(ds, fus, cln, layout, ("ply",), out / ".work")
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        with measure(stats, "preview"):
            preview_stage(mesh, ds, layout)
        r2 = resource.getrusage(resource.RUSAGE_SELF)
        if args.keep_mesh:  # the fused mesh, to compare two versions' outputs
            Path(args.keep_mesh).mkdir(parents=True, exist_ok=True)
            shutil.copyfile(layout.mesh("ply"), Path(args.keep_mesh) / f"mesh_{args.child}.ply")
        depth = np.load(Path(args.result) / "depth" / f"{base_views[0].name}.npy", mmap_mode="r")
        mp = args.child * depth.shape[0] * depth.shape[1] / 1e6
        area = float(mesh.area)
        row = {"frames": args.child, "views": len(base_views), "depth_size": f"{depth.shape[1]}x{depth.shape[0]}",
               "fusion_peak_mb": stats["fusion"]["peak_mb"], "fusion_s": stats["fusion"]["seconds"],
               "fusion_cpu_s": round(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime, 1),
               "preview_peak_mb": stats["preview"]["peak_mb"], "preview_s": stats["preview"]["seconds"],
               "preview_cpu_s": round(r2.ru_utime + r2.ru_stime - r1.ru_utime - r1.ru_stime, 1),
               "faces": len(mesh.faces), "area_m2": round(area, 2), "faces_per_m2": round(len(mesh.faces) / area),
               "faces_per_input_mp": round(len(mesh.faces) / mp), "voxel": mesh.metadata.get("voxel_size"),
               "chunks": mesh.metadata.get("chunks"), "budget_mb": round(getattr(fus, "memory_gb", 0) * 1024),
               "streamed": info.get("streamed")}
    if sampler:
        row["profile_mb"] = sampler.stop()
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("result", help="folder with depth/ (bench_real --out DIR: DIR/NAME) or a reconstruct output")
    ap.add_argument("--dataset", help="photos and cameras (default: RESULT itself)")
    ap.add_argument("--counts", default="10,20,40,80", help="frame counts, comma-separated (default: 10,20,40,80)")
    ap.add_argument("--json", help="write the rows here")
    ap.add_argument("--profile", action="store_true", help="resident memory per step (sampled every 20 ms)")
    ap.add_argument("--keep-mesh", metavar="DIR", help="copy each count's mesh.ply to DIR/mesh_N.ply")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="override a FusionConfig or CleanConfig setting (the pipeline's defaults otherwise)")
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args)))
        return 0
    rows = []
    for n in [int(c) for c in args.counts.split(",")]:
        cmd = [sys.executable, __file__, args.result, "--child", str(n)] + (["--dataset", args.dataset] if args.dataset else [])
        cmd += (["--profile"] if args.profile else []) + (["--keep-mesh", args.keep_mesh] if args.keep_mesh else [])
        cmd += [a for s in args.set for a in ("--set", s)]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode:
            print(p.stderr[-3000:], file=sys.stderr)
            return 1
        rows.append(json.loads(p.stdout.strip().splitlines()[-1]))
        print(json.dumps(rows[-1]), flush=True)
    proj = None
    if len(rows) >= 2:
        import numpy as np

        slope, icpt = np.polyfit([r["frames"] for r in rows], [r["fusion_peak_mb"] for r in rows], 1)
        proj = {"fusion_peak_mb_at_50": round(slope * 50 + icpt), "mb_per_frame": round(slope, 1)}
    cols = ["frames", "fusion_peak_mb", "budget_mb", "streamed", "fusion_cpu_s", "preview_peak_mb", "preview_cpu_s",
            "faces", "area_m2", "faces_per_m2", "faces_per_input_mp", "voxel"]
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(str(r.get(c, "")) for c in cols) + " |")
    if proj:
        print(f"projection (linear in frames): {proj['mb_per_frame']} MB per frame, {proj['fusion_peak_mb_at_50']} MB "
              "fusion peak at 50 frames")
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "projection": proj, "set": args.set}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
