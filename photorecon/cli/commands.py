"""Sub-command definitions: arguments come from the stage configs; the work is in the stage modules."""
from __future__ import annotations

import argparse
import logging
from contextlib import contextmanager

from .config import Ranged, add_config_arguments, command, config_from_args
from .options import COMMON_OPTIONS, QUALITY_PRESETS, SHORT_HELP, _BASIC, _apply_quality, _quality_arg

log = logging.getLogger("photorecon")


OVERWRITE_HELP = ("write into a non-empty folder this command did not write: its files are added next to what is "
                  "there, which is kept (never replaced)")
OVERWRITE_FILE_HELP = "replace an existing output file (never an input, never part of a photorecon result)"


def _out_args(p: argparse.ArgumentParser, required: bool = True) -> None:
    p.add_argument("-o", "--out", required=required, help="output folder")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


def _cluster_args(p: argparse.ArgumentParser) -> None:
    from ..distributed import ClusterConfig

    add_config_arguments(p.add_argument_group("cluster (Dask)"), ClusterConfig)


def _masks_arg(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--masks", metavar="DIR", help=f"mask folder: NAME.png or COLMAP's NAME.EXT.png (e.g. IMG_1.jpg.png) "
                                                  f"at the image's size, 0 = ignore the pixel; {what}")


@command
def synth(sub):
    from ..synthetic import SynthConfig

    p = sub.add_parser("synth", help="render a mesh or built-in scene to images, depth, masks and cameras",
                       description="Render a synthetic dataset with ground truth (see the README for the layout).")
    _out_args(p)
    add_config_arguments(p, SynthConfig)
    p.set_defaults(func=_run_synth)


def _run_synth(args):
    from ..synthetic import SynthConfig, synthesize

    cfg = config_from_args(SynthConfig, args)
    res = synthesize(cfg, args.out, overwrite=args.overwrite)
    print(f"synth: {len(res.views)} views, {res.seconds_per_view:.3f} s/view -> {res.root}")
    return 0


@command
def fuse(sub):
    from ..fusion import FusionConfig
    from ..mesh import CleanConfig

    p = sub.add_parser("fuse", help="fuse a dataset's depth maps into one mesh (TSDF or grid)",
                       description="Fuse DATASET/depth/*.npy (synth layout, cameras from sparse/0 or "
                                   "transforms.json) into OUT/mesh.ply with a preview.png.")
    p.add_argument("dataset", help="dataset folder (synth layout)")
    _out_args(p)
    p.add_argument("--depth-dir", help="depth maps folder (default: DATASET/depth)")
    _masks_arg(p, "default: DATASET/masks, else the images' alpha channel")
    p.add_argument("--formats", default="ply", help="comma-separated mesh formats: ply,obj,glb (default: ply)")
    add_config_arguments(p, FusionConfig)
    add_config_arguments(p, CleanConfig)
    _cluster_args(p)
    p.set_common(COMMON_OPTIONS["fuse"], SHORT_HELP)
    p.set_defaults(func=_run_fuse)


def _run_fuse(args):
    from ..fusion import FusionConfig, fuse_dataset
    from ..mesh import CleanConfig, parse_formats

    formats = parse_formats(args.formats)
    from ..distributed import ClusterConfig

    path = fuse_dataset(args.dataset, args.out, config_from_args(FusionConfig, args),
                        config_from_args(CleanConfig, args), args.depth_dir, args.overwrite, formats,
                        masks_dir=args.masks, cluster=config_from_args(ClusterConfig, args))
    print(f"fuse: mesh written to {path}")
    return 0


