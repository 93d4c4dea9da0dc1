"""``reconstruct()``: an image folder -> poses -> depth -> fused mesh -> report, composed from the stage modules.

OUT layout::

    OUT/images/            undistorted images the depth stage used
    OUT/sparse/0/          COLMAP text model (pinhole cameras, sparse points)
    OUT/transforms.json    the same cameras, NeRF convention
    OUT/masks/             NAME.png: --masks or the images' alpha channels, undistorted like the images
    OUT/depth/             NAME.npy (+ NAME.conf.npy) and NAME.png previews
    OUT/mesh.ply, mesh.glb the cleaned, fused mesh (small holes filled; PLY vertex/face property ``filled``)
    OUT/mesh_closed.ply, mesh_closed.glb  object captures: a watertight companion (every hole filled, the support
                           side closed)
    OUT/preview.png        the mesh from four viewpoints with the camera frusta
    OUT/preview_mesh.ply   the mesh decimated to <= 200k faces: report.html's 3D view
    OUT/first_look/        while a large capture's depth maps are computed: mesh.ply + preview.png fused from
                           the coarse depth maps; removed once the result is complete
    OUT/model.glb          the mesh simplified to --model-faces and textured from the photos (atlas at most
                           --max-atlas a side, embedded as JPEG); with --formats obj also model.obj + model.mtl +
                           model.png; upright (+Y up, an object on its support at the origin; the transform
                           from the reconstruction's frame in report.json's texture.frame); --texture off: none
    OUT/report.json        versions, parameters, per-stage seconds and peak memory, counts, warnings
    OUT/report.html        a self-contained page: an interactive 3D view of the mesh and cameras, the previews,
                           depth maps and numbers (photorecon.report)
    OUT/colmap/            SfM working files (database, distorted model), cached
    OUT/.stages/           one marker per completed stage (poses, depth, fusion, preview, model): a hash of its
                           settings, of its input files' names, sizes and times and of the stage before, and
                           a SHA-256 of each of its outputs; a re-run skips a stage whose marker matches and
                           whose outputs hold what it wrote, unless force=True

The stages run through ``photorecon.stages.Stages``: every file is written atomically and a stage's marker
only after all its outputs, so an interrupted run leaves nothing a later run mistakes for complete, and a stage
that writes other outputs makes every later stage run again. A run that fails leaves the last complete result
(mesh, previews, textured model, report) as it was (``Stages.keeping_result``). The input folder is never written
to.
"""
from __future__ import annotations

import logging
import platform
import shutil
import threading
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Literal

import numpy as np

from . import __version__
from .depth.mvs import MVSConfig
from .distributed import ClusterConfig, make_executor
from .errors import BadArgumentError, NoDepthError, NoImagesError
from .fusion import FusionConfig
from .fusion.budget import planned_footprint, voxel_settings
from .io.atomic import atomic_write_json
from .mesh import CleanConfig
from .mesh.refine import RefineConfig
from .report import PAGE_MAX_FACES, decimate_for_viewer, model_view_output, write_html_report
from .poses.scale import ScaleConfig
from .poses.sfm import SfMConfig
from .layout import Layout
from .resources import check_memory
from .results import Result
from .stages import Stages, atomic_dir, fingerprint
from .mesh.model import ModelConfig, model_output, model_paths
from .mesh.texture import TextureConfig
from .config_checks import check_config, expect_config

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
    texture: Literal["on", "off"] = field(default="on", metadata={"help": "on: also write OUT/model.glb, the mesh simplified to --model-faces and textured from the photos; off: skip it ('--texture' alone: on)", "const": "on"})
    min_depth_fraction: float = field(default=0.02, metadata={"help": "MVS: fail (exit 6) when on average less than this fraction of a view's pixels gets a confirmed depth: a mesh from so little depth is a fragment (0 = off; lower it for a subject that fills only a small part of the photos)", "range": (0.0, 1.0)})

    def __post_init__(self):
        if isinstance(self.texture, bool):  # texture=True / False: the former on/off switch
            self.texture = "on" if self.texture else "off"
        check_config(self)  # types, choices and ranges as declared (photorecon.config_checks)
        # options that contradict each other: refused when built, before any stage runs
        if self.depth_model and self.depth != "mvs":
            raise BadArgumentError(f"--depth-model {self.depth_model} and --depth {self.depth} both give the depth "
                                   "maps; give one of them")
        if self.depth_preset is not None:
            if not self.depth_model:
                raise BadArgumentError(f"--depth-preset {self.depth_preset} needs --depth-model FILE.onnx")
            from .depth.mono import PRESETS

            if self.depth_preset not in PRESETS:
                raise BadArgumentError(f"--depth-preset: expected one of {', '.join(sorted(PRESETS))}, got "
                                       f"{self.depth_preset!r}")


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
    model: ModelConfig = field(default_factory=ModelConfig)  # OUT/model.glb: its face budget and atlas size
    cluster: ClusterConfig = field(default_factory=ClusterConfig)  # where the depth and fusion tasks run
    refine: RefineConfig = field(default_factory=RefineConfig)  # photometric refinement of the cleaned mesh

    @classmethod
    def from_preset(cls, quality: str = "default", **stages) -> "StageConfigs":
        """The settings of ``--quality QUALITY`` (``photorecon.presets``: preview, default, high), then the settings
        of ``stages`` (``mvs={"n_sources": 6}``), which win over the preset as a command-line flag does."""
        from .presets import stage_configs

        return stage_configs(quality, **stages)

    def __post_init__(self):
        for f in fields(self):  # each stage's config of its own class (each checked its fields when built)
            expect_config(getattr(self, f.name), f.default_factory().__class__, f"StageConfigs.{f.name}")
        given = [f"--{k}" for k in ("intrinsics", "fx", "fy", "cx", "cy") if getattr(self.sfm, k) is not None]
        if self.run.poses and given:  # the given cameras carry their intrinsics; SfM's would be ignored
            raise BadArgumentError(f"--poses {self.run.poses} gives the cameras with their intrinsics; "
                                   f"{'/'.join(given)} (for SfM) would be ignored: give one or the other")


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
    mesh: dict  # vertices, faces, depth_maps_fused, mesher, watertight, boundary_edges, boundary_length,
    # filled_area, fill, closed (mesh_closed: watertight, filled_area), invented_fraction
    texture: dict  # the model stage (OUT/model.glb): faces, atlases, views_used, file_size, cpu_seconds ...
    warnings: list
    units: str  # "metres" when a scale was found, else "arbitrary"


