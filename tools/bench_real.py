#!/usr/bin/env python
"""Real photos, given cameras: PatchMatch MVS (the defaults) -> TSDF -> cleaning, on ../shared/data.

* walnuts/<capture> (12-camera ring, 1280x1024, COLMAP cameras without points, reference.ply in metres):
  accuracy, completeness and F-score at 0.5, 1 and 2 mm against the reference cloud (result samples more
  than 5 mm outside the reference's box are left out of accuracy: the cables behind the nut), the mesh cleaned
  with the defaults (``--scene auto``: the row's ``scene`` says what was detected and removed). With
  --support-plane also DTU-style, the platform under the nut left out (``support_plane``): the reference
  cloud has no platform, the photos do. With --object also the same fused mesh cleaned with ``--scene object``
  (photorecon's own support-plane removal, ``mesh.remove_support``, without the detection), scored uncropped,
  and its watertight companion (``mesh.closed_companion``, mesh_closed.ply; ``*_closed``). ``boundary_m``: the
  cleaned mesh's open boundary length (scene units: metres here). --reuse-depth: the depth maps an earlier
  run left in --out, no MVS.
* herz-jesu-p8, entry-p10 (3072x2048 facades, Strecha ground-truth cameras): the fraction of each image's
  pixels whose depth at least two other views confirm, the fused mesh's face count and the area of the
  ground in front of the facade (``ground_area``: faces within 15 cm of, and facing like, a plane fitted to
  the depth maps' bottom rows).

Per dataset: MVS seconds per view (JIT warm-up excluded: it runs first on a tiny scene), peak memory, and a
preview PNG (the mesh from outside and from the input cameras; with --object also the object mesh and the closed
companion) in --out. Prints a table; --json writes it.

    python tools/bench_real.py [--only walnut1,herz] [--out bench_real] [--json real.json] [--max-size 1600]
        [--planar-prior | --no-planar-prior] [--data ../shared/data] [--support-plane] [--object] [--reuse-depth]
        [--set NAME=VALUE]
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
from photorecon.mesh import (CleanConfig, boundary_length, clean, closed_companion, export, filled_area,
                             ransac_plane)
from photorecon.metrics import cloud_metrics, load_reference
from photorecon.report.preview import render_preview
from photorecon.resources import peak_bytes, reset_peak
from photorecon.synthetic import SynthConfig, synthesize

DATA = Path(__file__).resolve().parents[1] / "../shared/data"
SETS = {
    "walnut1": "walnuts/2016_10_24__17_43_02",
    "walnut2": "walnuts/2016_10_25__12_57_06",
    "walnut3": "walnuts/2016_10_24__17_44_40",
    "walnut4": "walnuts/2016_10_25__12_10_52",
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


def ground_plane(frames, rows: float = 0.15, tol: float = 0.05, max_tilt_deg: float = 35.0, iters: int = 1000,
                 seed: int = 0):
    """The ground in front of a facade: a RANSAC plane (unit normal n, offset c: n . X = c, n towards the
    cameras) through the world points of the bottom ``rows`` of every depth map (the cameras look at the
    facade with the ground below it), its normal within ``max_tilt_deg`` of the cameras' mean up direction
    (so that the facade's own foot is not taken), inliers within ``tol`` (scene units), refined by least
    squares."""
    from photorecon.cameras import backproject_depth, invert_rigid

    up = -np.mean([invert_rigid(f.view.cam_from_world)[:3, 1] for f in frames], axis=0)
    up /= np.linalg.norm(up)
    pts = []
    for f in frames:
        d = np.zeros_like(f.depth)
        h = f.depth.shape[0]
        d[int(h * (1 - rows)):] = f.depth[int(h * (1 - rows)):]
        pts.append(backproject_depth(d, f.view.intrinsics, f.view.cam_from_world))
    P = np.concatenate(pts)
    rng = np.random.default_rng(seed)
    P = P[rng.choice(len(P), min(len(P), 200_000), replace=False)]
    (n, c), _ = ransac_plane(P, tol, iters, rng, up, max_tilt_deg)
    inl = P[np.abs(P @ n - c) < tol]
    centre = inl.mean(0)
    n = np.linalg.svd(inl - centre, full_matrices=False)[2][2]
    cams = np.array([f.view.center for f in frames])
    if np.median(cams @ n - n @ centre) < 0:
        n = -n
    return n, float(n @ centre)


def ground_area(mesh, plane, tol: float = 0.15, max_angle_deg: float = 32.0) -> float:
    """Area of the mesh's faces within ``tol`` of the ground ``plane`` (``ground_plane``) whose normals are within
    ``max_angle_deg`` of its normal (scene units squared: m2 on the facades)."""
    n, c = plane
    near = np.abs(mesh.triangles_center @ n - c) < tol
    flat = mesh.face_normals @ n > np.cos(np.radians(max_angle_deg))
    return float(mesh.area_faces[near & flat].sum())


def support_plane(mesh, reference: np.ndarray, taus=TAUS, iters: int = 1000, seed: int = 0):
    """The platform an object stands on, for a DTU-style score that leaves it out (DTU's evaluation has a table
    plane per scan; the walnuts' reference cloud, cleaned by hand, has no platform): a RANSAC plane through the
    result's samples that the reference does not explain (farther than the middle tau from it), inliers within
    half the smallest tau. Accepted only when the whole reference lies on one side of it (a support, not a
    plane through the object) and it holds at least 1% of the samples. Returns (n, c_crop,
    plane_offset): n towards the reference, c_crop = the reference's lowest point along n (result samples below
    it are what the score leaves out), or None."""
    from scipy.spatial import cKDTree

    import trimesh

    pts = trimesh.sample.sample_surface(mesh, 200_000, seed=seed)[0]
    far = pts[cKDTree(reference).query(pts, workers=-1)[0] > sorted(taus)[len(taus) // 2]]
    if len(far) < 0.01 * len(pts):
        return None
    rng = np.random.default_rng(seed)
    tol = 0.5 * min(taus)
    best, best_k = ransac_plane(far, tol, iters, rng)
    if best is None or best_k < 0.01 * len(pts):
        return None
    n, c = best
    h = reference @ n - c
    if np.median(h) < 0:
        n, c, h = -n, -c, -h
    if h.min() <= 0:
        return None
    return n, float((reference @ n).min()), c


def _scores(row: dict, mesh, reference, suffix: str = "", crop_plane=None):
    m = cloud_metrics(mesh, reference, TAUS, crop_margin=0.005, crop_plane=crop_plane)
    for s in m.thresholds:
        mm = f"{s.tau * 1000:g}mm"
        row[f"acc@{mm}{suffix}"], row[f"comp@{mm}{suffix}"], row[f"F@{mm}{suffix}"] = s.precision, s.recall, s.fscore
    return m


def run_one(name: str, root: Path, out: Path, cfg: MVSConfig, fusion: dict | None = None,
            crop_support: bool = False, object_mode: bool = False, reuse_depth: bool = False) -> dict:
    ds = Dataset.open(root)
    work = out / name
    work.mkdir(parents=True, exist_ok=True)
    reset_peak()
    t0 = time.perf_counter()
    depth_dir = work / "depth"
    if reuse_depth and (depth_dir / "mvs_report.json").is_file():  # an earlier run's depth maps, as they are
        rep = json.loads((depth_dir / "mvs_report.json").read_text())
        print(f"{name}: depth maps reused from {depth_dir}", flush=True)
    else:
        rep = run_mvs(ds, depth_dir, cfg)
    t_mvs = time.perf_counter() - t0
    peak_mvs = peak_bytes() / 2**20
    confirmed = [v["valid_fraction"] for v in rep["per_view"].values()]
    t1 = time.perf_counter()
    dsd = Dataset.open(root, depth_dir=work / "depth")
    fc = FusionConfig(**{"trunc_voxels": 3.0, **(fusion or {})})
    frames = load_frames(dsd, fc)
    fused = fuse(frames, fc, dsd.model.points)
    mesh = clean(fused, CleanConfig(), cameras=ds.views)  # the defaults: --scene auto
    t_fuse = time.perf_counter() - t1
    export(mesh, work / "mesh.ply")
    obj = closed = None
    if object_mode:  # the same fused mesh cleaned with --scene object, and its closed companion
        obj = clean(fused, CleanConfig(scene="object"), cameras=ds.views)
        export(obj, work / "mesh_object.ply")
        render_preview(obj, work / "preview_object.png", cameras=ds.views)
        closed, closed_info = closed_companion(obj)
        export(closed, work / "mesh_closed.ply")
        render_preview(closed, work / "preview_closed.png", cameras=ds.views)
    render_preview(mesh, work / "preview.png", cameras=ds.views)
    row = {"dataset": name, "views": len(ds.views), "depth_maps": rep["views"],
           "size": rep["per_view"][next(iter(rep["per_view"]))]["size"],
           "sparse_points": rep["sparse_points"], "triangulated": rep["triangulated"],
           "triangulation_s": rep["triangulation_seconds"], "mvs_s_per_view": rep["seconds_per_view"],
           "mvs_total_s": t_mvs, "mvs_peak_mb": round(peak_mvs),
           "confirmed_2_views_mean": float(np.mean(confirmed)), "confirmed_2_views_min": float(np.min(confirmed)),
           "fusion_s": t_fuse, "voxel": mesh.metadata.get("voxel_size"), "faces": len(mesh.faces),
           "skipped": rep["skipped"], "scene": mesh.metadata.get("scene"),
           "boundary_m": boundary_length(mesh), "filled_area": filled_area(mesh), "fill": mesh.metadata.get("fill"),
           "scene_detected": (mesh.metadata.get("scene") or {}).get("detected")}
    ref = root / "reference.ply"
    if ref.is_file():
        reference = load_reference(ref)
        m = _scores(row, mesh, reference)
        if obj is not None:
            _scores(row, obj, reference, "_object")
            row["object_faces"] = len(obj.faces)
            row["boundary_m_object"] = boundary_length(obj)
            row["filled_area_object"] = filled_area(obj)
            row["closed_watertight"] = closed_info["watertight"]
            row["closed_filled_area"] = closed_info["filled_area"]
            _scores(row, closed, reference, "_closed")
            row["object_support"] = {k: v for k, v in obj.metadata.items() if k.startswith("support_")}
        row["accuracy_median_mm"] = m.accuracy_median * 1000
        row["completeness_median_mm"] = m.completeness_median * 1000
        if crop_support:
            plane = support_plane(mesh, reference)
            row["support_plane"] = None if plane is None else {"normal": plane[0].round(5).tolist(),
                                                               "crop_offset": plane[1], "plane_offset": plane[2]}
            if plane is not None:
                ms = _scores(row, mesh, reference, "_above_support", plane[:2])
                row["support_cropped_fraction"] = 1 - ms.result_samples / m.result_samples
    else:
        plane = ground_plane(frames)
        row["ground_m2"] = ground_area(mesh, plane)
        row["area_m2"] = float(mesh.area)
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
    ap.add_argument("--support-plane", action="store_true",
                    help="walnuts: also score with the platform under the nut left out, DTU-style (result samples "
                         "below the reference's lowest point along a plane fitted to the result's unexplained "
                         "samples; support_plane()); the uncropped scores are always reported")
    ap.add_argument("--object", action="store_true",
                    help="walnuts: also clean the same fused mesh with --object (the support plane and everything "
                         "below it removed, photorecon.mesh.remove_support) and score it uncropped (*_object)")
    ap.add_argument("--reuse-depth", action="store_true",
                    help="use the depth maps an earlier run left in --out (skips MVS; its timings are then not measured)")
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
        try:
            parsed = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):  # a choice, e.g. fill_gaps=on
            parsed = value.strip()
        (fusion if name.strip() in fusion_fields else over)[name.strip()] = parsed
    cfg = MVSConfig(**over)
    warm = warm_up()
    print(f"numba warm-up (compile or cache load): {warm:.1f} s", flush=True)
    rows = []
    for name in args.only.split(","):
        root = Path(args.data) / SETS[name]
        if not root.is_dir():
            print(f"{name}: {root} not found, skipped", file=sys.stderr)
            continue
        row = run_one(name, root, Path(args.out), cfg, fusion, args.support_plane, args.object, args.reuse_depth)
        rows.append(row)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}), flush=True)
        if args.json:
            Path(args.json).write_text(json.dumps({"warm_up_s": warm, "config": asdict(cfg), "fusion": fusion, "rows": rows}, indent=1))
    cols = ["dataset", "size", "mvs_s_per_view", "mvs_peak_mb", "confirmed_2_views_mean", "scene_detected", "faces", "ground_m2",
            "boundary_m", "acc@1mm", "comp@1mm", "F@0.5mm", "F@1mm", "F@2mm"]
    if args.support_plane:
        cols += ["acc@1mm_above_support", "F@1mm_above_support"]
    if args.object:
        cols += ["boundary_m_object", "acc@1mm_object", "comp@1mm_object", "F@1mm_object", "closed_watertight",
                 "closed_filled_area", "F@1mm_closed"]
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.3g}" if isinstance(r.get(c), float) else str(r.get(c, "")) for c in cols) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
