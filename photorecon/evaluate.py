"""``photorecon eval``'s work: a result mesh (or point cloud) against ground truth, estimated cameras against
reference ones. ``evaluate(EvalRequest(...))`` returns the report (a JSON-ready dict: ``mesh``, ``poses``,
``alignment``, ``warnings``) and writes the error-coloured mesh when asked; ``format_report`` is its text.

A result with cameras beside it (a reconstruct output's sparse/0) is first moved into the truth's frame through
the cameras (``align_to_truth``); without, a result whose bounding box does not match the truth's, or that lies
far from it everywhere (``FAR_FROM_TRUTH``), gets a warning.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from .errors import BadArgumentError

log = logging.getLogger("photorecon")

# a warning when, without an alignment, the result's median distance to the truth is above this fraction of the
# truth's diagonal (a reconstruction in the truth's frame: well under 1%; one in SfM's frame: 5-50%)
FAR_FROM_TRUTH = 0.05


@dataclass
class EvalRequest:
    """What to evaluate (the options of ``photorecon eval``): ``mesh`` against ``gt`` (a mesh, or a point cloud:
    a PLY with vertices and no faces), and/or the cameras ``poses`` against ``ref``."""

    mesh: str | None = None
    gt: str | None = None
    tau: list[float] | None = None  # distance thresholds, scene units (default: 1% and 0.5% of gt's diagonal)
    crop_to_reference: float | None = None  # ignore result samples farther than this from gt's bounding box
    icp: bool = False  # refine the result onto the truth with ICP first
    align_poses: bool | None = None  # align through the cameras (None: when both sides have cameras)
    poses: str | None = None  # estimated cameras (COLMAP folder or transforms.json)
    ref: str | None = None  # reference cameras
    error_mesh: str | None = None  # write the result coloured by error here (PLY, and a PNG beside it)
    quiet_json: bool = False  # the report goes to stdout as JSON: say a warning on stderr too


def evaluate(req: EvalRequest) -> dict:
    """The report of ``req`` (see the module docstring); ``BadArgumentError`` for a request that names only one
    side of a comparison, or none."""
    report: dict = {}
    if req.mesh or req.gt:
        if not (req.mesh and req.gt):
            raise BadArgumentError("eval: --mesh and --gt go together")
        _evaluate_mesh(req, report)
    if req.poses or req.ref:
        if not (req.poses and req.ref):
            raise BadArgumentError("eval: --poses and --ref go together")
        from .io.dataset import read_model
        from .metrics import pose_metrics

        report["poses"] = pose_metrics(read_model(req.poses).views, read_model(req.ref).views)
    if not report:
        raise BadArgumentError("eval: give --mesh and --gt, and/or --poses and --ref")
    return report


def _evaluate_mesh(req: EvalRequest, report: dict) -> None:
    import numpy as np
    import trimesh

    from .mesh import export
    from .metrics import cloud_metrics, error_colors, icp_refine, load_reference, mesh_metrics
    from .report.preview import render_preview

    if req.crop_to_reference is not None and not req.crop_to_reference >= 0:
        raise BadArgumentError(f"--crop-to-reference: expected a margin >= 0, got {req.crop_to_reference}")
    gt = load_reference(req.gt)
    result = load_reference(req.mesh)
    result, alignment, warning = align_to_truth(result, gt, req)
    if alignment:
        report["alignment"] = alignment
    gt_pts = np.asarray(gt.vertices) if isinstance(gt, trimesh.Trimesh) else gt
    diag = float(np.linalg.norm(gt_pts.max(0) - gt_pts.min(0)))
    taus = req.tau or [0.01 * diag, 0.005 * diag]
    if isinstance(gt, trimesh.Trimesh) and isinstance(result, trimesh.Trimesh):
        m = mesh_metrics(result, gt, taus[0], icp=req.icp, taus=req.tau, crop_margin=req.crop_to_reference)
    else:
        if req.icp:
            result = icp_refine(result, gt, max_dist=2 * max(taus))
        m = cloud_metrics(result, gt, taus, crop_margin=req.crop_to_reference)
    report["mesh"] = m.as_dict()
    if not alignment and not warning and m.accuracy_median > FAR_FROM_TRUTH * diag:
        warning = (f"the result lies far from the truth everywhere (median distance {m.accuracy_median:.4g}, "
                   f"{100 * m.accuracy_median / diag:.1f}% of the truth's diagonal): are they in the same "
                   f"frame? {_align_hint(req)}")
    if warning:
        report["warnings"] = [warning]
        if req.quiet_json:  # the JSON on stdout carries it; say it on stderr too
            log.warning("warning: %s", warning)
    if req.error_mesh:
        if not isinstance(result, trimesh.Trimesh):
            raise BadArgumentError(f"--error-mesh: {req.mesh} is a point cloud, not a mesh to colour")
        _, rgb = error_colors(result, gt, taus[0])
        colored = result.copy()
        colored.visual.vertex_colors = np.c_[rgb, np.full(len(rgb), 255)]
        export(colored, req.error_mesh)
        render_preview(colored, Path(req.error_mesh).with_suffix(".png"))


def align_to_truth(result, gt, req):
    """(the result in the truth's frame, the alignment's facts or None, a warning or None). ``req``: an
    ``EvalRequest`` (or any object with its ``mesh``, ``gt``, ``poses``, ``ref`` and ``align_poses``). Cameras
    on both sides (``poses`` / ``ref``, else beside the files) align the result unless ``align_poses`` is
    False; without, a result whose bounding box does not match the truth's gets a warning."""
    from .io.dataset import read_model
    from .metrics import align_by_cameras, cameras_beside, frames_differ

    if req.align_poses is not False:
        est = read_model(req.poses).views if req.poses else cameras_beside(req.mesh)
        ref = read_model(req.ref).views if req.ref else cameras_beside(req.gt)
        shared = len({v.name for v in est or ()} & {v.name for v in ref or ()})
        if est and ref and shared >= 3:
            moved, facts = align_by_cameras(result, est, ref)
            return moved, facts, None
        if req.align_poses:
            found = ("no cameras beside " + (req.mesh if not est else req.gt) if not (est and ref)
                     else f"{shared} image names in common")
            raise BadArgumentError(f"--align-poses: needs the cameras of both sides with at least 3 image names in "
                                   f"common (--poses and --ref, or sparse/0 or transforms.json beside each file); "
                                   f"found {found}")
    why = frames_differ(result, gt)
    if why is None:
        return result, None, None
    return result, None, f"{why}: are they in the same frame? {_align_hint(req)}"


