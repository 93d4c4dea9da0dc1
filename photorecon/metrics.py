"""Accuracy metrics against ground truth: meshes (Chamfer, F-score, normal consistency) and depth.

Mesh metrics sample ``n_samples`` points area-uniformly on each mesh with a fixed seed (default 200,000,
seed 0) and measure exact point-to-triangle distances to the other mesh (Open3D ``RaycastingScene``):
accuracy = result -> truth, completeness = truth -> result, Chamfer = their mean;
precision / recall = fraction of those distances below tau; F = 2PR / (P + R).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import trimesh

from .errors import BadArgumentError, EmptyMeshError


@dataclass
class MeshMetrics:
    accuracy_mean: float
    accuracy_median: float
    completeness_mean: float
    completeness_median: float
    chamfer: float
    tau: float
    precision: float
    recall: float
    fscore: float
    precision_half: float  # at tau / 2
    recall_half: float
    fscore_half: float
    normal_consistency: float
    diagonal: float
    n_samples: int

    def as_dict(self) -> dict:
        return asdict(self)


class _Distance:
    def __init__(self, mesh: trimesh.Trimesh):
        import open3d as o3d

        from .mesh import raycasting_scene

        self.scene = raycasting_scene(mesh)
        self.normals = np.asarray(mesh.face_normals)
        self.o3d = o3d

    def query(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance (N,), normal of the closest triangle (N, 3))."""
        ans = self.scene.compute_closest_points(self.o3d.core.Tensor(pts.astype(np.float32)))
        closest = ans["points"].numpy().astype(np.float64)
        return np.linalg.norm(pts - closest, axis=1), self.normals[ans["primitive_ids"].numpy()]


def sample_surface(mesh: trimesh.Trimesh, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    pts, face = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(pts), np.asarray(mesh.face_normals)[face]


def mesh_metrics(result: trimesh.Trimesh, gt: trimesh.Trimesh, tau: float | None = None, n_samples: int = 200_000,
                 seed: int = 0, icp: bool = False) -> MeshMetrics:
    """Compare ``result`` with ground truth ``gt``. ``tau`` defaults to 1% of the truth's bounding-box
    diagonal; the "half" figures use tau / 2 (0.5%). ``icp`` first refines the result onto the truth."""
    for name, m in (("result", result), ("ground truth", gt)):
        if m is None or not len(m.faces):
            raise EmptyMeshError(f"{name} mesh has no triangle: nothing to evaluate")
    diag = float(np.linalg.norm(gt.bounds[1] - gt.bounds[0]))
    tau = 0.01 * diag if tau is None else float(tau)
    if not tau > 0:
        raise BadArgumentError(f"tau: expected > 0, got {tau}")
    if icp:
        result = icp_refine(result, gt, max_dist=2 * tau)
    pr, nr = sample_surface(result, n_samples, seed)
    pg, ng = sample_surface(gt, n_samples, seed + 1)
    d_acc, n_acc = _Distance(gt).query(pr)
    d_comp, n_comp = _Distance(result).query(pg)
    nc = 0.5 * (np.abs(np.einsum("nc,nc->n", nr, n_acc)).mean() + np.abs(np.einsum("nc,nc->n", ng, n_comp)).mean())

    def prf(t):
        p, r = float((d_acc < t).mean()), float((d_comp < t).mean())
        return p, r, (2 * p * r / (p + r) if p + r > 0 else 0.0)

    p, r, f = prf(tau)
    p2, r2, f2 = prf(tau / 2)
    return MeshMetrics(float(d_acc.mean()), float(np.median(d_acc)), float(d_comp.mean()), float(np.median(d_comp)),
                       float(0.5 * (d_acc.mean() + d_comp.mean())), tau, p, r, f, p2, r2, f2, float(nc), diag,
                       n_samples)


def icp_refine(result: trimesh.Trimesh, gt: trimesh.Trimesh, max_dist: float) -> trimesh.Trimesh:
    """Rigidly align ``result`` to ``gt`` with point-to-plane ICP (Open3D) on surface samples."""
    import open3d as o3d

    ps, _ = sample_surface(result, 50_000, 0)
    pg, ng = sample_surface(gt, 50_000, 1)
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(ps))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pg))
    dst.normals = o3d.utility.Vector3dVector(ng)
    reg = o3d.pipelines.registration.registration_icp(
        src, dst, max_dist, np.eye(4), o3d.pipelines.registration.TransformationEstimationPointToPlane())
    out = result.copy()
    out.apply_transform(reg.transformation)
    return out