@command
def eval_cmd(sub):
    p = sub.add_parser("eval", help="evaluate a mesh against ground truth (or poses against a reference)",
                       description="Mesh: accuracy, completeness, Chamfer, precision/recall/F-score at each tau "
                                   "(default 1%% and 0.5%% of the truth's diagonal), normal consistency; "
                                   f"{200_000} area-uniform samples per mesh, seed 0. A --gt with vertices and no "
                                   "faces is a reference point cloud (DTU / ETH3D / Tanks-and-Temples style): per "
                                   "tau, accuracy = fraction of result samples within tau of a reference point, "
                                   "completeness = fraction of reference points within tau of the result, F-score. "
                                   "A result with cameras beside it (a reconstruct output's sparse/0) is first moved "
                                   "into the truth's frame through the cameras (see --align-poses).")
    p.add_argument("--mesh", help="result mesh (or point cloud, against a point-cloud --gt)")
    p.add_argument("--gt", help="ground truth: a mesh, or a point cloud (PLY with vertices and no faces)")
    p.add_argument("--tau", type=Ranged(float, 0.0, None, exclusive_min=True, sep=True), metavar="T[,T...]",
                   help="distance thresholds in scene units, e.g. 0.0005,0.001,0.002 (default: 1%%,0.5%% of the "
                        "GT's bounding-box diagonal); with a mesh GT the first is the headline tau")
    p.add_argument("--crop-to-reference", type=Ranged(float, 0.0, None), metavar="MARGIN",
                   help="ignore result samples farther than MARGIN (scene units) from the GT's bounding box: "
                        "background the reference does not cover; completeness is unaffected")
    p.add_argument("--icp", action="store_true", help="refine the result onto the truth with ICP first")
    p.add_argument("--align-poses", action=argparse.BooleanOptionalAction, default=None,
                   help="move the result into the truth's frame with the similarity that aligns its cameras to the "
                        "truth's (same image names; cameras from --poses/--ref, else sparse/0 or transforms.json "
                        "beside each file); default: when both sides have cameras")
    p.add_argument("--poses", help="estimated cameras: COLMAP folder or transforms.json")
    p.add_argument("--ref", help="reference cameras: COLMAP folder or transforms.json")
    p.add_argument("--json", dest="json_out", nargs="?", const="-", help="print JSON (or write it to a file)")
    p.add_argument("--error-mesh", help="write the result coloured by error to this PLY (and a PNG next to it)")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    p.set_defaults(func=_run_eval)


def _run_eval(args):
    import json
    from pathlib import Path

    import numpy as np

    from ..errors import BadArgumentError
    from ..io.atomic import atomic_write_text
    from ..io.output import check_file_output

    report = {}
    inputs = (args.mesh, args.gt, args.poses, args.ref)
    written = [("--json", args.json_out)]
    if args.error_mesh:  # the coloured mesh and its picture
        written += [("--error-mesh", args.error_mesh), ("--error-mesh", Path(args.error_mesh).with_suffix(".png"))]
    for flag, dst in written:
        check_file_output(dst, args.overwrite, inputs, flag)
    if args.mesh or args.gt:
        if not (args.mesh and args.gt):
            raise BadArgumentError("eval: --mesh and --gt go together")
        import trimesh

        from ..mesh import export
        from ..metrics import cloud_metrics, error_colors, icp_refine, load_reference, mesh_metrics
        from ..report.preview import render_preview

        if args.crop_to_reference is not None and not args.crop_to_reference >= 0:
            raise BadArgumentError(f"--crop-to-reference: expected a margin >= 0, got {args.crop_to_reference}")
        gt = load_reference(args.gt)
        result = load_reference(args.mesh)
        result, alignment, warning = _align_for_eval(result, gt, args)
        if alignment:
            report["alignment"] = alignment
        gt_pts = np.asarray(gt.vertices) if isinstance(gt, trimesh.Trimesh) else gt
        diag = float(np.linalg.norm(gt_pts.max(0) - gt_pts.min(0)))
        taus = args.tau or [0.01 * diag, 0.005 * diag]
        if isinstance(gt, trimesh.Trimesh) and isinstance(result, trimesh.Trimesh):
            m = mesh_metrics(result, gt, taus[0], icp=args.icp, taus=args.tau, crop_margin=args.crop_to_reference)
        else:
            if args.icp:
                result = icp_refine(result, gt, max_dist=2 * max(taus))
            m = cloud_metrics(result, gt, taus, crop_margin=args.crop_to_reference)
        report["mesh"] = m.as_dict()
        if not alignment and not warning and m.accuracy_median > FAR_FROM_TRUTH * diag:
            warning = (f"the result lies far from the truth everywhere (median distance {m.accuracy_median:.4g}, "
                       f"{100 * m.accuracy_median / diag:.1f}% of the truth's diagonal): are they in the same "
                       f"frame? {_align_hint(args)}")
        if warning:
            report["warnings"] = [warning]
            if args.json_out == "-":  # the JSON on stdout carries it; say it on stderr too
                import logging

                logging.getLogger("photorecon").warning("warning: %s", warning)
        if args.error_mesh:
            if not isinstance(result, trimesh.Trimesh):
                raise BadArgumentError(f"--error-mesh: {args.mesh} is a point cloud, not a mesh to colour")
            _, rgb = error_colors(result, gt, taus[0])
            colored = result.copy()
            colored.visual.vertex_colors = np.c_[rgb, np.full(len(rgb), 255)]
            export(colored, args.error_mesh)
            render_preview(colored, Path(args.error_mesh).with_suffix(".png"))
    if args.poses or args.ref:
        if not (args.poses and args.ref):
            raise BadArgumentError("eval: --poses and --ref go together")
        from ..io.dataset import read_model
        from ..metrics import pose_metrics

        report["poses"] = pose_metrics(read_model(args.poses).views, read_model(args.ref).views)
    if not report:
        raise BadArgumentError("eval: give --mesh and --gt, and/or --poses and --ref")
    if args.json_out:
        text = json.dumps(report, indent=2)
        if args.json_out == "-":
            print(text)
        else:
            atomic_write_text(args.json_out, text + "\n")
    if args.json_out != "-":
        _print_report(report)
    return 0


