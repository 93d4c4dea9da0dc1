#!/usr/bin/env python
"""Where a mesh misses a reference cloud, and why: result samples far from the reference (accuracy misses) and
reference points far from the result (completeness misses), grouped by height above the support plane, by
surface slope and by how many photos saw them, with each miss told as the reference's or the mesh's fault.

Categories of a miss at tau (distance > tau):

* accuracy (result sample -> nearest reference point):
  ``outside_box``    more than --crop-margin outside the reference's bounding box (what bench_real leaves out);
  ``support``        within --support-height of the support plane (the platform: not in a hand-cleaned reference);
  ``reference_hole`` no reference point within --hole-radius: the reference has a hole where the mesh has surface;
  ``reference_thin`` the nearest reference point lies where the reference is thin: fewer than half the reference's
                     median count of neighbours within --density-radius (the rims of its coverage, where a scan
                     runs out: a miss there may be the reference's as much as the mesh's);
  ``mesh_off``       the reference is dense nearby, the mesh is off the surface by tau..hole-radius;
* completeness (reference point -> result surface):
  ``mesh_hole``      no result surface within --hole-radius: the mesh has a hole where the reference has surface;
  ``mesh_off``       result surface nearby, off by tau..hole-radius.

Height: along the support plane's normal (``bench_real.support_plane``: a RANSAC plane through the result's
samples the reference does not explain); without one (a mesh whose support was removed), along the normal of
the plane through the camera centres (a ring's axis; ``camera_up``), from the lowest reference point. Slope: angle between the surface normal (result: face normal; reference: its stored normals,
else the nearest result face's) and that up direction (0 = facing up, 90 = vertical, 180 = facing down). Photos:
how many cameras see the point (in the image, facing it, and not hidden by the result mesh).

Prints a table per grouping; --json writes everything; --png a picture: histograms of each grouping (all points
grey, misses coloured by category) and the points from the first camera coloured by category.

    python tools/diagnose_real.py --dataset ../shared/data/walnuts/2016_10_24__17_43_02 --mesh bench_real/walnut1/mesh.ply
        [--tau 0.0005] [--png diag.png] [--json diag.json] [--samples 200000]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import trimesh
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_real import support_plane  # noqa: E402

from photorecon.cameras import project  # noqa: E402
from photorecon.errors import PhotoreconError  # noqa: E402
from photorecon.io.dataset import read_model  # noqa: E402
from photorecon.mesh import load_mesh, raycasting_scene  # noqa: E402
from photorecon.metrics import distance_to, load_reference, sample_surface  # noqa: E402

HEIGHT_BINS_MM = (-np.inf, 0.0, 1.0, 3.0, 6.0, 12.0, 24.0, np.inf)
SLOPE_BINS = (0, 30, 60, 90, 120, 180)
VIEW_BINS = (0, 1, 2, 3, 5, 8, 1000)
ACC_CATS = ("outside_box", "support", "reference_hole", "reference_thin", "mesh_off")
THIN = 0.5  # reference_thin: fewer neighbours than this fraction of the reference's median count
COMP_CATS = ("mesh_hole", "mesh_off")
COLORS = {"ok": (170, 170, 170), "outside_box": (120, 120, 120), "support": (0, 160, 255),
          "reference_hole": (255, 80, 200), "reference_thin": (200, 170, 255), "mesh_off": (0, 0, 230),
          "mesh_hole": (230, 120, 0)}  # BGR


def views_seeing(points: np.ndarray, normals: np.ndarray, views, scene, tol: float) -> np.ndarray:
    """How many ``views`` see each point: inside the image, the surface facing the camera (normals may be 0:
    no test), and no surface of ``scene`` more than ``tol`` in front of it."""
    import open3d as o3d

    count = np.zeros(len(points), np.int32)
    for v in views:
        uv, z = project(points, v.intrinsics, v.cam_from_world)
        W, H = v.intrinsics.size
        with np.errstate(invalid="ignore"):
            ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] <= H - 1)
        d = points - v.center
        dist = np.linalg.norm(d, axis=1)
        facing = np.einsum("nc,nc->n", normals, -d) / np.maximum(dist, 1e-12)
        ok &= (facing > 0.05) | (np.linalg.norm(normals, axis=1) == 0)
        idx = np.flatnonzero(ok)
        if len(idx):
            rays = np.concatenate([np.broadcast_to(v.center, (len(idx), 3)), d[idx]], 1).astype(np.float32)
            t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
            hidden = np.isfinite(t) & ((1 - t) * dist[idx] > tol)
            count[idx[~hidden]] += 1
    return count


def camera_up(views) -> np.ndarray:
    """Up for a ring of cameras: the normal of the plane through their centres, signed so that the cameras'
    mean viewing direction points down (or level)."""
    C = np.array([v.center for v in views])
    up = np.linalg.svd(C - C.mean(0), full_matrices=False)[2][2]
    look = np.mean([v.cam_from_world[2, :3] for v in views], axis=0)
    return -up if up @ look > 0 else up


def reference_normals(path: Path, n_points: int) -> np.ndarray | None:
    try:
        import open3d as o3d

        pc = o3d.io.read_point_cloud(str(path))
        nrm = np.asarray(pc.normals)
        return nrm if len(nrm) == n_points and np.abs(nrm).sum() > 0 else None
    except Exception:  # a reference without normals: the nearest result face's are used
        return None


def _bin_labels(edges, unit=""):
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        if not np.isfinite(lo):
            out.append(f"< {hi:g}{unit}")
        elif not np.isfinite(hi) or hi >= 1000:
            out.append(f">= {lo:g}{unit}")
        else:
            out.append(f"{lo:g}-{hi:g}{unit}")
    return out


def grouped(values: np.ndarray, edges, cats: np.ndarray, names) -> list[dict]:
    """Per bin of ``values``: points, misses (cats != 'ok') and each category's count."""
    rows = []
    which = np.digitize(values, edges[1:-1])
    for b, label in enumerate(_bin_labels(edges)):
        m = which == b
        n = int(m.sum())
        row = {"bin": label, "points": n, "missed": int((cats[m] != "ok").sum())}
        row.update({c: int((cats[m] == c).sum()) for c in names})
        rows.append(row)
    return rows


