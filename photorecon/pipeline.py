"""``reconstruct()``: an image folder -> poses -> depth -> fused mesh -> report, composed from the stage modules.

OUT layout::

    OUT/images/            undistorted images the depth stage used
    OUT/sparse/0/          COLMAP text model (pinhole cameras, sparse points)
    OUT/transforms.json    the same cameras, NeRF convention
    OUT/masks/             NAME.png: --masks or the images' alpha channels, undistorted like the images
    OUT/depth/             NAME.npy (+ NAME.conf.npy) and NAME.png previews
    OUT/mesh.ply, mesh.glb the cleaned, fused mesh
    OUT/preview.png        the mesh from four viewpoints with the camera frusta
    OUT/preview_mesh.ply   the mesh decimated to <= 200k faces: report.html's 3D view
    OUT/textured/          with --texture: mesh.obj + mesh.mtl + texture.png, mesh.glb (texture embedded),
                           preview.png
    OUT/report.json        versions, parameters, per-stage seconds and peak memory, counts, warnings
    OUT/report.html        a self-contained page: an interactive 3D view of the mesh and cameras, the previews,
                           depth maps and numbers (photorecon.report)
    OUT/colmap/            SfM working files (database, distorted model), cached
    OUT/.stages/           one marker per completed stage (poses, depth, fusion, preview): a hash of its
                           settings, of its input files' names, sizes and times and of the stage before;
                           a re-run skips a stage whose marker matches, unless force=True

The stages run through ``photorecon.stages.Stages``: every file is written atomically and a stage's marker
only after all its outputs, so an interrupted run leaves nothing a later run mistakes for complete, and a stage
that runs again makes every later stage run again. The input folder is never written to.
"""
from __future__ import annotations

import logging
import platform
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from . import __version__
from .depth.mvs import MVSConfig
from .distributed import ClusterConfig, make_executor
from .errors import BadArgumentError, InputDataError, NoDepthError, NoImagesError
from .fusion import FusionConfig
from .io.atomic import atomic_write_json
from .mesh import CleanConfig
from .report import VIEWER_MAX_FACES, decimate_for_viewer, write_html_report
from .poses.scale import ScaleConfig
from .poses.sfm import SfMConfig
from .layout import Layout
from .results import Result
from .stages import Stages, atomic_dir, fingerprint
from .mesh.texture import TextureConfig

log = logging.getLogger("photorecon")


@dataclass
class ReconstructConfig:
    """Top-level settings of ``photorecon reconstruct``."""

    poses: str | None = field(default=None, metadata={"help": "use these cameras (COLMAP model folder or transforms.json) instead of SfM", "metavar": "PATH"})
    depth: str = field(default="mvs", metadata={"help": "depth source: 'mvs', or a folder of NAME.npy depth maps (e.g. a synth dataset's depth/)", "metavar": "SOURCE"})
    depth_model: str | None = field(default=None, metadata={"help": "monocular depth from this ONNX model (MiDaS-style), aligned to the SfM points", "metavar": "FILE.onnx"})
    depth_preset: str | None = field(default=None, metadata={"help": "preset for --depth-model (see 'photorecon depth --help')", "metavar": "NAME"})
    formats: str = field(default="ply,glb", metadata={"help": "mesh formats to write, comma-separated: ply, obj, glb", "metavar": "LIST"})
    masks: str | None = field(default=None, metadata={"help": "mask folder: NAME.png or NAME.EXT.png at the image's size, 0 = ignore the pixel (default: the images' alpha channel)", "metavar": "DIR"})
    texture: bool = field(default=False, metadata={"help": "also write a UV-textured mesh baked from the photos (OUT/textured/)"})


@dataclass
class StageConfigs:
    run: ReconstructConfig = field(default_factory=ReconstructConfig)
    sfm: SfMConfig = field(default_factory=SfMConfig)
    mvs: MVSConfig = field(default_factory=MVSConfig)
    # MVS and monocular depth are noisier than rendered depth: a wider truncation band than FusionConfig's
    fusion: FusionConfig = field(default_factory=lambda: FusionConfig(trunc_voxels=3.0))
    clean: CleanConfig = field(default_factory=CleanConfig)
    scale: ScaleConfig = field(default_factory=ScaleConfig)
    texture: TextureConfig = field(default_factory=TextureConfig)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)  # where the depth and fusion tasks run


