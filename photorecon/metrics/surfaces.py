"""Surface accuracy against ground truth: meshes (Chamfer, F-score, normal consistency) and reference point
clouds (DTU / ETH3D / Tanks-and-Temples style, absolute thresholds).

Mesh metrics sample ``n_samples`` points area-uniformly on each mesh with a fixed seed (default 200,000,
seed 0) and measure exact point-to-triangle distances to the other mesh (Open3D ``RaycastingScene``):
accuracy = result -> truth, completeness = truth -> result, Chamfer = their mean;
precision / recall = fraction of those distances below tau; F = 2PR / (P + R).

Point-cloud metrics (``cloud_metrics``) do the same against a reference point cloud (e.g. a laser scan):
result surface samples -> nearest reference point (KD-tree) and reference point -> result surface (exact,
or nearest result point when the result is itself a point cloud). Result samples far outside the
reference's bounding box (background the reference does not cover) can be left out with ``crop_margin``.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from ..errors import BadArgumentError, EmptyMeshError, InputDataError
from ..mesh.convert import raycasting_scene
from ..mesh.export import check_finite_vertices


@dataclass
class ThresholdScore:
    """Scores at one distance threshold ``tau`` (scene units). ``precision`` is the "accuracy" of DTU / T&T
    (fraction of result samples within tau of the reference), ``recall`` their "completeness" (fraction of
    reference samples within tau of the result), ``fscore`` = 2PR / (P + R)."""

    tau: float
    precision: float
    recall: float
    fscore: float

def _scores(d_acc: np.ndarray, d_comp: np.ndarray, taus: Sequence[float]) -> list[ThresholdScore]:
    out = []
    for t in taus:
        p = float((d_acc < t).mean()) if len(d_acc) else 0.0
        r = float((d_comp < t).mean()) if len(d_comp) else 0.0
        out.append(ThresholdScore(float(t), p, r, 2 * p * r / (p + r) if p + r > 0 else 0.0))
    return out

def check_taus(taus) -> list[float]:
    """Distance thresholds as a list of finite floats > 0 (a single number is accepted)."""
    arr = np.atleast_1d(np.asarray(taus, dtype=float)) if taus is not None else np.zeros(0)
    if arr.ndim != 1 or not len(arr) or not (np.isfinite(arr).all() and (arr > 0).all()):
        raise BadArgumentError(f"tau: expected one or more finite distances > 0, got {taus!r}")
    return [float(t) for t in arr]

def _box_distance(pts: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Euclidean distance of each point (N, 3) to the axis-aligned box [lo, hi] (0 inside)."""
    return np.linalg.norm(np.maximum(np.maximum(lo - pts, pts - hi), 0.0), axis=1)

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
    thresholds: list[ThresholdScore] = field(default_factory=list)  # every requested tau (default tau, tau/2)
    crop_margin: float | None = None
    cropped: int = 0  # result samples left out by crop_margin
    reference: str = "mesh"

    def as_dict(self) -> dict:
        return asdict(self)

@dataclass
class CloudMetrics:
    """A result (mesh or points) against a reference point cloud. Distances in the reference's units."""

    thresholds: list[ThresholdScore]
    accuracy_mean: float  # result samples -> nearest reference point
    accuracy_median: float
    completeness_mean: float  # reference points -> result surface
    completeness_median: float
    chamfer: float
    reference_points: int
    reference_spacing: float  # median nearest-neighbour distance between reference points
    result_samples: int  # result samples evaluated (after cropping)
    crop_margin: float | None
    cropped: int  # result samples left out by crop_margin and crop_plane
    outside_fraction: float  # of all result samples: farther than max(tau) from the reference's bounding box
    reference: str = "points"

    def as_dict(self) -> dict:
        return asdict(self)

    def at(self, tau: float) -> ThresholdScore:
        """The scores at threshold ``tau`` (one of those evaluated)."""
        for s in self.thresholds:
            if np.isclose(s.tau, tau, rtol=1e-9, atol=0):
                return s
        raise BadArgumentError(f"tau {tau} was not evaluated; evaluated: {[s.tau for s in self.thresholds]}")

class _Distance:
    def __init__(self, mesh: trimesh.Trimesh):
        import open3d as o3d

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