def reference_density(tree: cKDTree, reference: np.ndarray, radius: float) -> np.ndarray:
    """Each reference point's neighbours within ``radius`` (itself included), over the reference's median count:
    1 where the reference is as dense as usual, towards 0 where its coverage thins out."""
    count = tree.query_ball_point(reference, radius, workers=-1, return_length=True)
    return count / max(float(np.median(count)), 1.0)


def diagnose(mesh: trimesh.Trimesh, reference: np.ndarray, ref_normals: np.ndarray | None, views, tau: float,
             hole_radius: float, support_height: float, crop_margin: float, samples: int,
             density_radius: float | None = None) -> dict:
    pts, nrm = sample_surface(mesh, samples)
    tree = cKDTree(reference)
    d_acc, nearest = tree.query(pts, workers=-1)
    density_radius = density_radius or 3 * tau
    thin = reference_density(tree, reference, density_radius)[nearest] < THIN
    d_comp = distance_to(mesh, reference)
    scene = raycasting_scene(mesh)
    if ref_normals is None:  # the nearest result face's normal
        import open3d as o3d

        closest = scene.compute_closest_points(o3d.core.Tensor(reference.astype(np.float32)))
        ref_normals = np.asarray(mesh.face_normals)[closest["primitive_ids"].numpy()]
    plane = support_plane(mesh, reference)
    if plane is not None:
        up, c0 = plane[0], plane[2]
        support = {"normal": up.round(5).tolist(), "offset": plane[2]}
    else:
        up = camera_up(views)
        c0 = float((reference @ up).min())
        support = None
    h_pts, h_ref = pts @ up - c0, reference @ up - c0
    slope = lambda n: np.degrees(np.arccos(np.clip(n @ up, -1, 1)))  # noqa: E731
    s_pts, s_ref = slope(nrm), slope(ref_normals)
    v_pts = views_seeing(pts + 1e-6 * nrm, nrm, views, scene, 2 * tau)
    v_ref = views_seeing(reference, ref_normals, views, scene, 2 * tau)

    lo, hi = reference.min(0) - crop_margin, reference.max(0) + crop_margin
    outside = ((pts < lo) | (pts > hi)).any(1)
    acc = np.full(len(pts), "ok", object)
    miss = d_acc > tau
    acc[miss & ~outside] = "mesh_off"
    acc[miss & ~outside & thin] = "reference_thin"
    acc[miss & ~outside & (d_acc > hole_radius)] = "reference_hole"
    acc[miss & ~outside & (np.abs(h_pts) < support_height) & (plane is not None)] = "support"
    acc[miss & outside] = "outside_box"
    comp = np.full(len(reference), "ok", object)
    comp[d_comp > tau] = "mesh_off"
    comp[d_comp > hole_radius] = "mesh_hole"

    scored = ~outside
    dense = ~outside & ~thin & (d_acc <= hole_radius)
    out = {"tau": tau, "hole_radius": hole_radius, "density_radius": density_radius,
           "support_height": support_height, "support_plane": support,
           "result_samples": int(len(pts)), "result_samples_scored": int(scored.sum()),
           "reference_points": int(len(reference)),
           "accuracy": float((~miss[scored]).mean()), "completeness": float((d_comp <= tau).mean()),
           "accuracy_where_reference_dense": float((~miss[dense]).mean()) if dense.any() else None,
           "result_samples_where_reference_dense": int(dense.sum()),
           "accuracy_misses": {c: int((acc == c).sum()) for c in ACC_CATS},
           "completeness_misses": {c: int((comp == c).sum()) for c in COMP_CATS}}
    p, r = out["accuracy"], out["completeness"]
    out["fscore"] = 2 * p * r / (p + r) if p + r else 0.0
    out["by_height_mm"] = {"result": grouped(h_pts * 1000, HEIGHT_BINS_MM, acc, ACC_CATS),
                           "reference": grouped(h_ref * 1000, HEIGHT_BINS_MM, comp, COMP_CATS)}
    out["by_slope_deg"] = {"result": grouped(s_pts, SLOPE_BINS, acc, ACC_CATS),
                           "reference": grouped(s_ref, SLOPE_BINS, comp, COMP_CATS)}
    out["by_photos"] = {"result": grouped(v_pts, VIEW_BINS, acc, ACC_CATS),
                        "reference": grouped(v_ref, VIEW_BINS, comp, COMP_CATS)}
    out["_arrays"] = {"pts": pts, "acc": acc, "ref": reference, "comp": comp, "h": (h_pts, h_ref),
                      "slope": (s_pts, s_ref), "views": (v_pts, v_ref)}
    return out