@dataclass
class ReconstructResult(Result):
    """What ``reconstruct`` did: report.json's content. The stage sections (``poses``, ``depth``, ``mesh``,
    ``texture``) hold what each stage recorded (JSON-ready facts, also when the stage was cached)."""

    photorecon: str  # version
    python: str
    versions: dict  # dependency -> version
    input: str
    output: str
    parameters: dict  # stage -> its settings
    stages: dict  # stage -> seconds, peak_mb, cached
    poses: dict  # source, registered, unregistered, scale, sfm_seconds
    depth: dict  # source, views, skipped / excluded, seconds_per_view
    mesh: dict  # vertices, faces, depth_maps_fused, mesher, watertight, boundary_edges, invented_fraction
    texture: dict  # with --texture: faces, charts, views_used, folder ...
    warnings: list
    units: str  # "metres" when a scale was found, else "arbitrary"


def _undistort_given(model, images_dir: Path, out: Path, masks_dir: Path | None = None):
    """Given cameras: copy (and, for distorted cameras, undistort with OpenCV) the images into OUT/images.
    An image's mask in ``masks_dir`` (NAME.EXT.png or NAME.png, 0 = ignore), else its alpha channel (RGBA,
    grey + alpha), becomes OUT/masks/NAME.png (255 where > 0), undistorted like the image, so the depth and
    fusion stages use it as a mask."""
    from .cameras import View
    from .io.colmap_text import SparseModel
    from .io.images import damaged_image, mask_file, read_alpha, read_image, read_mask, write_image

    layout = Layout(out)
    img_out, mask_out = layout.images, layout.masks
    img_out.mkdir(parents=True, exist_ok=True)
    views, damaged = [], []
    for v in model.views:
        name = v.image_file or v.name
        src = images_dir / name
        if not src.is_file():
            cands = [p for p in images_dir.glob(v.name + ".*")]
            if not cands:
                raise InputDataError(f"view {v.name}: image {name} not found in {images_dir}")
            src = cands[0]
        # OpenCV decodes a truncated JPEG without an error (grey from where the data stops): check it first
        why = damaged_image(src) if src.suffix.lower() in (".jpg", ".jpeg") else None
        img = None
        if not why:
            try:
                img = read_image(src)
            except InputDataError:
                why = damaged_image(src)
                if not why:
                    raise
        if why:
            log.warning("view %s: image %s is %s; view skipped", v.name, src, why)
            damaged.append(v.name)
            continue
        if img.shape[:2] != (v.intrinsics.height, v.intrinsics.width):
            raise InputDataError(f"view {v.name}: image {src} is {img.shape[1]}x{img.shape[0]}, camera is "
                                 f"{v.intrinsics.width}x{v.intrinsics.height}")
        user_mask = mask_file(masks_dir, src.name) if masks_dir else None
        if user_mask is not None:
            m = read_mask(user_mask, (img.shape[1], img.shape[0]), f"image {src.name}")
        else:
            alpha = read_alpha(src)
            m = None if alpha is None else alpha > 0
        mask = None if m is None else np.where(m, 255, 0).astype(np.uint8)
        intr = v.intrinsics
        if intr.has_distortion:
            dist = np.array([intr.k1, intr.k2, intr.p1, intr.p2])
            img = cv2.undistort(img, intr.K, dist, None, intr.K)
            if mask is not None:  # same maps; outside the source image -> 0 (no data)
                mask = np.where(cv2.undistort(mask, intr.K, dist, None, intr.K) >= 128, 255, 0).astype(np.uint8)
            intr = intr.pinhole()
        dst_name = Path(src.name).stem + ".png"
        write_image(img_out / dst_name, img)
        mask_path = mask_out / dst_name  # the output model names the view after its image's stem
        if mask is not None:
            mask_out.mkdir(exist_ok=True)
            write_image(mask_path, mask)
        else:
            mask_path.unlink(missing_ok=True)  # a stale mask from an earlier run with other images
        views.append(View(v.name, intr, v.cam_from_world, image_file=dst_name))
    if damaged and len(views) < 2:
        raise InputDataError(f"{images_dir}: {len(views)} usable image(s) for the given cameras"
                             + (f" ({len(damaged)} truncated or damaged: {', '.join(damaged[:5])})" if damaged else "")
                             + "; at least 2 needed")
    return SparseModel(views, model.points, model.colors, model.point_ids, model.errors, model.observations)


