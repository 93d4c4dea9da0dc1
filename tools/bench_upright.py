#!/usr/bin/env python
"""The model's frame (``photorecon.mesh.upright``) on finished reconstructions: for each output folder OUT, its
mesh (``OUT/mesh.ply``, or ``--mesh NAME``) and cameras (``OUT/sparse/0`` through ``photorecon.io.dataset``),
which rule stood it upright and how the frame agrees with the rest of the evidence:

* ``plane_to_Y``: degrees between the support plane's normal and the model's +Y (0 by construction when the
  support plane set the frame, a check of the transform; "-" under "camera up");
* ``camup_to_Y``: degrees between the cameras' up (``camera_up``) and the model's +Y;
* ``cams_min_Y``: the lowest camera's height in the model's frame (below 0: a camera under the ground);
* ``below``: the fraction of the mesh's vertices more than 2 voxels below Y = 0 (an object should have none);
* ``origin``: the world point at the model's origin.

Two rows per folder: ``report`` uses the plane and scene that OUT/report.json records (``mesh.scene``: the
cleaning's decision and the support plane it removed); ``search`` looks for the plane in the mesh itself (on a
cleaned object, whose support is gone, that falls back on the cameras' up). ``--scene`` forces a rule.

    python tools/bench_upright.py OUT [OUT ...] [--scene auto|object|open] [--mesh mesh.ply] [--json out.json]

On the walnut capture 2016_10_24__17_43_02 (../shared/data/walnuts; ``reconstruct --quality preview --poses
sparse/0``; 2026-11-29, shared 2-core host): the support plane that the search finds in the mesh kept whole
(``--scene open``) lies 0.43 degrees from the one the cleaning removed (``--scene auto``, an object capture), the
two base centres 0.16 mm apart, forward 0.2 degrees apart; no camera below Y = 0. That rig's cameras hang upside
down (their up 178 degrees from the plane's normal): the cleaned mesh without its report's plane ("search" row of
the auto run) falls back on the cameras' up and comes out upside down.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from photorecon.errors import PhotoreconError
from photorecon.io.dataset import Dataset
from photorecon.mesh.export import load_mesh
from photorecon.mesh.upright import apply_views, camera_up, upright_frame


def _angle(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def _report(out: Path) -> dict:
    try:
        return json.loads((out / "report.json").read_text())
    except (OSError, ValueError):
        return {}


def measure(out: Path, mesh_name: str, scene: str) -> list[dict]:
    """The rows for one output folder (see the module's docstring)."""
    report = _report(out)
    mesh = load_mesh(out / mesh_name)
    views = Dataset.open(out).views
    m_info = report.get("mesh") or {}
    voxel = m_info.get("voxel_size") if isinstance(m_info.get("voxel_size"), (int, float)) else None
    units = report.get("units") if isinstance(report.get("units"), str) and report.get("units") else "scene units"
    cam_up = camera_up(views)[0]
    rows = []
    for source in ("report", "search"):
        m = mesh.copy()
        m.metadata = {}
        sc = m_info.get("scene") if isinstance(m_info.get("scene"), dict) else None
        if source == "report":
            if sc is None:
                continue
            m.metadata["scene"] = {"detected": sc.get("detected")}
            if isinstance(sc.get("support_removed"), dict):
                m.metadata.update({k: sc["support_removed"][k] for k in ("support_normal", "support_offset")
                                   if k in sc["support_removed"]})
        up = upright_frame(m, views, scene=scene, units=units, voxel=voxel)
        R = up.model_from_world[:3, :3]
        V = np.asarray(m.vertices) @ R.T + up.model_from_world[:3, 3]
        tol = 2 * voxel if voxel else 0.002 * float(np.linalg.norm(np.ptp(V, axis=0)))
        cams = np.array([v.center for v in apply_views(up.model_from_world, views)])
        rows.append({
            "out": str(out), "source": source, "rule": up.rule, "reason": up.reason, "units": up.units,
            "plane_to_Y": None if up.plane is None else round(_angle(R @ up.plane[0], [0, 1, 0]), 3),
            "camup_to_Y": round(_angle(R @ cam_up, [0, 1, 0]), 3),
            "cams_min_Y": round(float(cams[:, 1].min()), 5),
            "below": round(float((V[:, 1] < -tol).mean()), 4),
            "origin": [round(float(x), 5) for x in up.origin_world],
        })
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("outs", nargs="+", type=Path, help="photorecon output folders (mesh.ply, sparse/0)")
    ap.add_argument("--scene", default="auto", choices=("auto", "object", "open"))
    ap.add_argument("--mesh", default="mesh.ply", help="the mesh file inside each folder")
    ap.add_argument("--json", type=Path, help="write the rows here")
    args = ap.parse_args(argv)
    rows = []
    for out in args.outs:
        try:
            rows += measure(out, args.mesh, args.scene)
        except PhotoreconError as exc:
            print(f"{out}: {exc}", file=sys.stderr)
    print(f"{'folder':40s} {'source':7s} {'rule':14s} {'plane_to_Y':>10s} {'camup_to_Y':>10s} {'cams_min_Y':>11s} "
          f"{'below':>7s}")
    for r in rows:
        p = "-" if r["plane_to_Y"] is None else f"{r['plane_to_Y']:.3f}"
        print(f"{r['out'][-40:]:40s} {r['source']:7s} {r['rule']:14s} {p:>10s} {r['camup_to_Y']:10.3f} "
              f"{r['cams_min_Y']:11.4g} {r['below']:7.4f}")
        print(f"    {r['reason']}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
