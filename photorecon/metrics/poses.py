"""Camera poses against reference ones: the Sim3 that aligns cameras of the same name (Umeyama), the rotation and
camera-centre errors after it, a result moved into the truth's frame through its cameras, and a reconstruct
output evaluated against a synthetic dataset."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..errors import BadArgumentError, InputDataError
from ..io.dataset import read_model
from ..layout import Layout
from ..transform import umeyama
from .surfaces import MeshMetrics, mesh_metrics


def _pairs(estimate: list, reference: list) -> list:
    ref = {v.name: v for v in reference}
    pairs = [(e, ref[e.name]) for e in estimate if e.name in ref]
    if len(pairs) < 3:
        raise BadArgumentError(f"pose metrics: {len(pairs)} images in common between estimate and reference; "
                               "need at least 3 (names must match)")
    return pairs

def align_cameras(estimate: list, reference: list) -> tuple[float, np.ndarray, np.ndarray]:
    """Sim3 (s, R, t) taking the estimate's world to the reference's: Umeyama on the camera centres of the
    views (``View`` lists) that share a name. ``X_ref = s * R @ X_est + t``."""
    pairs = _pairs(estimate, reference)
    return umeyama(np.array([e.center for e, _ in pairs]), np.array([r.center for _, r in pairs]))

def pose_metrics(estimate: list, reference: list) -> dict:
    """Compare estimated cameras with reference cameras (``View`` lists, matched by name): Sim3 (Umeyama)
    alignment of the camera centres, then per-image rotation error (degrees) and centre error (absolute,
    in reference units, and relative to the reference cameras' spread = RMS distance of the reference
    centres from their centroid)."""
    pairs = _pairs(estimate, reference)
    ref = {v.name: v for v in reference}
    s, R, t = align_cameras(estimate, reference)
    ce = np.array([e.center for e, _ in pairs])
    cr = np.array([r.center for _, r in pairs])
    c_al = s * ce @ R.T + t
    cerr = np.linalg.norm(c_al - cr, axis=1)
    rerr = []
    for e, r in pairs:
        R_e = e.cam_from_world[:3, :3] @ R.T  # estimated camera rotation, in the reference world
        d = R_e @ r.cam_from_world[:3, :3].T
        rerr.append(np.degrees(np.arccos(np.clip((np.trace(d) - 1) / 2, -1, 1))))
    rerr = np.array(rerr)
    spread = float(np.sqrt(((cr - cr.mean(0)) ** 2).sum(1).mean()))
    return {"registered": len(pairs), "reference_count": len(reference), "estimate_count": len(estimate),
            "missing": sorted(set(ref) - {e.name for e, _ in pairs}),
            "rot_mean_deg": float(rerr.mean()), "rot_median_deg": float(np.median(rerr)), "rot_max_deg": float(rerr.max()),
            "center_mean": float(cerr.mean()), "center_median": float(np.median(cerr)), "center_max": float(cerr.max()),
            "spread": spread, "center_mean_rel": float(cerr.mean() / spread), "center_max_rel": float(cerr.max() / spread),
            "sim3_scale": s, "per_image": {e.name: {"rot_deg": float(a), "center": float(b)}
                                           for (e, _), a, b in zip(pairs, rerr, cerr)}}

def evaluate_reconstruction(rec_dir, data_dir, n_samples: int = 100_000) -> tuple[dict, MeshMetrics]:
    """A ``reconstruct`` output folder against a synthetic dataset: pose metrics, and mesh metrics after
    moving the mesh into the truth's world with the Sim3 that aligns the cameras."""
    rec_layout, ref_layout = Layout(rec_dir), Layout(data_dir)
    ref = read_model(ref_layout.sparse).views
    est = read_model(rec_layout.sparse).views
    poses = pose_metrics(est, ref)
    s, R, t = align_cameras(est, ref)
    mesh = trimesh.load(rec_layout.mesh("ply"), process=False)
    mesh.vertices = s * np.asarray(mesh.vertices) @ R.T + t
    gt = trimesh.load(ref_layout.gt_mesh, process=False)
    return poses, mesh_metrics(mesh, gt, n_samples=n_samples)

def cameras_beside(path: str | Path) -> list | None:
    """The cameras of the result or dataset folder holding the file ``path`` (``sparse/0`` or
    ``transforms.json`` next to a reconstruct output's mesh.ply or a dataset's gt_mesh.ply), or None."""
    layout = Layout(Path(path).resolve().parent)
    for src in (layout.sparse, layout.transforms):
        if src.exists():
            try:
                return read_model(src).views
            except (InputDataError, BadArgumentError):
                return None
    return None

def align_by_cameras(geometry, estimate: list, reference: list):
    """``geometry`` (a ``Trimesh`` or (N, 3) points in the estimate's world) moved into the reference's world
    with the Sim3 that aligns the cameras of the same name (``align_cameras``). Returns (moved geometry, facts:
    shared views, scale, camera-centre RMS after alignment and relative to the reference cameras' spread)."""
    s, R, t = align_cameras(estimate, reference)
    pairs = _pairs(estimate, reference)
    ce = np.array([e.center for e, _ in pairs])
    cr = np.array([r.center for _, r in pairs])
    rms = float(np.sqrt(((s * ce @ R.T + t - cr) ** 2).sum(1).mean()))
    spread = float(np.sqrt(((cr - cr.mean(0)) ** 2).sum(1).mean()))
    if isinstance(geometry, trimesh.Trimesh):
        moved = geometry.copy()
        moved.vertices = s * np.asarray(geometry.vertices) @ R.T + t
    else:
        moved = s * np.asarray(geometry, float) @ R.T + t
    return moved, {"method": "cameras", "views": len(pairs), "scale": float(s), "rotation": R.tolist(),
                   "translation": t.tolist(), "camera_rms": rms, "camera_rms_rel": rms / spread if spread else 0.0}

def frames_differ(result, reference) -> str | None:
    """A reason to think ``result`` and ``reference`` (meshes or points) are in different frames, from their
    bounding boxes (centres apart by more than half the reference's diagonal, or sizes differing more than 3x),
    or None."""
    def box(g):
        p = np.asarray(g.vertices if isinstance(g, trimesh.Trimesh) else g, float)
        return p.min(0), p.max(0)

    (lr, hr), (lg, hg) = box(result), box(reference)
    dr, dg = float(np.linalg.norm(hr - lr)), float(np.linalg.norm(hg - lg))
    gap = float(np.linalg.norm((lr + hr) / 2 - (lg + hg) / 2))
    if dg <= 0:
        return None
    if gap > 0.5 * dg or not 1 / 3 <= dr / dg <= 3:
        return (f"the result's bounding box (diagonal {dr:.4g}, centre {gap:.4g} from the truth's) does not match "
                f"the truth's (diagonal {dg:.4g})")
    return None