def print_tables(rep: dict) -> None:
    print(f"tau {rep['tau'] * 1000:g} mm: accuracy {rep['accuracy']:.3f}, completeness {rep['completeness']:.3f}, "
          f"F {rep['fscore']:.3f}; hole radius {rep['hole_radius'] * 1000:g} mm; support plane "
          f"{'found' if rep['support_plane'] else 'not found (height from the lowest reference point)'}")
    print("accuracy misses:", ", ".join(f"{k} {v}" for k, v in rep["accuracy_misses"].items()),
          f"(of {rep['result_samples']} result samples)")
    print("completeness misses:", ", ".join(f"{k} {v}" for k, v in rep["completeness_misses"].items()),
          f"(of {rep['reference_points']} reference points)")
    if rep["accuracy_where_reference_dense"] is not None:
        print(f"accuracy where the reference is dense (not reference_thin or reference_hole): "
              f"{rep['accuracy_where_reference_dense']:.3f} over {rep['result_samples_where_reference_dense']} samples")
    for key, title in (("by_height_mm", "height above the support, mm"), ("by_slope_deg", "slope, degrees (0 = up)"),
                       ("by_photos", "photos that saw it")):
        print(f"\n{title}")
        print("| bin | result | acc. miss | " + " | ".join(ACC_CATS) + " | reference | comp. miss | "
              + " | ".join(COMP_CATS) + " |")
        print("|---" * (5 + len(ACC_CATS) + len(COMP_CATS)) + "|")
        for a, c in zip(rep[key]["result"], rep[key]["reference"]):
            fa = a["missed"] / a["points"] if a["points"] else 0.0
            fc = c["missed"] / c["points"] if c["points"] else 0.0
            print(f"| {a['bin']} | {a['points']} | {fa:.3f} | " + " | ".join(str(a[k]) for k in ACC_CATS)
                  + f" | {c['points']} | {fc:.3f} | " + " | ".join(str(c[k]) for k in COMP_CATS) + " |")


