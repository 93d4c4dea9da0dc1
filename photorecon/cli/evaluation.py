"""``photorecon eval``'s text output: the result aligned to the reference, the tables of distances and
thresholds.
"""
from __future__ import annotations


def _align_for_eval(result, gt, args):
    """``eval --mesh``: (the result in the truth's frame, the alignment's facts or None, a warning or None).
    Cameras on both sides (--poses/--ref, else beside the files) align the result unless --no-align-poses;
    without, a result whose bounding box does not match the truth's gets a warning."""
    from ..errors import BadArgumentError
    from ..io.dataset import read_model
    from ..metrics import align_by_cameras, cameras_beside, frames_differ

    if args.align_poses is not False:
        est = read_model(args.poses).views if args.poses else cameras_beside(args.mesh)
        ref = read_model(args.ref).views if args.ref else cameras_beside(args.gt)
        shared = len({v.name for v in est or ()} & {v.name for v in ref or ()})
        if est and ref and shared >= 3:
            moved, facts = align_by_cameras(result, est, ref)
            return moved, facts, None
        if args.align_poses:
            found = ("no cameras beside " + (args.mesh if not est else args.gt) if not (est and ref)
                     else f"{shared} image names in common")
            raise BadArgumentError(f"--align-poses: needs the cameras of both sides with at least 3 image names in "
                                   f"common (--poses and --ref, or sparse/0 or transforms.json beside each file); "
                                   f"found {found}")
    why = frames_differ(result, gt)
    if why is None:
        return result, None, None
    hint = ("--align-poses aligns them through their cameras" if args.align_poses is False else
            "give the cameras of both (--poses and --ref) to align them, or --icp for a small offset")
    return result, None, f"{why}: are they in the same frame? {hint}"


def _print_thresholds(rows: list[dict]) -> None:
    print(f"  {'tau':>10}  {'accuracy':>9}  {'completeness':>12}  {'F-score':>8}   (fractions within tau)")
    for t in rows:
        print(f"  {t['tau']:>10.4g}  {t['precision']:>9.4f}  {t['recall']:>12.4f}  {t['fscore']:>8.4f}")


def _print_report(report: dict) -> None:
    a = report.get("alignment")
    if a:
        print(f"aligned through the cameras: {a['views']} shared views, scale {a['scale']:.6g}, camera centres "
              f"within {a['camera_rms']:.4g} RMS ({100 * a['camera_rms_rel']:.3f}% of their spread)")
    for w in report.get("warnings", []):
        print(f"warning: {w}")
    if report.get("mesh", {}).get("reference") == "points":
        m = report["mesh"]
        crop = (f", {m['cropped']} left out beyond {m['crop_margin']:.4g} of its bounding box"
                if m["crop_margin"] is not None else "")
        print(f"result vs reference point cloud ({m['reference_points']} points, spacing {m['reference_spacing']:.4g}; "
              f"{m['result_samples']} result samples{crop})")
        print(f"  accuracy     mean {m['accuracy_mean']:.4g}  median {m['accuracy_median']:.4g}  (result -> reference)")
        print(f"  completeness mean {m['completeness_mean']:.4g}  median {m['completeness_median']:.4g}  (reference -> result)")
        print(f"  chamfer      {m['chamfer']:.4g}")
        _print_thresholds(m["thresholds"])
        if m["crop_margin"] is None and m["outside_fraction"] > 0.01:
            print(f"  note: {100 * m['outside_fraction']:.1f}% of the result lies beyond the largest tau outside the "
                  "reference's bounding box (background?) and counts as inaccurate; --crop-to-reference MARGIN "
                  "leaves it out")
        if min(t["tau"] for t in m["thresholds"]) < m["reference_spacing"]:
            print("  note: a tau below the reference's point spacing understates accuracy (distances go to the "
                  "nearest reference point)")
    elif "mesh" in report:
        m = report["mesh"]
        d = m["diagonal"]
        print(f"mesh vs ground truth (diagonal {d:.4g}, tau {m['tau']:.4g})")
        print(f"  accuracy     mean {m['accuracy_mean']:.4g}  median {m['accuracy_median']:.4g}")
        print(f"  completeness mean {m['completeness_mean']:.4g}  median {m['completeness_median']:.4g}")
        print(f"  chamfer      {m['chamfer']:.4g}  ({100 * m['chamfer'] / d:.3f}% of diagonal)")
        print(f"  at tau       precision {m['precision']:.4f}  recall {m['recall']:.4f}  F {m['fscore']:.4f}")
        print(f"  at tau/2     precision {m['precision_half']:.4f}  recall {m['recall_half']:.4f}  F {m['fscore_half']:.4f}")
        if len(m["thresholds"]) > 2 or m["thresholds"][0]["tau"] != m["tau"]:
            _print_thresholds(m["thresholds"])
        if m["crop_margin"] is not None:
            print(f"  cropped      {m['cropped']} result samples beyond {m['crop_margin']:.4g} of the truth's bounding box")
        print(f"  normal consistency {m['normal_consistency']:.4f}")
    if "poses" in report:
        p = report["poses"]
        print(f"poses: {p['registered']} of {p['reference_count']} reference images matched")
        print(f"  rotation error (deg)  mean {p['rot_mean_deg']:.4g}  median {p['rot_median_deg']:.4g}  max {p['rot_max_deg']:.4g}")
        print(f"  centre error          mean {p['center_mean']:.4g}  median {p['center_median']:.4g}  max {p['center_max']:.4g}"
              f"  ({100 * p['center_mean_rel']:.4f}% of spread)")