def _align_for_eval(result, gt, args):
    """``eval --mesh``: (the result in the truth's frame, the alignment's facts or None, a warning or None).
    Cameras on both sides (--poses/--ref, else beside the files) align the result unless --no-align-poses;
    without, a result whose bounding box does not match the truth's gets a warning (and, once measured, one
    that lies far from the truth everywhere: ``FAR_FROM_TRUTH``)."""
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
    return result, None, f"{why}: are they in the same frame? {_align_hint(args)}"


# eval warns when, without an alignment, the result's median distance to the truth is above this fraction of the
# truth's diagonal (a reconstruction in the truth's frame: well under 1%; one in SfM's frame: 5-50%)
FAR_FROM_TRUTH = 0.05


def _align_hint(args) -> str:
    return ("--align-poses aligns them through their cameras" if args.align_poses is False else
            "give the cameras of both (--poses and --ref) to align them, or --icp for a small offset")


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


@command
def sfm(sub):
    from ..poses.scale import ScaleConfig
    from ..poses.sfm import SfMConfig

    p = sub.add_parser("sfm", help="camera poses for an image folder (COLMAP SfM via pycolmap)",
                       description="Structure from motion: writes OUT/images (undistorted), OUT/sparse/0 "
                                   "(COLMAP text) and OUT/transforms.json; stages are cached in OUT/colmap.")
    p.add_argument("images", help="image folder or video file (never written to)")
    _out_args(p)
    p.add_argument("--force", action="store_true", help="recompute every stage instead of reusing cached ones")
    _masks_arg(p, "no features there (the images' alpha channel counts too); undistorted into OUT/masks")
    _quality_arg(p, ("sfm",))
    add_config_arguments(p, SfMConfig)
    add_config_arguments(p.add_argument_group("metric scale"), ScaleConfig)
    p.set_common(COMMON_OPTIONS["sfm"], SHORT_HELP)
    p.set_defaults(func=_run_sfm)