# The depth stage's memory per working pixel of one reference view: its maps and costs, plus each source
# image (50 views at 1600x1067, 8 sources: 863 MB process peak, about 500 MB above the process's own)
DEPTH_BYTES_PER_PIXEL = 100
DEPTH_BYTES_PER_SOURCE_PIXEL = 25


def depth_memory(views, cfg: MVSConfig) -> float:
    """Bytes the MVS depth stage needs at once (about): the largest view at the working size, with its
    sources."""
    px = 0.0
    for v in views:
        w, h = v.intrinsics.width, v.intrinsics.height
        scale = min(1.0, cfg.max_size / max(w, h)) if cfg.max_size else 1.0
        px = max(px, w * h * scale * scale)
    return px * (DEPTH_BYTES_PER_PIXEL + DEPTH_BYTES_PER_SOURCE_PIXEL * cfg.n_sources)


def confirmed_fraction(per_view: dict, n_views: int) -> float:
    """The mean fraction of the views' pixels with a confirmed depth (a view without depth counts 0)."""
    return round(sum(v["valid_fraction"] for v in per_view.values()) / max(n_views, 1), 5)


def check_enough_depth(mean: float, per_view: dict, n_views: int, run: ReconstructConfig, mvs: MVSConfig) -> None:
    """``NoDepthError`` when the depth maps confirm less than ``run.min_depth_fraction`` of the pixels on
    average: the mesh would be a fragment (a few hundred faces), not a result."""
    if mean >= run.min_depth_fraction:
        return
    best = max((v["valid_fraction"] for v in per_view.values()), default=0.0)
    from .depth.methods import method

    hint = getattr(method(mvs.method), "HINT", None) or (
        "check that the photos overlap and the cameras are right (photorecon view OUT); lower "
        "--min-consistent or --min-confidence")
    raise NoDepthError(f"depth: only {100 * mean:.1f}% of the pixels of the {n_views} views have a confirmed depth "
                       f"(the best view {100 * best:.1f}%; at least {100 * run.min_depth_fraction:g}% needed): too "
                       f"little for a mesh; {hint}; a subject that fills only a small part of the photos: lower "
                       "--min-depth-fraction")