def fusion_stage(ds, fusion_cfg: FusionConfig, clean_cfg, layout: Layout, formats: tuple[str, ...], work_dir,
                 executor=None):
    """``reconstruct``'s fusion stage: the dataset's depth maps -> fused, cleaned mesh -> ``layout.mesh(fmt)``.
    Returns the mesh and its facts (``fusion.fuse_to_files``)."""
    from .fusion import fuse_to_files, load_frames

    frames = load_frames(ds, fusion_cfg)
    return fuse_to_files(frames, fusion_cfg, clean_cfg, layout, formats, ds.views, ds.model.points, executor, ds,
                         work_dir)


def preview_stage(mesh, ds, layout: Layout) -> None:
    """``reconstruct``'s preview stage: the mesh decimated for report.html's 3D view (``decimate_for_viewer``)
    -> ``layout.viewer_mesh``, and preview.png rendered from that copy (a few hundred pixels a side show no
    more than its faces)."""
    from .mesh import export
    from .report.preview import render_preview

    from .resources import release_memory

    release_memory()  # what the fusion stage freed (its frames, the grids)
    small = decimate_for_viewer(mesh, VIEWER_MAX_FACES)
    release_memory()
    export(small, layout.viewer_mesh)
    render_preview(small, layout.preview, cameras=ds.views)


def reconstruct(images: str | Path, out: str | Path, cfgs: StageConfigs | None = None, force: bool = False,
                overwrite: bool = False) -> ReconstructResult:
    """Run the whole pipeline; returns what it did (also written to OUT/report.json)."""
    from .io.output import output_folder
    from .poses.ingest import VIDEO_SUFFIXES
    from .mesh import parse_formats

    cfgs = cfgs or StageConfigs()
    run = cfgs.run
    images = Path(images)
    is_video = images.is_file() and images.suffix.lower() in VIDEO_SUFFIXES
    if not images.is_dir() and not is_video:
        raise NoImagesError(f"{images}: no such image folder (or video file)")
    if is_video and run.poses:
        raise BadArgumentError("--poses needs an image folder whose file names match the cameras, not a video")
    formats = parse_formats(run.formats)
    if run.texture:
        from .mesh.texture import check_config

        check_config(cfgs.texture)  # a bad --atlas-size fails before anything is written
    if run.depth != "mvs" and not Path(run.depth).is_dir():
        raise BadArgumentError(f"--depth: expected 'mvs' or a folder of depth maps, got {run.depth!r}")
    if run.depth_model:
        from .depth.mono import check_model_file

        check_model_file(run.depth_model)
    masks = Path(run.masks) if run.masks else None
    if masks is not None:  # before anything is written
        from .poses.sfm import check_sfm_masks

        check_sfm_masks(images, masks)
    inputs = (images, masks, run.poses, run.depth_model, cfgs.sfm.intrinsics,
              run.depth if run.depth != "mvs" else None)
    with output_folder(out, overwrite, inputs=inputs) as out:
        return _reconstruct(images, out, cfgs, force, is_video, formats, masks)