def error_colors(result: trimesh.Trimesh, gt: trimesh.Trimesh, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex distance to ``gt`` and RGB colours (turbo, 0 -> blue ... >= 2 tau -> red)."""
    import cv2

    d, _ = _Distance(gt).query(np.asarray(result.vertices, np.float64))
    x = (np.clip(d / (2 * tau), 0, 1) * 255).astype(np.uint8)
    rgb = cv2.applyColorMap(x[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
    return d, rgb


def depth_metrics(pred: np.ndarray, gt: np.ndarray, rel_threshold: float = 0.01) -> dict:
    """Depth errors on pixels valid in both: AbsRel, RMSE, fraction within ``rel_threshold`` of the truth,
    and coverage (fraction of true surface pixels with a prediction)."""
    pred, gt = np.asarray(pred, np.float64), np.asarray(gt, np.float64)
    if pred.shape != gt.shape:
        raise BadArgumentError(f"depth metrics: shapes differ, {pred.shape} vs {gt.shape}")
    both = (pred > 0) & (gt > 0) & np.isfinite(pred)
    if not both.any():
        return {"abs_rel": float("nan"), "rmse": float("nan"), "within": 0.0, "coverage": 0.0, "pixels": 0}
    rel = np.abs(pred[both] - gt[both]) / gt[both]
    return {"abs_rel": float(rel.mean()), "rmse": float(np.sqrt(((pred[both] - gt[both]) ** 2).mean())),
            "within": float((rel < rel_threshold).mean()), "coverage": float(both.sum() / max((gt > 0).sum(), 1)),
            "pixels": int(both.sum())}


def doubled_shell_fraction(mesh: trimesh.Trimesh, tau: float, n_samples: int = 50_000, seed: int = 0) -> float:
    """Fraction of surface samples that have *another* sheet of the same mesh within ``tau`` along their
    normal (either side) facing the same way: the overlapping shells that concatenated per-view meshes give.
    A single clean surface scores ~0; a mesh duplicated with a small offset scores ~1."""
    import open3d as o3d

    pts, nrm = sample_surface(mesh, n_samples, seed)
    from .mesh import raycasting_scene

    scene = raycasting_scene(mesh)
    fn = np.asarray(mesh.face_normals)
    eps = 1e-3 * tau
    doubled = np.zeros(len(pts), bool)
    for sign in (1.0, -1.0):
        d = sign * nrm
        rays = np.concatenate([pts + eps * d, d], 1).astype(np.float32)
        ans = scene.cast_rays(o3d.core.Tensor(rays))
        th = ans["t_hit"].numpy()
        hit = np.isfinite(th) & (th < tau)
        ids = ans["primitive_ids"].numpy()
        same = np.zeros(len(pts), bool)
        same[hit] = np.einsum("nc,nc->n", fn[ids[hit]], nrm[hit]) > 0.5
        doubled |= same
    return float(doubled.mean())


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ~ s * R @ src + t`` (Umeyama 1991). Returns (s, R, t)."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise BadArgumentError(f"Sim3 alignment: expected two (N, 3) arrays with N >= 3, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    var = (xs ** 2).sum() / len(src)
    s = float(np.trace(np.diag(D) @ S) / var) if with_scale and var > 0 else 1.0
    return s, R, mu_d - s * R @ mu_s


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
    from pathlib import Path

    from .io.dataset import read_model

    rec_dir, data_dir = Path(rec_dir), Path(data_dir)
    ref = read_model(data_dir / "sparse" / "0").views
    est = read_model(rec_dir / "sparse" / "0").views
    poses = pose_metrics(est, ref)
    s, R, t = align_cameras(est, ref)
    mesh = trimesh.load(rec_dir / "mesh.ply", process=False)
    mesh.vertices = s * np.asarray(mesh.vertices) @ R.T + t
    gt = trimesh.load(data_dir / "gt_mesh.ply", process=False)
    return poses, mesh_metrics(mesh, gt, n_samples=n_samples)