def _run_sfm(args):
    from pathlib import Path

    from ..io.output import output_folder
    from ..poses.scale import ScaleConfig, scale_output
    from ..poses.sfm import SfMConfig, check_sfm_masks, run_sfm

    _apply_quality(args)
    cfg = config_from_args(SfMConfig, args)
    scale_cfg = config_from_args(ScaleConfig, args)  # a bad --marker-size fails before anything is written
    if not Path(args.images).exists():  # before the output folder is made
        from ..errors import NoImagesError

        raise NoImagesError(f"{args.images}: no such image folder (or video file)")
    if args.masks:
        check_sfm_masks(args.images, args.masks)  # before anything is written
    with output_folder(args.out, args.overwrite, inputs=(args.images, args.masks, cfg.intrinsics),
                       command="sfm") as out:
        res = run_sfm(args.images, out, cfg, force=args.force, masks=args.masks)
        units = scale_output(out, args.images if Path(args.images).is_dir() else None, scale_cfg)["units"]
    n = len(res.registered) + len(res.unregistered)
    print(f"sfm: {len(res.registered)} of {n} images registered, {len(res.model.points)} sparse points -> "
          f"{out}/sparse/0, {out}/transforms.json (units: {units})"
          + (f" (reused: {', '.join(res.cached)})" if res.cached else ""))
    return 0


@command
def convert(sub):
    p = sub.add_parser("convert", help="convert cameras between COLMAP, transforms.json, NeRF Blender, NeuS, LLFF "
                                       "and PyTorch3D",
                       description="SRC: COLMAP folder (text or binary), dataset folder, transforms.json or "
                                   "transforms_SPLIT.json (NeRF Blender), cameras_sphere.npz (IDR/NeuS, images in "
                                   "image/ beside it), poses_bounds.npy (LLFF, images in images/ beside it). "
                                   "DST: a folder (COLMAP), a .json file (transforms.json; NeRF Blender when named "
                                   "transforms_train|val|test.json; PyTorch3D with --to pytorch3d), a .npz (NeuS) "
                                   "or a .npy (LLFF). NeuS and LLFF pair camera i with the i-th sorted image.")
    p.add_argument("src")
    p.add_argument("dst")
    from ..io.convert import formats

    p.add_argument("--to", choices=formats(), default="auto",  # the camera format registry, io.cameras
                   help="output format (default: from DST: folder -> colmap-text, .json -> transforms or blender, "
                        ".npz -> neus, .npy -> llff)")
    p.add_argument("--world", choices=["none", "nerfstudio", "instant-ngp"], default="none",
                   help="transforms.json world orientation to write (default: none = photorecon's world)")
    p.add_argument("--src-world", choices=["none", "nerfstudio", "instant-ngp"], default=None,
                   help="world orientation of a transforms.json SRC (default: as recorded in the file)")
    p.add_argument("--neus-world", choices=["normalized", "original"], default="normalized",
                   help="world of a NeuS SRC: normalized (world_mat @ scale_mat, the unit-sphere frame NeuS trains "
                        "in; default) or original (world_mat alone)")
    p.add_argument("--bounds", nargs=2, type=Ranged(float, 0.0, None, exclusive_min=True), metavar=("NEAR", "FAR"),
                   help="LLFF output: near and far depth for every image (default: from the sparse points)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing DST file; a DST folder: " + OVERWRITE_HELP)
    p.set_defaults(func=_run_convert)


def _run_convert(args):
    from ..io.convert import convert_cameras, writes_folder
    from ..io.output import check_file_output, output_folder

    def write():
        return convert_cameras(args.src, args.dst, args.to, args.world, args.src_world, args.neus_world,
                               tuple(args.bounds) if args.bounds else None)

    from pathlib import Path

    if writes_folder(args.to, Path(args.dst)):  # a COLMAP folder
        with output_folder(args.dst, args.overwrite, inputs=(args.src,), command="convert", resumable=False):
            dst = write()
    else:
        check_file_output(args.dst, args.overwrite, (args.src,), "DST", may_hold=(args.src,))  # a new file in SRC
        dst = write()
    print(f"convert: {args.src} -> {dst}")
    return 0


