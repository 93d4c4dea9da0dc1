#!/usr/bin/env python
"""Where a synthetic scene's F-score is lost: a `reconstruct` (or `fuse`) output against its synthetic dataset.

Splits the truth samples that the mesh misses (farther than tau = 1% of the diagonal) into
* hidden: seen by fewer than 2 cameras (the rendered depth maps): no depth can reach them (the ceiling);
* depth lost: seen, but no depth point of OUT/depth (back-projected) lies within tau of them;
* fusion lost: some depth point lies within tau, yet the mesh does not (TSDF, cleaning);
and the mesh samples farther than tau / 2 and tau from the truth (precision). The mesh is Sim3-aligned through
the cameras as in `tools/bench.py`. Writes an error picture (orthographic top / front / side views of the truth
samples not reached and of the mesh samples off the truth) with --png.

    python tools/diagnose_synth.py DATA OUT [--mesh OUT/mesh.ply] [--png err.png] [--json d.json]
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

from photorecon.cameras import backproject_depth, project
from photorecon.io.dataset import read_model
from photorecon.layout import Layout
from photorecon.metrics import _Distance, align_cameras, sample_surface


def seen_count(pts: np.ndarray, views, depth_dir: Path, tol: float) -> np.ndarray:
    """How many cameras see each point: its projection's rendered depth within ``tol`` of its own."""
    n = np.zeros(len(pts), int)
    for v in views:
        gd = np.load(depth_dir / f"{v.name}.npy")
        uv, z = project(pts, v.intrinsics, v.cam_from_world)
        with np.errstate(invalid="ignore"):
            ij = np.round(np.nan_to_num(uv, nan=-1)).astype(int)
        ok = (z > 0) & (ij[:, 0] >= 0) & (ij[:, 0] < gd.shape[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < gd.shape[0])
        g = np.zeros(len(pts))
        g[ok] = gd[ij[ok, 1], ij[ok, 0]]
        n += ok & (g > 0) & (np.abs(g - z) < tol)
    return n


def depth_points(views, depth_dir: Path, s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Every depth map of ``depth_dir`` back-projected (at its own resolution), moved into the truth's world."""
    pts = []
    for v in views:
        p = depth_dir / f"{v.name}.npy"
        if not p.is_file():
            continue
        d = np.load(p)
        intr = v.intrinsics if d.shape == (v.intrinsics.height, v.intrinsics.width) else v.intrinsics.scaled(d.shape[1], d.shape[0])
        P = backproject_depth(np.where(d > 0, d, 0), intr, v.cam_from_world)  # the valid pixels only
        pts.append(s * P @ R.T + t)
    return np.concatenate(pts) if pts else np.zeros((0, 3))


def picture(path: Path, pg, miss_cls, pr, d_acc, tau) -> None:
    lo, hi = pg.min(0) - 0.05, pg.max(0) + 0.05
    S = 360

    def panel(P, colors, i, j, title):
        img = np.full((S + 30, S, 3), 255, np.uint8)
        sc = S / max(hi[i] - lo[i], hi[j] - lo[j])
        u = ((P[:, i] - lo[i]) * sc).astype(int)
        v = (S - (P[:, j] - lo[j]) * sc).astype(int) + 30
        ok = (u >= 0) & (u < S) & (v >= 30) & (v < S + 30)
        for layer in range(4):
            m = ok & (colors[:, 3] == layer)
            img[v[m], u[m]] = colors[m, :3]
        cv2.putText(img, title, (4, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1)
        return img

    cg = np.tile([210, 210, 210, 0], (len(pg), 1))
    cg[miss_cls == 1] = (0, 140, 255, 1)  # hidden: orange
    cg[miss_cls == 2] = (0, 0, 255, 2)  # depth lost: red
    cg[miss_cls == 3] = (255, 0, 160, 3)  # fusion lost: purple
    far, mid = d_acc >= tau, (d_acc >= tau / 2) & (d_acc < tau)
    cr = np.tile([210, 210, 210, 0], (len(pr), 1))
    cr[mid] = (0, 200, 255, 1)
    cr[far] = (0, 0, 255, 2)
    rows = [np.concatenate([panel(P, C, 0, 1, f"{what}: top"), panel(P, C, 0, 2, f"{what}: front x-z"),
                            panel(P, C, 1, 2, f"{what}: side y-z")], 1)
            for P, C, what in ((pg, cg, "truth not reached"), (pr, cr, "mesh off the truth"))]
    img = np.concatenate(rows + [np.full((24, rows[0].shape[1], 3), 255, np.uint8)], 0)
    cv2.putText(img, "truth: orange hidden, red depth lost, purple fusion lost | mesh: yellow 0.5-1%, red > 1% of the diagonal",
                (4, img.shape[0] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1)
    cv2.imwrite(str(path), img)


def diagnose(data: Path, rec: Path, mesh_path: Path | None = None, n: int = 100_000, png: Path | None = None) -> dict:
    ref = read_model(Layout(data).sparse).views
    est_layout = Layout(rec)
    est = read_model(est_layout.sparse).views if est_layout.sparse.is_dir() else ref
    s, R, t = align_cameras(est, ref)
    mesh = trimesh.load(mesh_path or est_layout.mesh("ply"), process=False)
    mesh.vertices = s * np.asarray(mesh.vertices) @ R.T + t
    gt = trimesh.load(Layout(data).gt_mesh, process=False)
    diag = float(np.linalg.norm(gt.bounds[1] - gt.bounds[0]))
    tau = 0.01 * diag
    pr, _ = sample_surface(mesh, n, 0)
    pg, _ = sample_surface(gt, n, 1)
    d_acc, _ = _Distance(gt).query(pr)
    d_comp, _ = _Distance(mesh).query(pg)
    seen = seen_count(pg, ref, Layout(data).depth, 0.003 * diag) >= 2
    depth_dir = rec / "depth"
    dp = depth_points(est, depth_dir, s, R, t) if depth_dir.is_dir() else np.zeros((0, 3))
    dd = cKDTree(dp).query(pg, workers=-1)[0] if len(dp) else np.full(len(pg), np.inf)
    miss = d_comp >= tau
    cls = np.zeros(len(pg), int)
    cls[miss & ~seen] = 1
    cls[miss & seen & (dd >= tau)] = 2
    cls[miss & (dd < tau) & (cls == 0)] = 3
    P, Rc = float((d_acc < tau).mean()), float((d_comp < tau).mean())
    out = {"tau": tau, "precision": P, "recall": Rc, "fscore": 2 * P * Rc / (P + Rc) if P + Rc else 0.0,
           "truth_seen_by_2_views": float(seen.mean()), "recall_of_seen_truth": float((~miss[seen]).mean()),
           "missed_hidden": float((cls == 1).mean()), "missed_depth_lost": float((cls == 2).mean()),
           "missed_fusion_lost": float((cls == 3).mean()),
           "mesh_off_half_tau": float(((d_acc >= tau / 2) & (d_acc < tau)).mean()),
           "mesh_off_tau": float((d_acc >= tau).mean())}
    if png:
        picture(png, pg, cls, pr, d_acc, tau)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", help="the synthetic dataset (photorecon synth)")
    ap.add_argument("out", help="the reconstruct (or fuse) output: OUT/mesh.ply, OUT/depth, OUT/sparse/0")
    ap.add_argument("--mesh", help="another mesh than OUT/mesh.ply (in OUT's frame)")
    ap.add_argument("--png", help="write the error picture here")
    ap.add_argument("--json", help="write the numbers here")
    args = ap.parse_args()
    r = diagnose(Path(args.data), Path(args.out), Path(args.mesh) if args.mesh else None,
                 png=Path(args.png) if args.png else None)
    for k, v in r.items():
        print(f"{k:24} {v:.4f}")
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