def fusion_stage(ds, fusion_cfg: FusionConfig, clean_cfg, layout: Layout, formats: tuple[str, ...], work_dir,
                 executor=None, refine_cfg: RefineConfig | None = None, views=None):
    """``reconstruct``'s fusion stage: the dataset's depth maps (of ``views``, default all) -> fused, cleaned
    mesh -> ``layout.mesh(fmt)``; with ``refine_cfg.refine`` the cleaned mesh refined against the photos
    (``mesh.refine``) replaces those files. Returns the mesh and its facts (``fusion.fuse_to_files``;
    ``refine``: what the refinement did)."""
    from .fusion import frames_hold_bytes, fuse_to_files, load_frames

    frames = load_frames(ds, fusion_cfg, views, frames_hold_bytes(fusion_cfg), work_dir)  # streamed: kept there
    mesh, info = fuse_to_files(frames, fusion_cfg, clean_cfg, layout, formats, ds.views, ds.model.points, executor,
                               ds, work_dir)
    if refine_cfg is not None and refine_cfg.refine:
        from .fusion import write_closed
        from .mesh import boundary_length, export
        from .mesh.refine import refine_dataset

        del frames
        # a mesh simplified to a face budget stays at its budget
        metadata = dict(mesh.metadata)  # what the cleaning found (the scene, the support plane)
        mesh, info["refine"] = refine_dataset(mesh, ds, refine_cfg, subdivide=not clean_cfg.target_faces)
        info.update(vertices=len(mesh.vertices), faces=len(mesh.faces), boundary_length=boundary_length(mesh))
        for fmt in formats:
            export(mesh, layout.mesh(fmt))
        info["closed"] = write_closed(mesh, clean_cfg, layout, formats, metadata)
    return mesh, info


def preview_stage(mesh, ds, layout: Layout) -> None:
    """``reconstruct``'s preview stage: the mesh decimated for report.html's 3D view (``decimate_for_viewer``)
    -> ``layout.viewer_mesh``, and preview.png rendered from that copy (a few hundred pixels a side show no
    more than its faces)."""
    from .mesh import export
    from .report.preview import render_preview
    from .resources import release_memory

    release_memory()  # what the fusion stage freed (its frames, the grids)
    small = decimate_for_viewer(mesh, PAGE_MAX_FACES)
    release_memory()
    export(small, layout.viewer_mesh)
    render_preview(small, layout.preview, cameras=ds.views)


def first_look_stage(maps: dict, ds, layout: Layout, fusion_cfg: FusionConfig) -> None:
    """A first look while the depth stage runs (``run_mvs``'s ``on_coarse``): the coarse depth maps of every
    view fused (``fusion.first_look``) -> ``layout.first_look``/mesh.ply and preview.png. Nothing is written when
    the coarse maps hold no surface; the run goes on either way, and removes the folder once its result is
    complete."""
    import time

    from .errors import EmptyMeshError
    from .fusion.first_look import first_look_mesh
    from .mesh import export
    from .report.preview import render_preview

    t0 = time.process_time()
    try:
        mesh = first_look_mesh(maps, fusion_cfg, cameras=ds.views)
    except (NoDepthError, EmptyMeshError) as exc:
        log.info("first look: none (%s)", exc)
        return
    with atomic_dir(layout.first_look) as tmp:
        export(mesh, tmp / "mesh.ply")
        render_preview(decimate_for_viewer(mesh, PAGE_MAX_FACES), tmp / "preview.png", cameras=ds.views)
    log.info("first look: %s (%d faces from the coarse depth maps of %d views, %.0f CPU s); the full result "
             "replaces it", layout.first_look / "preview.png", len(mesh.faces), len(maps), time.process_time() - t0)


def reconstruct(images: str | Path, out: str | Path, cfgs: StageConfigs | None = None, force: bool = False,
                overwrite: bool = False, quality: str | None = None) -> ReconstructResult:
    """Run the whole pipeline; returns what it did (also written to OUT/report.json). ``quality``: the settings of
    ``--quality`` (``StageConfigs.from_preset(quality)``), in place of ``cfgs``."""
    from .io.output import output_folder
    from .poses.ingest import VIDEO_SUFFIXES, not_a_folder
    from .mesh import parse_formats

    if quality is not None:
        if cfgs is not None:
            raise BadArgumentError(f"reconstruct: give cfgs or quality={quality!r}, not both (settings over a preset: "
                                   f"cfgs=StageConfigs.from_preset({quality!r}, mvs={{...}}))")
        cfgs = StageConfigs.from_preset(quality)
    cfgs = expect_config(cfgs, StageConfigs, "cfgs")
    run = cfgs.run
    images = Path(images)
    is_video = images.is_file() and images.suffix.lower() in VIDEO_SUFFIXES
    if not images.is_dir() and not is_video:
        raise NoImagesError(not_a_folder(images))
    if is_video and run.poses:
        raise BadArgumentError("--poses needs an image folder whose file names match the cameras, not a video")
    formats = parse_formats(run.formats)
    from .depth.methods import method, names

    for name in names("stage"):  # --depth FOLDER, --depth-model FILE.onnx: checked before anything is written
        method(name).check(run)
    masks = Path(run.masks) if run.masks else None
    if masks is not None:  # before anything is written
        from .poses.sfm import check_sfm_masks

        check_sfm_masks(images, masks)
    inputs = (images, masks, run.poses, run.depth_model, cfgs.sfm.intrinsics,
              run.depth if run.depth != "mvs" else None)
    lock_warnings: list[str] = []  # a stale lock taken over: listed in the report too
    with output_folder(out, overwrite, inputs=inputs, command="reconstruct", warnings=lock_warnings) as out:
        return _reconstruct(images, out, cfgs, force, is_video, formats, masks, lock_warnings)