@command
def mvs(sub):
    from ..depth.mvs import MVSConfig

    p = _depth_parser(sub, "mvs", MVSConfig, _run_mvs,
                      help="dense depth by multi-view stereo on the CPU (no weights, no GPU)",
                      description="PatchMatch stereo (or --mvs sweep: a plane sweep) from the dataset's cameras "
                                  "(sparse/0 or transforms.json) and sparse points; writes depth/NAME.npy, "
                                  "NAME.conf.npy, NAME.normal.npy and NAME.png to DATASET/depth (or -o DIR).")
    _masks_arg(p, "no depth there (default: DATASET/masks, else the images' alpha channel)")
    _quality_arg(p, ("mvs",))
    p.set_common(COMMON_OPTIONS["mvs"], SHORT_HELP)


def _depth_parser(sub, name: str, cfg_type, func, help: str, description: str,
                  dataset_help: str = "dataset folder (images/ + sparse/0 or transforms.json)"):
    """A depth command's parser: DATASET, -o, the config's flags and the cluster flags."""
    p = sub.add_parser(name, help=help, description=description)
    p.add_argument("dataset", help=dataset_help)
    p.add_argument("-o", "--out", help="depth output folder (default: DATASET/depth, when it is new or this "
                                        "command's own)")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    add_config_arguments(p, cfg_type)
    _cluster_args(p)
    p.set_defaults(func=func)
    return p


def _run_depth_tasks(args, run, cfg_type, *extra, masks=None):
    """Open the dataset, run ``run(ds, *extra, out, cfg, executor)`` on the chosen cluster (or in process)."""
    from ..distributed import ClusterConfig, executor
    from ..io.dataset import Dataset

    cfg = config_from_args(cfg_type, args)  # a bad or contradictory setting: refused before anything is read
    cluster = config_from_args(ClusterConfig, args)
    ds = Dataset.open(args.dataset, masks_dir=masks)
    names = [n for v in ds.views for n in (f"{v.name}.npy", f"{v.name}.conf.npy", f"{v.name}.normal.npy",
                                           f"{v.name}.png")]
    with _dataset_output(ds, args.out, "depth", args.command, names + [".mvs_work", ".mono_work"],
                         args.overwrite, extra[:1]) as out:
        log.info("%s: depth maps go to %s", args.command, out)
        with executor(cluster) as ex:
            return ds, run(ds, *extra, out, cfg, ex)


@contextmanager
def _dataset_output(ds, out, default: str, command: str, names, overwrite: bool, extra_inputs=()):
    """The output folder of a command that writes into a dataset (DATASET/``default``) or into ``out`` (-o),
    through the output guard (``io.output``): ``names`` are the files it writes there. Its inputs are the
    dataset's images, masks and cameras (``extra_inputs`` too); while it runs the dataset is locked as well
    when the output lies in it."""
    from contextlib import ExitStack
    from pathlib import Path

    from ..io.output import output_folder, output_lock

    root = Path(ds.root)
    out = Path(out) if out else root / default
    inputs = {Path(ds.image_path(v)).parent for v in ds.views} | {root, root / "sparse", root / "transforms.json"}
    if ds.masks_dir is not None:
        inputs.add(Path(ds.masks_dir))
    inputs = (*sorted(inputs), *extra_inputs)
    with ExitStack() as stack:
        folder = stack.enter_context(output_folder(out, overwrite, inputs, tuple(names), command, may_hold=(root,),
                                                   resumable=False))
        if folder.resolve().is_relative_to(root.resolve()):
            stack.enter_context(output_lock(root))
        yield folder


def _run_mvs(args):
    from ..depth.mvs import MVSConfig, run_mvs

    _apply_quality(args)
    ds, rep = _run_depth_tasks(args, run_mvs, MVSConfig, masks=args.masks)
    where = args.out or f"{args.dataset}/depth"
    print(f"mvs: depth for {rep.views} of {len(ds.views)} views ({rep.seconds_per_view:.2f} s/view) -> {where}")
    return 0


