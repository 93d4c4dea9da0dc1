"""The textured model's face budget (``reconstruct --model-faces``): how far the simplified mesh lies from the full
one, in pixel footprints, and what simplifying and texturing cost, for a few budgets.

    .venv/bin/python tools/bench_model.py OUT [OUT ...] [--budgets 100000,250000,500000,1000000]

Each OUT is a ``reconstruct`` output (mesh.ply, depth/, images/, cameras), e.g. ``photorecon demo``'s
``reconstruction`` folder or a reconstruct of a ``photorecon synth`` dataset with ``--depth DATASET/depth``. Per
budget below the mesh's face count: points sampled uniformly on each surface (``--samples``), their distances to
the other surface (Open3D ``RaycastingScene.compute_distance``) in pixel footprints (``fusion.pixel_footprint`` of
OUT's depth maps); the symmetric Hausdorff distance, the larger of the two 95th percentiles, the smaller of the two
fractions within one footprint; and the CPU seconds of simplifying (``clean.simplify``) and of the whole model
(``mesh.model.build_model``: simplify + texture + compact) in this process. With OUT's report.json, the model's
CPU as a fraction of the run's (the sum of its other stages' ``cpu_seconds`` plus the model's measured here: OUT must
come from a run that computed every stage, not a cached re-run). Prints a Markdown table; ``--json FILE``: the rows.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def distances(a, b, n: int, seed: int = 0) -> np.ndarray:
    """Distances from ``n`` points sampled uniformly on mesh ``a`` to the surface of mesh ``b``."""
    import open3d as o3d
    import trimesh

    from photorecon.mesh.convert import raycasting_scene

    pts, _ = trimesh.sample.sample_surface(a, n, seed=seed)
    scene = raycasting_scene(b)
    return scene.compute_distance(o3d.core.Tensor(np.asarray(pts, np.float32))).numpy()


def main(argv=None) -> int:
    from photorecon.fusion import FusionConfig, load_frames, pixel_footprint
    from photorecon.io.dataset import Dataset
    from photorecon.mesh import load_mesh, simplify
    from photorecon.mesh.model import ModelConfig, build_model
    from photorecon.mesh.texture import TextureConfig

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("outs", nargs="+", type=Path)
    ap.add_argument("--budgets", default="100000,250000,500000,1000000")
    ap.add_argument("--samples", type=int, default=300_000)
    ap.add_argument("--no-texture", action="store_true", help="distances and simplification only")
    ap.add_argument("--json", type=Path, help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    budgets = [int(b) for b in args.budgets.split(",")]
    rows = []
    for out in args.outs:
        ds = Dataset.open(out)
        views = [v for v in ds.views if ds.has_depth(v)]
        footprint = pixel_footprint(load_frames(ds, FusionConfig(), views))
        full = load_mesh(out / "mesh.ply")
        run_cpu = None
        if (out / "report.json").is_file():
            stages = json.loads((out / "report.json").read_text())["stages"]
            run_cpu = sum(s.get("cpu_seconds", 0) for k, s in stages.items() if k != "model")
        for budget in budgets:
            if budget >= len(full.faces):
                continue
            t0 = time.process_time()
            small = simplify(full, budget)
            cpu_simplify = time.process_time() - t0
            d_ab = distances(small, full, args.samples) / footprint
            d_ba = distances(full, small, args.samples) / footprint
            row = {"out": str(out), "faces_full": len(full.faces), "budget": budget, "faces": len(small.faces),
                   "footprint": footprint, "hausdorff": float(max(d_ab.max(), d_ba.max())),
                   "p95": float(max(np.percentile(d_ab, 95), np.percentile(d_ba, 95))),
                   "within_1": float(min((d_ab <= 1).mean(), (d_ba <= 1).mean())), "cpu_simplify": cpu_simplify}
            if not args.no_texture:
                t0 = time.process_time()
                model = build_model(full, ds.views, lambda k: ds.image(ds.views[k]), ModelConfig(model_faces=budget),
                                    TextureConfig(), ds.mask)
                row["cpu_model"] = time.process_time() - t0
                row["atlas"] = "x".join(map(str, model.info["atlases"][0]))
                row["texels_per_pixel"] = model.info["texels_per_pixel"]
                if run_cpu:
                    row["model_share"] = row["cpu_model"] / (run_cpu + row["cpu_model"])
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    print("\n| output | full faces | budget | faces | footprint | Hausdorff (fp) | p95 (fp) | within 1 fp | "
          "simplify CPU s | model CPU s | atlas | texels/px | model share of run CPU |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {Path(r['out']).name} | {r['faces_full']} | {r['budget']} | {r['faces']} | {r['footprint']:.4g} | "
              f"{r['hausdorff']:.2f} | {r['p95']:.2f} | {100 * r['within_1']:.1f}% | {r['cpu_simplify']:.1f} | "
              f"{r.get('cpu_model', float('nan')):.1f} | {r.get('atlas', '')} | {r.get('texels_per_pixel', '')} | "
              f"{100 * r['model_share']:.1f}% |" if "model_share" in r else
              f"| {Path(r['out']).name} | {r['faces_full']} | {r['budget']} | {r['faces']} | {r['footprint']:.4g} | "
              f"{r['hausdorff']:.2f} | {r['p95']:.2f} | {100 * r['within_1']:.1f}% | {r['cpu_simplify']:.1f} | "
              f"{r.get('cpu_model', float('nan')):.1f} | {r.get('atlas', '')} | {r.get('texels_per_pixel', '')} | |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