def _reconstruct(images: Path, out: Path, cfgs: StageConfigs, force: bool, is_video: bool, formats: tuple,
                 masks: Path | None, warnings: list[str] | None = None) -> ReconstructResult:
    """``reconstruct`` in its checked, locked output folder; ``warnings``: those of the run so far."""
    from .depth.methods import method as depth_method, stage_method
    from .depth.mvs import run_mvs
    from .fusion import fuse_to_files, load_frames
    from .io.colmap_text import write_colmap_text
    from .io.dataset import Dataset, read_model
    from .io.nerf import write_transforms
    from .mesh import export, load_mesh
    from .report.preview import render_preview
    from .poses.ingest import ingest_given
    from .poses.scale import given_units, scale_output
    from .poses.sfm import run_sfm

    run = cfgs.run
    layout = Layout(out)
    stages = Stages(layout.stages, force)
    warnings = list(warnings or [])
    # the report is written last; a run that fails leaves the last complete run's result and report as they were
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
                model = ingest_given(read_model(run.poses), images, out, masks)
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

        # 2. depth: OUT/depth, by a depth method of the registry (photorecon/depth/methods): one that writes the
        # folder itself when the settings select it (--depth-model, --depth FOLDER), else MVS with --method METHOD
        whole = stage_method(run)
        source = whole.SOURCE if whole is not None else "mvs"

        def depth() -> dict:
            written = None  # the views whose depth maps the stage reports
            with atomic_dir(layout.depth) as tmp_depth:
                if whole is not None:
                    # depth maps in the given cameras' units scale with them (--marker-size, GPS)
                    factor = stages.info["poses"].get("scale", {}).get("factor", 1.0) if run.poses else 1.0
                    info = whole.run_stage(ds, run, tmp_depth, executor, work / "depth", factor)
                else:
                    check_memory("depth (MVS)", depth_memory(ds.views, cfgs.mvs))
                    note = getattr(depth_method(cfgs.mvs.method), "NOTE", None)
                    if note:
                        log.warning(note)
                    rep = run_mvs(ds, tmp_depth, cfgs.mvs, executor(), work / "depth",
                                  on_coarse=lambda maps: first_look_stage(maps, ds, layout, cfgs.fusion),
                                  mesh_footprint=lambda maps, working: planned_footprint(maps, working, cfgs.fusion))
                    n_depth = rep["depth_views"]["chosen"]  # the views that were to get a depth map (--depth-views)
                    info = {"source": "mvs", "views": rep["views"], "skipped": rep["skipped"],
                            "depth_views": rep["depth_views"],
                            "seconds_per_view": rep["seconds_per_view"],
                            "cpu_seconds_per_view": round(rep["cpu_seconds_per_view"], 2),
                            "cpu_seconds_per_mp_source": round(rep["cpu_seconds_per_mp_source"], 3),
                            "triangulation_seconds": rep["triangulation_seconds"],
                            "confirmed_fraction": confirmed_fraction(rep["per_view"], n_depth),
                            # per view its depth map's size, resolution and why (--depth-resolution)
                            "resolution": {n: "{} {}x{}{}".format(s["resolution"], *s["size"],
                                                                   f" ({s['resolution_reason']})" if "resolution_reason" in s else "")
                                           for n, s in rep["per_view"].items()}}
                    check_enough_depth(info["confirmed_fraction"], rep["per_view"], n_depth, run, cfgs.mvs)
                    written = sorted(rep["per_view"])
            _check_depth_written(layout, info["views"], written)
            log.info("depth: %d depth maps (%s)", info["views"], info["source"])
            return info

        depth_inputs = whole.inputs(run, fingerprint) if whole is not None else asdict(cfgs.mvs)
        stages.run("depth", {"source": source, "inputs": depth_inputs,  # MVS: also what sets the voxel it plans for
                             "mesh": None if whole is not None else voxel_settings(cfgs.fusion)}, depth, outputs=[layout.depth])

        # 3. fusion, cleaning, export: OUT/mesh.*; then OUT/preview.png
        fused = {}

        def fusion() -> dict:
            # MVS writes depth maps for the views it chose (--depth-views) and could match: those are fused
            views = [v for v in ds.views if ds.has_depth(v)] if source == "mvs" else None
            fused["mesh"], info = fusion_stage(ds, cfgs.fusion, cfgs.clean, layout, formats, work / "fusion",
                                               executor(), cfgs.refine, views)
            return info

        def preview() -> None:
            preview_stage(fused["mesh"] if "mesh" in fused else load_mesh(layout.mesh(formats[0])), ds, layout)

        stages.run("fusion", {"fusion": asdict(cfgs.fusion), "clean": asdict(cfgs.clean), "formats": formats,
                              **({"refine": asdict(cfgs.refine)} if cfgs.refine.refine else {})},
                   fusion, outputs=[layout.mesh(fmt) for fmt in formats] + [layout.mesh_closed(fmt) for fmt in formats],
                   optional=[layout.mesh_closed(fmt) for fmt in formats], result=True)
        stages.run("preview", {"viewer_faces": PAGE_MAX_FACES}, preview, outputs=[layout.preview, layout.viewer_mesh],
                   result=True)

        # 4. the textured model: the mesh simplified and textured from the photos: OUT/model.glb (+ .obj)
        if run.texture == "on":
            def model() -> dict:  # model.glb, then model_view.png: a photo beside the model seen from its camera
                mesh = fused["mesh"] if "mesh" in fused else load_mesh(layout.mesh(formats[0]))
                info = model_output(out, cfgs.model, cfgs.texture, formats, mesh=mesh, fusion=stages.info.get("fusion"),
                                    scale=stages.info.get("poses", {}).get("scale"))  # frame: plane, units
                return {**info, "view": model_view_output(out, info)}

            stages.run("model", {"model": asdict(cfgs.model), "texture": asdict(cfgs.texture), "obj": "obj" in formats,
                                 "frame": "upright"}, model, outputs=model_paths(layout, formats) + [layout.model_view],
                       result=True)
        else:  # an earlier run's model goes with the run's success (put back if it fails)
            stages.set_aside([*model_paths(layout, ("glb", "obj")), layout.model_view, layout.stages / "model.json"], group="model")
    except BaseException:
        stages.restore()  # the last complete result put back
        raise
    finally:
        log.removeHandler(handler)
        for ex in executors:
            ex.close()
    try:
        work.rmdir()  # empty once every stage finished
    except OSError:
        pass
    try:
        report = ReconstructResult(
            photorecon=__version__, python=platform.python_version(), versions=_versions(), input=str(images),
            output=str(out), parameters={k: asdict(v) for k, v in asdict_shallow(cfgs).items()}, stages=stages.stats,
            poses=stages.info.get("poses", {}), depth=stages.info.get("depth", {}), mesh=stages.info.get("fusion", {}),
            texture=stages.info.get("model", {}), warnings=warnings,
            units=stages.info.get("poses", {}).get("scale", {}).get("units", "arbitrary"))
        stages.set_aside([layout.report_json, layout.report_html], group="report")
        atomic_write_json(layout.report_json, report.to_dict())
        write_html_report(out, report.to_dict())
    except BaseException:
        stages.restore()
        raise
    stages.discard_kept()  # the run is complete: the result it replaced goes
    shutil.rmtree(layout.first_look, ignore_errors=True)  # the full result replaces the first look
    return report


def asdict_shallow(cfgs: StageConfigs) -> dict:
    return {"run": cfgs.run, "sfm": cfgs.sfm, "mvs": cfgs.mvs, "fusion": cfgs.fusion, "clean": cfgs.clean,
            "scale": cfgs.scale, "texture": cfgs.texture, "model": cfgs.model, "cluster": cfgs.cluster,
            "refine": cfgs.refine}


class _WarningCollector(logging.Handler):
    """The warnings of one run for its report: those logged by the thread that made it (the run's), not those of
    another run in another thread of the same process."""

    def __init__(self, sink: list):
        super().__init__(logging.WARNING)
        self.sink = sink
        self.thread = threading.get_ident()

    def emit(self, record):
        if record.thread == self.thread:
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


def _versions() -> dict:
    out = {}
    for mod in ("numpy", "cv2", "open3d", "pycolmap", "trimesh", "onnxruntime", "scipy"):
        try:
            out[mod] = __import__(mod).__version__
        except Exception:  # a missing optional module is reported as such
            out[mod] = None
    return out