def _add_stage_args(p):
    from ..pipeline import StageConfigs

    d = StageConfigs()  # the pipeline's own defaults (e.g. a wider TSDF truncation for MVS depth)
    for title, cfg in (("pipeline", d.run), ("structure from motion", d.sfm), ("multi-view stereo", d.mvs),
                       ("fusion", d.fusion), ("cleaning", d.clean), ("refinement", d.refine), ("metric scale", d.scale),
                       ("texture (with --texture)", d.texture), ("cluster (Dask)", d.cluster)):
        add_config_arguments(p.add_argument_group(title), type(cfg), defaults=cfg)


@command
def reconstruct(sub):
    p = sub.add_parser("reconstruct", help="image folder -> poses, depth and one fused mesh",
                       description="Ingest -> poses (SfM, or --poses) -> undistort -> depth (MVS, --depth-model, or "
                                   "--depth DIR) -> fusion (TSDF or grid) -> cleaning -> export, preview and report. "
                                   "A re-run resumes from the last complete stage.")
    p.add_argument("images", help="image folder or video file (never written to)")
    _out_args(p)
    p.add_argument("--force", action="store_true", help="recompute every stage")
    _quality_arg(p, ("sfm", "mvs", "fusion", "clean"))
    _add_stage_args(p)
    p.set_common(COMMON_OPTIONS["reconstruct"], SHORT_HELP)
    p.set_defaults(func=_run_reconstruct)


def _run_reconstruct(args):
    from ..depth.mvs import MVSConfig
    from ..fusion import FusionConfig
    from ..mesh import CleanConfig
    from ..distributed import ClusterConfig
    from ..pipeline import ReconstructConfig, StageConfigs, reconstruct as run
    from ..poses.scale import ScaleConfig
    from ..poses.sfm import SfMConfig
    from ..mesh.refine import RefineConfig
    from ..mesh.texture import TextureConfig

    _apply_quality(args)
    cfgs = StageConfigs(config_from_args(ReconstructConfig, args), config_from_args(SfMConfig, args),
                        config_from_args(MVSConfig, args), config_from_args(FusionConfig, args),
                        config_from_args(CleanConfig, args), config_from_args(ScaleConfig, args),
                        config_from_args(TextureConfig, args), config_from_args(ClusterConfig, args),
                        config_from_args(RefineConfig, args))
    rep = run(args.images, args.out, cfgs, force=args.force, overwrite=args.overwrite)
    p, d, m = rep.poses, rep.depth, rep.mesh
    print(f"reconstruct: {p.get('registered')} images registered, {d.get('views')} depth maps ({d.get('source')}), "
          f"mesh {m.get('vertices')} vertices / {m.get('faces')} faces")
    print(f"  files: {args.out}/mesh.ply, preview.png, report.html, report.json")
    if rep.texture:
        t = rep.texture
        print(f"  textured: {t['faces']} faces, {t['atlas_size']}x{t['atlas_size']} atlas -> {args.out}/textured/"
              "mesh.obj (+ mesh.mtl, texture.png), mesh.glb")
    if rep.warnings:
        print(f"  {len(rep.warnings)} warning(s); see report.json")
    return 0


@command
def demo(sub):
    from ..demo import DemoConfig

    p = sub.add_parser("demo", help="the built-in demo: synthesize a scene, reconstruct it, measure it",
                       description="Renders a textured scene, reconstructs it from its images alone (SfM + MVS + "
                                   "TSDF) and prints accuracy against the ground truth. --scene bunny: the original "
                                   "article's experiment (the Stanford bunny from a ring of cameras, rendered depth, "
                                   "meshed three ways side by side).")
    p.add_argument("-o", "--out", default="photorecon_demo", help="output folder (default: ./photorecon_demo)")
    p.add_argument("--overwrite", action="store_true", help="allow a non-empty folder not made by photorecon")
    add_config_arguments(p, DemoConfig)
    p.set_defaults(func=_run_demo)