def _histogram(canvas, x0, y0, w, h, rows, cats, title):
    """Bars per bin: the bin's points (grey outline, log scale) and its misses stacked by category."""
    cv2.putText(canvas, title, (x0, y0 - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.rectangle(canvas, (x0, y0), (x0 + w, y0 + h), (0, 0, 0), 1)
    top = max(max(r["points"] for r in rows), 1)
    scale = lambda n: h * np.log10(1 + n) / np.log10(1 + top)  # noqa: E731
    bw = w // len(rows)
    for i, r in enumerate(rows):
        bx = x0 + i * bw + 3
        cv2.rectangle(canvas, (bx, int(y0 + h - scale(r["points"]))), (bx + bw - 6, y0 + h), (200, 200, 200), -1)
        y = y0 + h
        missed = r["missed"]
        for c in cats:  # the misses' share of the bin, split by category, on the bin's bar
            if r[c] and missed:
                part = scale(r["points"]) * r[c] / r["points"]
                cv2.rectangle(canvas, (bx, int(y - part)), (bx + bw - 6, int(y)), COLORS[c], -1)
                y -= part
        cv2.putText(canvas, r["bin"], (bx, y0 + h + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.33, (0, 0, 0), 1, cv2.LINE_AA)


def write_png(rep: dict, views, path: Path) -> None:
    a = rep["_arrays"]
    W, Hc = 1500, 900
    canvas = np.full((Hc, W, 3), 255, np.uint8)
    panels = [("by_height_mm", "height, mm"), ("by_slope_deg", "slope, deg"), ("by_photos", "photos")]
    for i, (key, t) in enumerate(panels):
        _histogram(canvas, 30 + i * 300, 40, 270, 160, rep[key]["result"], ACC_CATS, f"result samples by {t}")
        _histogram(canvas, 30 + i * 300, 260, 270, 160, rep[key]["reference"], COMP_CATS, f"reference points by {t}")
    # legend
    for k, (c, col) in enumerate(COLORS.items()):
        cv2.rectangle(canvas, (30, 470 + 18 * k), (42, 482 + 18 * k), col, -1)
        cv2.putText(canvas, c, (48, 481 + 18 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(canvas, f"bar height: points (log); coloured: misses at tau {rep['tau'] * 1000:g} mm by cause",
                (30, 490 + 18 * len(COLORS)), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    # the points from the first camera, cropped to them: result samples (top) and reference points (bottom),
    # misses drawn last
    v = views[0]
    uv_all = project(np.concatenate([a["pts"], a["ref"]]), v.intrinsics, v.cam_from_world)[0]
    uv_all = uv_all[np.isfinite(uv_all).all(1)]
    lo_uv, hi_uv = np.percentile(uv_all, 0.5, axis=0) - 10, np.percentile(uv_all, 99.5, axis=0) + 10
    for j, (P, cats, title) in enumerate(((a["pts"], a["acc"], "result samples"), (a["ref"], a["comp"], "reference"))):
        uv, z = project(P, v.intrinsics, v.cam_from_world)
        uv = uv - lo_uv
        iw, ih = hi_uv - lo_uv
        s = min(560 / iw, 420 / ih)
        box = (930, 20 + 440 * j, int(iw * s), int(ih * s))
        cv2.rectangle(canvas, (box[0], box[1]), (box[0] + box[2], box[1] + box[3]), (0, 0, 0), 1)
        cv2.putText(canvas, f"{title} from {v.name}", (box[0] + 4, box[1] + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (0, 0, 0), 1, cv2.LINE_AA)
        order = np.argsort(cats != "ok", kind="stable")
        for c in np.unique(cats):
            col = COLORS[c]
            m = order[cats[order] == c]
            m = m[np.isfinite(uv[m]).all(1) & (z[m] > 0)]
            x = (box[0] + uv[m, 0] * s).astype(int)
            y = (box[1] + uv[m, 1] * s).astype(int)
            ok = (x > box[0]) & (x < box[0] + box[2]) & (y > box[1]) & (y < box[1] + box[3])
            canvas[y[ok], x[ok]] = col
    cv2.imwrite(str(path), canvas)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", required=True, help="capture folder: sparse/0 (cameras) and reference.ply")
    ap.add_argument("--mesh", required=True, help="the result mesh")
    ap.add_argument("--reference", help="reference cloud (default: DATASET/reference.ply)")
    ap.add_argument("--tau", type=float, default=0.0005, help="miss threshold, scene units (default 0.0005)")
    ap.add_argument("--hole-radius", type=float, default=None, help="no point within this: a hole (default 4 tau)")
    ap.add_argument("--density-radius", type=float, default=None,
                    help="reference density counted within this (default 3 tau): reference_thin below half its median")
    ap.add_argument("--support-height", type=float, default=0.001,
                    help="result misses within this of the support plane count as 'support' (default 0.001)")
    ap.add_argument("--crop-margin", type=float, default=0.005, help="as bench_real (default 0.005)")
    ap.add_argument("--samples", type=int, default=200_000, help="result surface samples (default 200000)")
    ap.add_argument("--json", help="write the report as JSON here")
    ap.add_argument("--png", help="write the picture here")
    args = ap.parse_args()
    root = Path(args.dataset)
    ref_path = Path(args.reference) if args.reference else root / "reference.ply"
    try:
        reference = load_reference(ref_path)
        if isinstance(reference, trimesh.Trimesh):
            reference = np.asarray(reference.vertices)
        mesh = load_mesh(args.mesh)
        sparse = root / "sparse" / "0"
        views = read_model(sparse if sparse.is_dir() else root).views
    except PhotoreconError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    rep = diagnose(mesh, reference, reference_normals(ref_path, len(reference)), views, args.tau,
                   args.hole_radius or 4 * args.tau, args.support_height, args.crop_margin, args.samples,
                   args.density_radius)
    print_tables(rep)
    if args.png:
        write_png(rep, views, Path(args.png))
    if args.json:
        Path(args.json).write_text(json.dumps({k: v for k, v in rep.items() if k != "_arrays"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
