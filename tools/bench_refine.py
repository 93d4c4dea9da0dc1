#!/usr/bin/env python
"""Photometric refinement (``--refine``) of an existing mesh, scored before and after against a reference.

* a walnut capture (``--dataset``, its cameras in sparse/0, ``reference.ply``) and a mesh of it (e.g.
  bench_real's ``OUT/walnut1/mesh.ply``): accuracy / completeness / F-score at 0.5, 1 and 2 mm as
  bench_real scores them (result samples more than 5 mm outside the reference's box left out);
* a synthetic dataset (``photorecon synth``, e.g. ``--scene relief``) and a reconstruct output's mesh:
  against its gt_mesh.ply, Chamfer and F-score at ``--tau`` (scene units).

Prints one row per setting (the first: no refinement) with seconds and CPU seconds of the refinement and the
mean vertex displacement; --json writes the rows; --out writes each refined mesh.

    python tools/bench_refine.py --dataset ../shared/data/walnuts/2016_10_24__17_43_02 --mesh bench_real/walnut1/mesh.ply
        [--set refine_smooth=0.5 --set refine_levels=1 ...] [--variant "refine_views=6"] [--json r.json] [--out DIR]
"""
from __future__ import annotations

import argparse
import ast
import json
import sys
from dataclasses import asdict
from pathlib import Path

from photorecon import progress
from photorecon.io.dataset import Dataset
from photorecon.mesh import export, load_mesh
from photorecon.mesh.refine import RefineConfig, refine_dataset
from photorecon.metrics import cloud_metrics, load_reference, mesh_metrics

TAUS = (0.0005, 0.001, 0.002)


def score(mesh, root: Path, taus) -> dict:
    ref = root / "reference.ply"
    if ref.is_file():
        m = cloud_metrics(mesh, load_reference(ref), taus, crop_margin=0.005)
        out = {"accuracy_median": m.accuracy_median, "completeness_median": m.completeness_median}
    else:
        m = mesh_metrics(mesh, load_mesh(root / "gt_mesh.ply"), taus[0], taus=taus)
        out = {"chamfer": m.chamfer, "accuracy_mean": m.accuracy_mean, "completeness_mean": m.completeness_mean}
    for s in m.thresholds:
        out[f"F@{s.tau:g}"] = s.fscore
    return out


def _settings(text: str) -> dict:
    out = {}
    for item in filter(None, text.split(",")):
        k, _, v = item.partition("=")
        out[k.strip()] = ast.literal_eval(v.strip())
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", required=True, help="capture with reference.ply, or a synth dataset (gt_mesh.ply)")
    ap.add_argument("--mesh", required=True, help="the mesh to refine")
    ap.add_argument("--tau", default=",".join(map(str, TAUS)), help="thresholds, scene units, comma-separated")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="RefineConfig setting for every variant")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=VALUE[,...]",
                    help="one more row with these settings (default: one row with the defaults)")
    ap.add_argument("--json", help="write the rows as JSON here")
    ap.add_argument("--out", help="write each refined mesh into this folder")
    args = ap.parse_args()
    progress.set_enabled(False)
    root = Path(args.dataset)
    taus = [float(t) for t in args.tau.split(",")]
    ds = Dataset.open(root)
    mesh = load_mesh(args.mesh)
    base = _settings(",".join(args.set))
    rows = [{"setting": "none", "vertices": len(mesh.vertices), **score(mesh, root, taus)}]
    print(json.dumps(rows[-1]), flush=True)
    for k, variant in enumerate(args.variant or [""]):
        cfg = RefineConfig(**{"refine": True, **base, **_settings(variant)})
        refined, info = refine_dataset(mesh, ds, cfg)
        rows.append({"setting": variant or "defaults", **{k2: v for k2, v in asdict(cfg).items() if k2 != "refine"},
                     **info, **score(refined, root, taus)})
        print(json.dumps(rows[-1]), flush=True)
        if args.out:
            Path(args.out).mkdir(parents=True, exist_ok=True)
            export(refined, Path(args.out) / f"refined_{k}.ply")
        if args.json:
            Path(args.json).write_text(json.dumps(rows, indent=1))
    cols = ["setting", "vertices", "seconds", "cpu_seconds", "mean_displacement"] + [f"F@{t:g}" for t in taus]
    cols += ["chamfer"] if "chamfer" in rows[0] else ["accuracy_median", "completeness_median"]
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.4g}" if isinstance(r.get(c), float) else str(r.get(c, "")) for c in cols) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