def _run_demo(args):
    from pathlib import Path

    from ..demo import DemoConfig, print_bunny_summary, print_summary, run_bunny_demo, run_demo

    cfg = config_from_args(DemoConfig, args)
    if cfg.scene == "bunny":
        print_bunny_summary(run_bunny_demo(args.out, cfg, overwrite=args.overwrite), Path(args.out))
        return 0
    s = run_demo(args.out, cfg, overwrite=args.overwrite)
    print_summary(s, Path(args.out))
    return 0


@command
def depth(sub):
    from ..depth.mono import MonoConfig

    p = _depth_parser(sub, "depth", MonoConfig, _run_depth,
                      help="monocular depth from an ONNX model (MiDaS-style), aligned to the SfM points",
                      description="Runs a user-supplied ONNX depth model (no weights ship, nothing is downloaded) "
                                  "and aligns each prediction to the dataset's sparse points; writes "
                                  "DATASET/depth/NAME.npy + NAME.png (or -o DIR).",
                      dataset_help="dataset folder (images/ + sparse/0 with points)")
    p.add_argument("--model", required=True, help="ONNX model file")


def _run_depth(args):
    from ..depth.mono import MonoConfig, run_mono

    ds, rep = _run_depth_tasks(args, run_mono, MonoConfig, args.model)
    print(f"depth: {rep.views} of {len(ds.views)} views aligned ({rep.inference_ms_per_image:.0f} ms inference, "
          f"{rep.alignment_ms_per_image:.1f} ms alignment per image) -> {args.out or args.dataset + '/depth'}")
    if rep.excluded:
        print("  excluded: " + ", ".join(f"{k} ({v})" for k, v in rep.excluded.items()))
    return 0


@command
def view(sub):
    from ..report import VIEW_MAX_FACES

    p = sub.add_parser("view", help="look at a result: the mesh and the cameras in a browser (served on localhost)",
                       description="Serves an interactive 3D view of a result (the mesh, the cameras as frusta with "
                                   "their images) with viser on http://HOST:PORT until Ctrl-C; or, with --html FILE, "
                                   "writes a standalone viewer page (one file, no server, no network) and exits.")
    p.add_argument("result", help="result folder (OUT of 'reconstruct' or 'fuse') or a mesh file (never written to)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default: 127.0.0.1, this machine only)")
    p.add_argument("--port", type=Ranged(int, 0, 65535), default=8080, help="port (default: 8080; 0 = any free port)")
    p.add_argument("--max-faces", type=Ranged(int, 4, 2_000_000_000), default=None,
                   help=f"decimate larger meshes to this many faces (default: {VIEW_MAX_FACES:,} served, "
                        "200,000 for --html)")
    p.add_argument("--lighting", choices=("environment", "plain"), default="environment",
                   help="environment: soft image-based light from all sides (default); plain: directional "
                        "lights only, quick to draw in a browser without a GPU")
    p.add_argument("--html", metavar="FILE", help="write a standalone viewer page to FILE instead of serving")
    p.add_argument("--overwrite", action="store_true", help="--html: " + OVERWRITE_FILE_HELP)
    p.set_defaults(func=_run_view)