def _reconstruct(images: Path, out: Path, cfgs: StageConfigs, force: bool, is_video: bool, formats: tuple,
                 masks: Path | None) -> ReconstructResult:
    """``reconstruct`` in its checked, locked output folder."""
    from .depth.mvs import run_mvs
    from .fusion import fuse_to_files, load_frames
    from .io.colmap_text import write_colmap_text
    from .io.dataset import Dataset, read_model
    from .io.nerf import write_transforms
    from .mesh import export, load_mesh
    from .report.preview import render_preview
    from .poses.scale import given_units, scale_output
    from .poses.sfm import run_sfm

    run = cfgs.run
    layout = Layout(out)
    stages = Stages(layout.stages, force)
    warnings: list[str] = []
    handler = _WarningCollector(warnings)
    log.addHandler(handler)
    executors: list = []  # the depth and fusion tasks' executor, made (a cluster started) when first needed
    work = layout.work  # intermediate task outputs, kept across an interruption: a re-run reuses them

    def executor():
        if not executors:
            executors.append(make_executor(cfgs.cluster))
        return executors[0]

    try:
        # 1. poses: OUT/images, OUT/sparse/0, OUT/transforms.json
        def poses() -> dict:
            if run.poses:
                shutil.rmtree(layout.images, ignore_errors=True)  # no image left from an earlier SfM run
                model = _undistort_given(read_model(run.poses), images, out, masks)
                write_colmap_text(model, layout.sparse)
                write_transforms(model.views, layout.transforms)
                info = {"source": run.poses, "registered": len(model.views), "unregistered": []}
            else:
                res = run_sfm(images, out, cfgs.sfm, force=force, masks=masks)
                info = {"source": "sfm", "registered": len(res.registered), "unregistered": res.unregistered,
                        "sfm_seconds": res.seconds}
            # metric scale (markers or EXIF GPS): rewrites OUT/sparse/0 and OUT/transforms.json, records units
            info["scale"] = scale_output(out, None if is_video else images, cfgs.scale, given_units(run.poses))
            log.info("poses: %d images registered", info["registered"])
            return info

        sfm_inputs = None if run.poses else {"settings": asdict(cfgs.sfm), "intrinsics":
                                             cfgs.sfm.intrinsics and fingerprint(cfgs.sfm.intrinsics)}
        # a changed mask folder reruns poses (SfM features, or the undistorted masks) and all that follows
        stages.run("poses", {"images": fingerprint(images), "poses": run.poses and fingerprint(run.poses),
                             "sfm": sfm_inputs, "masks": masks and fingerprint(masks),
                             "scale": asdict(cfgs.scale)},
                   poses, outputs=[layout.images, layout.sparse, layout.transforms, layout.masks],
                   optional=[layout.masks])
        ds = Dataset.open(out)

        # 2. depth: OUT/depth
        source = "mono" if run.depth_model else "mvs" if run.depth == "mvs" else "folder"

        def depth() -> dict:
            written = None  # the views whose depth maps the stage reports
            with atomic_dir(layout.depth) as tmp_depth:
                if source == "mono":
                    from .depth.mono import MonoConfig, run_mono

                    rep = run_mono(ds, run.depth_model, tmp_depth, MonoConfig(preset=run.depth_preset), executor(),
                                   work / "depth")
                    info = {"source": "mono", "views": rep["views"], "excluded": rep.get("excluded", {})}
                elif source == "mvs":
                    rep = run_mvs(ds, tmp_depth, cfgs.mvs, executor(), work / "depth")
                    info = {"source": "mvs", "views": rep["views"], "skipped": rep["skipped"],
                            "seconds_per_view": rep["seconds_per_view"],
                            "cpu_seconds_per_view": round(rep["cpu_seconds_per_view"], 2),
                            "cpu_seconds_per_mp_source": round(rep["cpu_seconds_per_mp_source"], 3),
                            "triangulation_seconds": rep["triangulation_seconds"]}
                    written = sorted(rep["per_view"])
                else:
                    # depth maps in the given cameras' units scale with them (--marker-size, GPS)
                    factor = stages.info["poses"].get("scale", {}).get("factor", 1.0) if run.poses else 1.0
                    n = _copy_depth(Path(run.depth), ds, tmp_depth, factor)
                    info = {"source": str(run.depth), "views": n}
            _check_depth_written(layout, info["views"], written)
            log.info("depth: %d depth maps (%s)", info["views"], info["source"])
            return info

        if source == "mono":
            depth_inputs = {"model": fingerprint(run.depth_model), "preset": run.depth_preset}
        elif source == "mvs":
            depth_inputs = asdict(cfgs.mvs)
        else:
            depth_inputs = fingerprint(run.depth)
        stages.run("depth", {"source": source, "inputs": depth_inputs}, depth, outputs=[layout.depth])

        # 3. fusion, cleaning, export: OUT/mesh.*; then OUT/preview.png
        fused = {}

        def fusion() -> dict:
            fused["mesh"], info = fusion_stage(ds, cfgs.fusion, cfgs.clean, layout, formats, work / "fusion",
                                               executor())
            return info

        def preview() -> None:
            preview_stage(fused["mesh"] if "mesh" in fused else load_mesh(layout.mesh(formats[0])), ds, layout)

        stages.run("fusion", {"fusion": asdict(cfgs.fusion), "clean": asdict(cfgs.clean), "formats": formats},
                   fusion, outputs=[layout.mesh(fmt) for fmt in formats])
        stages.run("preview", {"viewer_faces": VIEWER_MAX_FACES}, preview, outputs=[layout.preview, layout.viewer_mesh])

        # 4. optional: a UV-textured mesh baked from the photos: OUT/textured/
        if run.texture:
            from .mesh.texture import texture_output

            def texture() -> dict:
                mesh = fused["mesh"] if "mesh" in fused else load_mesh(layout.mesh(formats[0]))
                return texture_output(out, cfgs.texture, mesh=mesh)

            stages.run("texture", asdict(cfgs.texture), texture, outputs=[layout.textured])
    finally:
        log.removeHandler(handler)
        for ex in executors:
            ex.close()
    try:
        work.rmdir()  # empty once every stage finished
    except OSError:
        pass
    report = ReconstructResult(
        photorecon=__version__, python=platform.python_version(), versions=_versions(), input=str(images),
        output=str(out), parameters={k: asdict(v) for k, v in asdict_shallow(cfgs).items()}, stages=stages.stats,
        poses=stages.info.get("poses", {}), depth=stages.info.get("depth", {}), mesh=stages.info.get("fusion", {}),
        texture=stages.info.get("texture", {}), warnings=warnings,
        units=stages.info.get("poses", {}).get("scale", {}).get("units", "arbitrary"))
    atomic_write_json(layout.report_json, report.to_dict())
    write_html_report(out, report.to_dict())
    return report