def distance_to(target: trimesh.Trimesh | np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Distance (N,) from each point (N, 3) to ``target``: exact point-to-triangle for a mesh, to the
    nearest point (KD-tree) for an (M, 3) point cloud."""
    pts = np.asarray(pts, np.float64)
    if isinstance(target, trimesh.Trimesh):
        return _Distance(target).query(pts)[0]
    from scipy.spatial import cKDTree

    return cKDTree(np.asarray(target, np.float64)).query(pts, workers=-1)[0]

def _as_points(geom, name: str, n_samples: int, seed: int) -> np.ndarray:
    """(N, 3) float64 points of a point array, a face-less Trimesh / PointCloud (its vertices) or a triangle
    mesh (``n_samples`` area-uniform surface samples)."""
    if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
        return sample_surface(geom, n_samples, seed)[0]
    pts = np.asarray(geom.vertices if hasattr(geom, "vertices") else geom, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise BadArgumentError(f"{name}: expected (N, 3) points, got shape {pts.shape}")
    if not len(pts):
        raise EmptyMeshError(f"{name} has no point: nothing to evaluate")
    if not np.isfinite(pts).all():
        raise BadArgumentError(f"{name}: {int((~np.isfinite(pts).all(1)).sum())} points are NaN/inf")
    return pts

def _crop(pts: np.ndarray, lo: np.ndarray, hi: np.ndarray, margin: float | None) -> np.ndarray:
    """Boolean mask of the points to keep: within ``margin`` of the box [lo, hi] (all when margin is None)."""
    if margin is None:
        return np.ones(len(pts), bool)
    if not (np.isfinite(margin) and margin >= 0):
        raise BadArgumentError(f"crop margin: expected a distance >= 0, got {margin}")
    keep = _box_distance(pts, lo, hi) <= margin
    if not keep.any():
        raise EmptyMeshError(f"no result sample lies within {margin:g} of the reference's bounding box "
                             f"{np.round(lo, 6).tolist()} .. {np.round(hi, 6).tolist()}: is the result in the "
                             "reference's frame and units?")
    return keep

def cloud_metrics(result: trimesh.Trimesh | np.ndarray, reference, taus: Sequence[float] | float,
                  n_samples: int = 200_000, seed: int = 0, crop_margin: float | None = None,
                  crop_plane: tuple[np.ndarray, float] | None = None) -> CloudMetrics:
    """Compare ``result`` (a triangle mesh, or (N, 3) points) with a reference point cloud ((M, 3) points
    or a face-less ``Trimesh`` / ``PointCloud``; a triangle mesh is sampled), DTU / T&T style.

    ``taus``: absolute distance thresholds in the reference's units (e.g. metres), one or several. A mesh
    result is sampled with ``n_samples`` area-uniform points (seed ``seed``); a point result is used as is.
    Accuracy distances go from result samples to the nearest reference point, so they are inflated by up
    to about the reference's point spacing (reported as ``reference_spacing``): use taus above it.

    ``crop_margin``: leave out result samples farther than this from the reference's axis-aligned bounding
    box (background the reference does not cover), as the T&T evaluation crops to its region. Only the
    accuracy side is cropped: completeness always measures reference points against the whole result.
    Without cropping, ``outside_fraction`` tells how much of the result lies beyond max(tau) outside the
    box (every such sample counts as inaccurate at every tau).

    ``crop_plane`` (unit normal n (3,), offset c): also leave out of accuracy the result samples with
    n . x < c, as DTU's evaluation leaves out the table under its objects (its per-scan plane); the reference
    points below it are left out of completeness."""
    taus = check_taus(taus)
    if isinstance(result, trimesh.Trimesh) and not len(result.faces):
        result = np.asarray(result.vertices, np.float64)
    ref = _as_points(reference, "reference", n_samples, seed + 1)
    res_pts = _as_points(result, "result", n_samples, seed)
    lo, hi = ref.min(0), ref.max(0)
    outside = float((_box_distance(res_pts, lo, hi) > max(taus)).mean())
    keep = _crop(res_pts, lo, hi, crop_margin)
    if crop_plane is not None:
        n, c = np.asarray(crop_plane[0], np.float64), float(crop_plane[1])
        if n.shape != (3,) or not np.isfinite(n).all() or abs(np.linalg.norm(n) - 1) > 1e-6 or not np.isfinite(c):
            raise BadArgumentError(f"crop plane: expected a unit normal (3,) and a finite offset, got {n}, {c}")
        keep &= res_pts @ n >= c
        ref = ref[ref @ n >= c]
        if not keep.any() or not len(ref):
            raise EmptyMeshError("no result sample or no reference point lies above the crop plane")
    from scipy.spatial import cKDTree

    tree = cKDTree(ref)
    d_acc = tree.query(res_pts[keep], workers=-1)[0]
    d_comp = distance_to(result if isinstance(result, trimesh.Trimesh) else res_pts, ref)
    sub = ref[np.random.default_rng(seed).choice(len(ref), min(len(ref), 20_000), replace=False)]
    spacing = float(np.median(tree.query(sub, k=2, workers=-1)[0][:, 1])) if len(ref) > 1 else 0.0
    return CloudMetrics(_scores(d_acc, d_comp, taus), float(d_acc.mean()), float(np.median(d_acc)),
                        float(d_comp.mean()), float(np.median(d_comp)), float(0.5 * (d_acc.mean() + d_comp.mean())),
                        len(ref), spacing, int(keep.sum()), None if crop_margin is None else float(crop_margin),
                        int((~keep).sum()), outside)

def load_reference(path: str | Path) -> trimesh.Trimesh | np.ndarray:
    """A ground truth file: a triangle mesh (``Trimesh``) or, for a file with vertices and no faces (e.g. a
    PLY point cloud such as a laser scan), its (N, 3) float64 points. Raises ``InputDataError`` naming the
    file when it is missing, unreadable, empty or holds non-finite coordinates."""
    path = Path(path)
    if not path.is_file():
        raise InputDataError(f"{path}: no such mesh or point-cloud file")
    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        why = (str(exc).strip().splitlines() or [""])[0]
        raise InputDataError(f"{path}: cannot read mesh or point cloud ({type(exc).__name__}: {why})") from None
    geoms = loaded.dump() if isinstance(loaded, trimesh.Scene) else [loaded]
    meshes = [g for g in geoms if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    if meshes:
        mesh = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
        check_finite_vertices(mesh.vertices, path)
        return mesh
    parts = [np.asarray(g.vertices, np.float64).reshape(-1, 3) for g in geoms if hasattr(g, "vertices")]
    pts = np.concatenate(parts) if parts else np.zeros((0, 3))
    if not len(pts):
        raise InputDataError(f"{path}: no faces and no points: an empty mesh or point cloud")
    check_finite_vertices(pts, path, "points")
    return pts

def mesh_metrics(result: trimesh.Trimesh, gt: trimesh.Trimesh, tau: float | None = None, n_samples: int = 200_000,
                 seed: int = 0, icp: bool = False, taus: Sequence[float] | None = None,
                 crop_margin: float | None = None) -> MeshMetrics:
    """Compare ``result`` with ground truth ``gt``. ``tau`` defaults to 1% of the truth's bounding-box
    diagonal; the "half" figures use tau / 2 (0.5%). ``taus`` adds scores at other thresholds to
    ``thresholds`` (default: tau and tau / 2). ``crop_margin`` leaves out result samples farther than this
    from the truth's bounding box (as in ``cloud_metrics``). ``icp`` first refines the result onto the truth."""
    for name, m in (("result", result), ("ground truth", gt)):
        if m is None or not len(m.faces):
            raise EmptyMeshError(f"{name} mesh has no triangle: nothing to evaluate")
    diag = float(np.linalg.norm(gt.bounds[1] - gt.bounds[0]))
    tau = check_taus(0.01 * diag if tau is None else tau)[0]
    taus = check_taus(taus) if taus is not None else [tau, tau / 2]
    if icp:
        result = icp_refine(result, gt, max_dist=2 * tau)
    pr, nr = sample_surface(result, n_samples, seed)
    keep = _crop(pr, gt.bounds[0], gt.bounds[1], crop_margin)
    pr, nr = pr[keep], nr[keep]
    pg, ng = sample_surface(gt, n_samples, seed + 1)
    d_acc, n_acc = _Distance(gt).query(pr)
    d_comp, n_comp = _Distance(result).query(pg)
    nc = 0.5 * (np.abs(np.einsum("nc,nc->n", nr, n_acc)).mean() + np.abs(np.einsum("nc,nc->n", ng, n_comp)).mean())
    s1, s2 = _scores(d_acc, d_comp, [tau, tau / 2])
    return MeshMetrics(float(d_acc.mean()), float(np.median(d_acc)), float(d_comp.mean()), float(np.median(d_comp)),
                       float(0.5 * (d_acc.mean() + d_comp.mean())), tau, s1.precision, s1.recall, s1.fscore,
                       s2.precision, s2.recall, s2.fscore, float(nc), diag, n_samples,
                       _scores(d_acc, d_comp, taus), None if crop_margin is None else float(crop_margin),
                       int((~keep).sum()))

def seen_split_metrics(result: trimesh.Trimesh, gt: trimesh.Trimesh, observed: np.ndarray, radius: float,
                       tau: float | None = None, n_samples: int = 100_000, seed: int = 0) -> dict:
    """Precision, recall and F-score at ``tau`` (default 1% of the truth's diagonal) split by what the cameras
    saw: ``observed`` (N, 3) are the depth maps' points; a sample of either surface within ``radius`` of one is
    *seen*, else *unseen*. Returns ``seen`` (precision of the result's seen part, recall of the truth's seen
    part, their F-score: how well the observed surface is reconstructed) and ``unseen`` (the same for the
    parts no camera saw: how good the guess is), each with the ``share`` of the area it covers."""
    from scipy.spatial import cKDTree

    diag = float(np.linalg.norm(gt.bounds[1] - gt.bounds[0]))
    tau = check_taus(0.01 * diag if tau is None else tau)[0]
    pr, _ = sample_surface(result, n_samples, seed)
    pg, _ = sample_surface(gt, n_samples, seed + 1)
    d_acc, _ = _Distance(gt).query(pr)
    d_comp, _ = _Distance(result).query(pg)
    tree = cKDTree(np.asarray(observed, np.float64))
    seen_r = np.isfinite(tree.query(pr, k=1, distance_upper_bound=radius)[0])
    seen_g = np.isfinite(tree.query(pg, k=1, distance_upper_bound=radius)[0])
    out = {"tau": tau, "radius": float(radius)}
    for key, mr, mg in (("seen", seen_r, seen_g), ("unseen", ~seen_r, ~seen_g)):
        s = _scores(d_acc[mr], d_comp[mg], [tau])[0]
        out[key] = {"precision": s.precision, "recall": s.recall, "fscore": s.fscore,
                    "share_result": float(mr.mean()), "share_truth": float(mg.mean())}
    return out

def icp_refine(result, gt, max_dist: float):
    """Rigidly align ``result`` to ``gt`` with point-to-plane ICP (Open3D) on surface samples. Either may be
    a triangle mesh or (N, 3) points (a point target gets normals estimated from 20 neighbours); returns
    ``result`` moved, of the same kind."""
    import open3d as o3d

    def cloud(geom, seed):
        if isinstance(geom, trimesh.Trimesh):
            pts, nrm = sample_surface(geom, 50_000, seed)
        else:
            pts = np.asarray(geom, np.float64)
            pts, nrm = pts[np.random.default_rng(seed).choice(len(pts), min(len(pts), 50_000), replace=False)], None
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        if nrm is not None:
            pc.normals = o3d.utility.Vector3dVector(nrm)
        return pc

    src, dst = cloud(result, 0), cloud(gt, 1)
    if not dst.has_normals():
        dst.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
    reg = o3d.pipelines.registration.registration_icp(
        src, dst, max_dist, np.eye(4), o3d.pipelines.registration.TransformationEstimationPointToPlane())
    T = np.asarray(reg.transformation)
    if not isinstance(result, trimesh.Trimesh):
        return np.asarray(result, np.float64) @ T[:3, :3].T + T[:3, 3]
    out = result.copy()
    out.apply_transform(T)
    return out

def error_colors(result: trimesh.Trimesh, gt, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex distance to ``gt`` (a mesh, or (M, 3) reference points) and RGB colours (turbo, 0 -> blue
    ... >= 2 tau -> red)."""
    import cv2

    d = distance_to(gt, np.asarray(result.vertices, np.float64))
    x = (np.clip(d / (2 * tau), 0, 1) * 255).astype(np.uint8)
    rgb = cv2.applyColorMap(x[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
    return d, rgb

def doubled_shell_fraction(mesh: trimesh.Trimesh, tau: float, n_samples: int = 50_000, seed: int = 0) -> float:
    """Fraction of surface samples that have *another* sheet of the same mesh within ``tau`` along their
    normal (either side) facing the same way: the overlapping shells that concatenated per-view meshes give.
    A single clean surface scores ~0; a mesh duplicated with a small offset scores ~1."""
    import open3d as o3d

    pts, nrm = sample_surface(mesh, n_samples, seed)

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