def _run_view(args):
    import time

    from ..errors import BadArgumentError
    from ..report import (VIEW_MAX_FACES, VIEWER_MAX_FACES, load_result, start_viewer_server, stop_viewer_server,
                         write_viewer_page)

    if args.max_faces is not None and args.max_faces < 4:
        raise BadArgumentError(f"--max-faces: expected >= 4, got {args.max_faces}")
    if not 0 <= args.port <= 65535:
        raise BadArgumentError(f"--port: expected 0-65535, got {args.port}")
    if args.html:
        from ..io.output import check_file_output

        check_file_output(args.html, args.overwrite, (args.result,), "--html")
    mesh, cameras, images = load_result(args.result)
    if args.html:
        path = write_viewer_page(args.html, mesh, cameras, title=f"photorecon: {args.result}",
                                 max_faces=args.max_faces or VIEWER_MAX_FACES)
        print(f"view: {len(mesh.faces):,} faces, {len(cameras)} cameras -> {path} (open it in a browser)")
        return 0
    try:
        server = start_viewer_server(mesh, cameras, images, args.host, args.port, args.max_faces or VIEW_MAX_FACES,
                                     args.lighting)
    except OSError as exc:
        raise BadArgumentError(f"--host {args.host} --port {args.port}: cannot serve there ({exc})") from None
    host = server.get_host()
    print(f"view: {len(mesh.faces):,} faces, {len(cameras)} cameras at http://{host}:{server.get_port()} "
          "(Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    finally:
        stop_viewer_server(server)


@command
def texture(sub):
    from ..mesh.texture import TextureConfig

    p = sub.add_parser("texture", help="bake a UV-textured mesh from the photos of a reconstruct output",
                       description="Textures OUT/mesh.ply (or --mesh) from OUT/images with the cameras in OUT/sparse/0 "
                                   "or OUT/transforms.json: one photo per face (visible, seen head-on, sharpest), "
                                   "exposure evened out between photos, one atlas PNG. Writes OUT/textured/mesh.obj + "
                                   "mesh.mtl + texture.png, mesh.glb (texture embedded) and preview.png (or -o DIR).")
    p.add_argument("dataset", metavar="OUT", help="a reconstruct output (or any dataset folder with images and cameras)")
    p.add_argument("--mesh", help="mesh to texture (default: OUT/mesh.ply)")
    p.add_argument("-o", "--out", help="output folder (default: OUT/textured)")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)
    p.add_argument("--target-faces", dest="texture_faces", type=Ranged(int, 4, 2_000_000_000, also=(0,)),
                   default=TextureConfig.texture_faces,
                   help="simplify the mesh to about this many faces first (0 = keep; default: 0)")
    add_config_arguments(p, TextureConfig, skip=("texture_faces",))
    p.set_defaults(func=_run_texture)


def _run_texture(args):
    from pathlib import Path

    from ..mesh.texture import TextureConfig, texture_output

    cfg = config_from_args(TextureConfig, args, texture_faces=args.texture_faces)  # --target-faces: skipped above
    from ..io.dataset import Dataset
    from ..layout import COMMAND_WRITES

    ds = Dataset.open(args.dataset)
    mesh = Path(args.mesh) if args.mesh else Path(args.dataset) / "mesh.ply"
    with _dataset_output(ds, args.out, "textured", "texture", COMMAND_WRITES["texture"], args.overwrite,
                         (mesh,)) as dest:
        info = texture_output(args.dataset, cfg, args.mesh, dest)
    print(f"texture: {info['faces']} faces, {info['charts']} charts from {info['views_used']} views, "
          f"{info['texels_per_pixel']:.2f} texels per photo pixel -> {info['folder']}/mesh.obj (+ mesh.mtl, "
          "texture.png), mesh.glb, preview.png")
    return 0


@command
def warmup(sub):
    p = sub.add_parser("warmup", help="compile the numba kernels once, into numba's cache (tools/install.sh runs it)",
                       description="Compiles every compiled kernel (PatchMatch, TSDF) on a tiny synthetic scene, so "
                                   "numba's cache holds them (the __pycache__ folders next to the package's modules, "
                                   "or NUMBA_CACHE_DIR) and later runs load them instead of compiling them.")
    p.set_defaults(func=_run_warmup)


def _run_warmup(args):
    from ..warmup import warm_up

    r = warm_up()
    how = (f"{len(r['compiled'])} compiled, {len(r['cached'])} already in numba's cache" if r["compiled"]
           else "all already in numba's cache")
    print(f"warmup: {r['kernels']} kernels ({how}) in {r['seconds']:.1f} s")
    if r["missing"]:
        print("  not reached (compiled on first use instead): " + ", ".join(r["missing"]))
    return 0