def _align_hint(req) -> str:
    return ("--align-poses aligns them through their cameras" if req.align_poses is False else
            "give the cameras of both (--poses and --ref) to align them, or --icp for a small offset")


def _threshold_lines(rows: list[dict]) -> list[str]:
    lines = [f"  {'tau':>10}  {'accuracy':>9}  {'completeness':>12}  {'F-score':>8}   (fractions within tau)"]
    for t in rows:
        lines.append(f"  {t['tau']:>10.4g}  {t['precision']:>9.4f}  {t['recall']:>12.4f}  {t['fscore']:>8.4f}")
    return lines


def format_report(report: dict) -> str:
    """``evaluate``'s report as the text ``photorecon eval`` prints (without ``--json -``)."""
    out: list[str] = []
    a = report.get("alignment")
    if a:
        out.append(f"aligned through the cameras: {a['views']} shared views, scale {a['scale']:.6g}, camera centres "
                   f"within {a['camera_rms']:.4g} RMS ({100 * a['camera_rms_rel']:.3f}% of their spread)")
    for w in report.get("warnings", []):
        out.append(f"warning: {w}")
    if report.get("mesh", {}).get("reference") == "points":
        m = report["mesh"]
        crop = (f", {m['cropped']} left out beyond {m['crop_margin']:.4g} of its bounding box"
                if m["crop_margin"] is not None else "")
        out.append(f"result vs reference point cloud ({m['reference_points']} points, spacing "
                   f"{m['reference_spacing']:.4g}; {m['result_samples']} result samples{crop})")
        out.append(f"  accuracy     mean {m['accuracy_mean']:.4g}  median {m['accuracy_median']:.4g}  "
                   "(result -> reference)")
        out.append(f"  completeness mean {m['completeness_mean']:.4g}  median {m['completeness_median']:.4g}  "
                   "(reference -> result)")
        out.append(f"  chamfer      {m['chamfer']:.4g}")
        out += _threshold_lines(m["thresholds"])
        if m["crop_margin"] is None and m["outside_fraction"] > 0.01:
            out.append(f"  note: {100 * m['outside_fraction']:.1f}% of the result lies beyond the largest tau outside "
                       "the reference's bounding box (background?) and counts as inaccurate; --crop-to-reference "
                       "MARGIN leaves it out")
        if min(t["tau"] for t in m["thresholds"]) < m["reference_spacing"]:
            out.append("  note: a tau below the reference's point spacing understates accuracy (distances go to the "
                       "nearest reference point)")
    elif "mesh" in report:
        m = report["mesh"]
        d = m["diagonal"]
        out.append(f"mesh vs ground truth (diagonal {d:.4g}, tau {m['tau']:.4g})")
        out.append(f"  accuracy     mean {m['accuracy_mean']:.4g}  median {m['accuracy_median']:.4g}")
        out.append(f"  completeness mean {m['completeness_mean']:.4g}  median {m['completeness_median']:.4g}")
        out.append(f"  chamfer      {m['chamfer']:.4g}  ({100 * m['chamfer'] / d:.3f}% of diagonal)")
        out.append(f"  at tau       precision {m['precision']:.4f}  recall {m['recall']:.4f}  F {m['fscore']:.4f}")
        out.append(f"  at tau/2     precision {m['precision_half']:.4f}  recall {m['recall_half']:.4f}  "
                   f"F {m['fscore_half']:.4f}")
        if len(m["thresholds"]) > 2 or m["thresholds"][0]["tau"] != m["tau"]:
            out += _threshold_lines(m["thresholds"])
        if m["crop_margin"] is not None:
            out.append(f"  cropped      {m['cropped']} result samples beyond {m['crop_margin']:.4g} of the truth's "
                       "bounding box")
        out.append(f"  normal consistency {m['normal_consistency']:.4f}")
    if "poses" in report:
        p = report["poses"]
        out.append(f"poses: {p['registered']} of {p['reference_count']} reference images matched")
        out.append(f"  rotation error (deg)  mean {p['rot_mean_deg']:.4g}  median {p['rot_median_deg']:.4g}  "
                   f"max {p['rot_max_deg']:.4g}")
        out.append(f"  centre error          mean {p['center_mean']:.4g}  median {p['center_median']:.4g}  "
                   f"max {p['center_max']:.4g}  ({100 * p['center_mean_rel']:.4f}% of spread)")
    return "\n".join(out)