def asdict_shallow(cfgs: StageConfigs) -> dict:
    return {"run": cfgs.run, "sfm": cfgs.sfm, "mvs": cfgs.mvs, "fusion": cfgs.fusion, "clean": cfgs.clean,
            "scale": cfgs.scale, "texture": cfgs.texture, "cluster": cfgs.cluster}


class _WarningCollector(logging.Handler):
    def __init__(self, sink: list):
        super().__init__(logging.WARNING)
        self.sink = sink

    def emit(self, record):
        self.sink.append(record.getMessage())


def _check_depth_written(layout: Layout, count: int, names: list[str] | None = None) -> None:
    """The depth stage's outputs, checked before it is marked complete: ``count`` depth maps in OUT/depth (and
    each of ``names`` among them). Raises ``OutputError`` naming what is missing."""
    from .errors import OutputError

    have = {p.name[:-4] for p in layout.depth.glob("*.npy") if not p.name.endswith((".conf.npy", ".normal.npy"))}
    missing = [n for n in names or () if n not in have]
    if missing or len(have) < count or not have:
        what = f"{layout.depth_map(missing[0])}" if missing else f"{count} depth maps ({len(have)} found)"
        raise OutputError(f"depth stage: {what} missing in {layout.depth} after the stage wrote it; was the output "
                          "folder changed by another program meanwhile? Run again to redo the stage")


def _copy_depth(src: Path, ds, dst: Path, factor: float = 1.0) -> int:
    """Copy NAME.npy depth maps (and confidences, previews) for the dataset's views; validate each.
    ``factor``: multiplies the depths (the metric scale applied to the given cameras)."""
    from .io.images import read_depth

    dst.mkdir(parents=True, exist_ok=True)
    n = 0
    for v in ds.views:
        p = src / f"{v.name}.npy"
        if not p.is_file():
            log.warning("view %s: no depth map %s; skipped", v.name, p)
            continue
        d = read_depth(p, (v.intrinsics.height, v.intrinsics.width), v.name)
        if factor != 1.0:
            np.save(dst / p.name, (d * factor).astype(np.float32))
        else:
            shutil.copyfile(p, dst / p.name)
        for extra in (f"{v.name}.conf.npy", f"{v.name}.normal.npy", f"{v.name}.png"):
            if (src / extra).is_file():
                shutil.copyfile(src / extra, dst / extra)
        n += 1
    if not n:
        raise NoDepthError(f"{src}: no depth map matches the cameras' image names")
    return n


def _versions() -> dict:
    out = {}
    for mod in ("numpy", "cv2", "open3d", "pycolmap", "trimesh", "onnxruntime", "scipy"):
        try:
            out[mod] = __import__(mod).__version__
        except Exception:  # a missing optional module is reported as such
            out[mod] = None
    return out
