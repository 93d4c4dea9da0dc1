"""The stage commands (reconstruct, sfm, mvs, depth, fuse, texture): each parser is built from the stage configs,
each ``_run_*`` turns the arguments into configs and calls the stage; the work is in the stage modules. The
other commands are in ``tool_commands``."""
from __future__ import annotations

import argparse
import logging
from contextlib import contextmanager

from .config import Ranged, add_config_arguments, command, config_from_args
from .options import COMMON_OPTIONS, OVERWRITE_HELP, SHORT_HELP, _apply_quality, _out_args, _quality_arg

log = logging.getLogger("photorecon")


def _cluster_args(p: argparse.ArgumentParser) -> None:
    from ..distributed import ClusterConfig

    add_config_arguments(p.add_argument_group("cluster (Dask)"), ClusterConfig)


def _masks_arg(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--masks", metavar="DIR", help=f"mask folder: NAME.png or COLMAP's NAME.EXT.png (e.g. IMG_1.jpg.png) "
                                                  f"at the image's size, 0 = ignore the pixel; {what}")


def _add_stage_args(p):
    from ..pipeline import StageConfigs

    d = StageConfigs()  # the pipeline's own defaults (e.g. a wider TSDF truncation for MVS depth)
    for title, cfg in (("pipeline", d.run), ("structure from motion", d.sfm), ("multi-view stereo", d.mvs),
                       ("fusion", d.fusion), ("cleaning", d.clean), ("refinement", d.refine), ("metric scale", d.scale),
                       ("textured model (OUT/model.glb; --texture off: none)", d.model),
                       ("texturing of the model", d.texture), ("cluster (Dask)", d.cluster)):
        # the model's face budget and atlas size are --model-faces and --max-atlas (their former names:
        # aliases of those); photorecon texture has --target-faces and --atlas-size
        add_config_arguments(p.add_argument_group(title), type(cfg), defaults=cfg,
                             skip=("texture_faces", "atlas_size") if cfg is d.texture else ())


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


def stage_configs_from_args(args):
    """``reconstruct``'s ``StageConfigs`` from its parsed arguments: the pipeline's defaults, the ``--quality``
    preset, a ``--config`` file and the flags given, in that order (the same preset as
    ``StageConfigs.from_preset``)."""
    from dataclasses import fields

    from ..pipeline import StageConfigs

    _apply_quality(args)
    d = StageConfigs()
    return StageConfigs(**{f.name: config_from_args(type(getattr(d, f.name)), args) for f in fields(StageConfigs)})


def _run_reconstruct(args):
    from ..pipeline import reconstruct as run

    cfgs = stage_configs_from_args(args)
    rep = run(args.images, args.out, cfgs, force=args.force, overwrite=args.overwrite)
    p, d, m = rep.poses, rep.depth, rep.mesh
    print(f"reconstruct: {p.get('registered')} images registered, {d.get('views')} depth maps ({d.get('source')}), "
          f"mesh {m.get('vertices')} vertices / {m.get('faces')} faces")
    print(f"  files: {args.out}/mesh.ply, preview.png, report.html, report.json")
    if rep.texture:
        t = rep.texture
        w, h = t["atlases"][0]
        print(f"  textured model: {t['faces']} faces, {w}x{h} atlas -> {args.out}/model.glb "
              f"({t['file_size'] / 2**20:.1f} MB)" + (", model.obj (+ model.mtl, model.png)" if "model.obj" in t["files"] else ""))
    if rep.warnings:
        print(f"  {len(rep.warnings)} warning(s); see report.json")
    return 0


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
def mvs(sub):
    from ..depth.mvs import MVSConfig

    p = _depth_parser(sub, "mvs", MVSConfig, _run_mvs,
                      help="dense depth by multi-view stereo on the CPU (no weights, no GPU)",
                      description="PatchMatch stereo (or --method sweep: a plane sweep) from the dataset's cameras "
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


from . import tool_commands  # noqa: E402,F401  (the other commands register after these)
