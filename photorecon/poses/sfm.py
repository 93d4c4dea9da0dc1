"""Structure from motion through pycolmap: ``run_sfm`` and its settings, ``SfMConfig``.

Stages, each a function in its own module that writes one output and returns its path (hloc's style), run by the
stage runner (``photorecon.stages``) so that a re-run reuses a stage while its inputs and settings are unchanged:
ingest (oriented copies of the images, ``OUT/colmap/images``) -> ``extract.extract`` (SIFT,
``OUT/colmap/features.db``) -> ``match.match`` (exhaustive / retrieval (``retrieval.py``) / sequential / spatial
by EXIF GPS, chosen by count, video and GPS; ``OUT/colmap/database.db``) -> ``mapping.map_model`` (incremental,
or global (GLOMAP) for large sets; the largest model, ``OUT/colmap/sparse``) -> ``undistort.undistort`` to
pinhole images. pycolmap is imported inside functions (``_colmap._pycolmap``): its API changes between versions
(pycolmap 4.x: ``image.cam_from_world()`` is a method). Outputs in the synth layout: ``OUT/images/``
(undistorted), ``OUT/sparse/0/`` (COLMAP text, pinhole) and ``OUT/transforms.json``.
Masks (a user's folder, else the images' alpha) go to extraction as ``OUT/colmap/masks/NAME.EXT.png`` (COLMAP's
naming) and, undistorted, to ``OUT/masks/NAME.png``.
Stage markers (settings hash, seconds, peak memory): ``OUT/colmap/.stages/``.

The stages' functions are importable from here too (``from photorecon.poses.sfm import extract, match``).
"""
from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from ..errors import BadArgumentError, SfMError
from ..fields import check_config, expect_config
from ..io.atomic import atomic_write_json
from ..io.colmap_text import SparseModel
from ..io.space import check_space
from ..layout import Layout
from ..stages import Stages, atomic_dir, fingerprint
from ._colmap import MB, _pycolmap, _quiet, no_model_message
from .extract import (OCTAVE0_PIXELS_PER_FEATURE, SIFT_BYTES_PER_PIXEL, _given_intrinsics, camera_groups,  # noqa: F401
                      extract, features_bytes, sift_first_octave, sift_threads)
from .mapping import RELAXED_MAPPING, _incremental_options, choose_mapper, map_model  # noqa: F401
from .match import choose_matching, gps_priors, match  # noqa: F401
from .sfm_inputs import check_sfm_masks, sfm_masks, write_colmap_masks  # noqa: F401
from .undistort import publish, undistort

log = logging.getLogger("photorecon")


# --mapper auto maps globally from this many images: on 200 synthetic views GLOMAP was more accurate than
# incremental mapping with every matching (0.057-0.076 deg vs 0.078-0.102) at 0.9-1.7x its time (bench_sfm.py
# --large, 2026-11-23). On real photos it is not yet safe lower down: on gold_cape's 119 handheld photos (same
# matches, tools/bench_mappers.py, 2026-11-29, 2-core host, shared) it placed 118 at a mean rotation error of
# 17.9 degrees (two runs alike; 183-197 CPU s) against 0.087 for incremental mapping (118; 281 CPU s): see
# docs/benchmarks.md, "Structure from motion, large sets".
GLOBAL_MIN = 200

# --matching retrieval: photos retrieved per photo (--retrieval-neighbors)
RETRIEVAL_NEIGHBORS = 12


@dataclass
class SfMConfig:
    """Settings of the structure-from-motion stage (``photorecon sfm``)."""

    intrinsics: str | None = field(default=None, metadata={"help": "3x3 K text file (pixel (0,0) = centre of the top-left pixel); kept fixed unless --refine-intrinsics", "metavar": "FILE"})
    fx: float | None = field(default=None, metadata={"help": "focal length x in pixels (with --fy, --cx, --cy instead of --intrinsics)", "range": (0, 1e7), "exclusive_min": True})
    fy: float | None = field(default=None, metadata={"help": "focal length y in pixels", "range": (0, 1e7), "exclusive_min": True})
    cx: float | None = field(default=None, metadata={"help": "principal point x in pixels (pixel (0,0) = centre of the top-left pixel)", "range": (-1e6, 1e6)})
    cy: float | None = field(default=None, metadata={"help": "principal point y in pixels", "range": (-1e6, 1e6)})
    refine_intrinsics: bool = field(default=False, metadata={"help": "let bundle adjustment refine given intrinsics"})
    camera_model: Literal["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"] = field(
        default="SIMPLE_RADIAL", metadata={"help": "camera model to self-calibrate (given intrinsics use PINHOLE)"})
    max_image_size: int = field(default=1600, metadata={"help": "feature extraction works on images downscaled to this longest side, pixels", "range": (64, 65536)})
    max_features: int = field(default=8192, metadata={"help": "most SIFT features per image", "range": (16, 1_000_000)})
    small_image_size: int = field(default=500, metadata={"help": "when images are left out: photos whose long side is below this many pixels get SIFT again on 2x upsampled copies, matched guided (0 = off)", "range": (0, 65536)})
    low_contrast_peak: float = field(default=0.002, metadata={"help": "when fewer than 3/4 of the images register: SIFT again with this peak (contrast) threshold, for grey or low-contrast photos (COLMAP's default 0.0067; 0 = off)", "range": (0, 1)})
    affine_sift: bool = field(default=True, metadata={"help": "estimate affine feature shapes: longer tracks across oblique views"})
    dsp_sift: bool = field(default=False, metadata={"help": "domain-size pooling SIFT descriptors (slower extraction, sometimes more accurate)"})
    wide_baseline_retry: bool = field(default=True, metadata={"help": "when fewer than 9/10 of the images register: SIFT again with domain-size pooling and guided matching (photos far apart, e.g. 30 degrees round a small object)"})
    matching: Literal["auto", "exhaustive", "retrieval", "sequential", "spatial"] = field(default="auto", metadata={"help": "image pairs matched: every pair; retrieval: the --retrieval-neighbors most similar photos per photo (a visual index of the photos' own features) and loop-closing pairs; file-name neighbours (videos); or nearest by GPS. auto: exhaustive up to --exhaustive-max images, above it sequential for a video, spatial when every photo carries GPS, else retrieval"})
    exhaustive_max: int = field(default=80, metadata={"help": "largest image count --matching auto matches exhaustively (about where retrieval starts to cost less: docs/benchmarks.md)", "range": (0, 1_000_000)})
    retrieval_neighbors: int = field(default=RETRIEVAL_NEIGHBORS, metadata={"help": "retrieval matching: most similar photos matched per photo (then up to half as many loop-closing pairs per photo)", "range": (1, 100_000)})
    sequential_overlap: int = field(default=10, metadata={"help": "sequential matching: neighbours per image in file-name order", "range": (1, 100_000)})
    sequential_loops: bool = field(default=True, metadata={"help": "sequential matching: also match every k-th image with every other k-th one (k = --sequential-overlap), which closes loops"})
    spatial_neighbors: int = field(default=20, metadata={"help": "spatial matching: nearest photos by EXIF GPS per photo", "range": (1, 100_000)})
    spatial_max_distance: float = field(default=100.0, metadata={"help": "spatial matching: no pair farther apart than this, metres", "range": (0, 1e7), "exclusive_min": True})
    spatial_ignore_z: bool = field(default=True, metadata={"help": "spatial matching: ignore GPS altitude (consumer GPS altitude is poor)"})
    mapper: Literal["auto", "incremental", "hierarchical", "global"] = field(default="auto", metadata={"help": "COLMAP incremental, hierarchical (clusters mapped side by side, then merged; incremental again when it registers too few) or global (GLOMAP) mapping; auto = hierarchical from 100 images on, global from --global-min on"})
    global_min: int = field(default=GLOBAL_MIN, metadata={"help": "smallest image count --mapper auto maps globally", "range": (0, 10_000_000)})
    min_registered: float = field(default=0.5, metadata={"help": "fail when fewer than this fraction of the images register", "range": (0.0, 1.0)})
    threads: int = field(default=-1, metadata={"help": "threads (-1 = all cores)", "range": (1, 4096), "also": (-1,)})
    seed: int = field(default=0, metadata={"help": "random seed of the mapping", "range": (0, 2**31 - 1)})
    video_every: int = field(default=10, metadata={"help": "when IMAGES is a video file: take every k-th frame", "range": (1, 1_000_000)})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.fields)
        flags = [f"--{k}" for k in ("fx", "fy", "cx", "cy") if getattr(self, k) is not None]
        if self.intrinsics and flags:  # refused when built, before any stage runs
            raise BadArgumentError(f"--intrinsics {self.intrinsics} and {'/'.join(flags)} both give the "
                                   "intrinsics; give one of them")
        if flags and self.fx is None:
            raise BadArgumentError("intrinsics flags: --fx is required (with optional --fy, --cx, --cy)")


@dataclass
class SfMResult:
    model: SparseModel  # undistorted (pinhole) cameras + sparse points, what the depth stage uses
    registered: list[str]
    unregistered: list[str]
    seconds: dict = field(default_factory=dict)
    cached: list[str] = field(default_factory=list)


# The second SIFT pass with a lower contrast threshold runs when fewer than this fraction of the images register
# (a few unrelated photos among many do not cost a second extraction and matching).
LOW_CONTRAST_RETRY_BELOW = 0.75
# ... and the wide-baseline pass (domain-size pooling, guided matching) when fewer than this fraction register
WIDE_BASELINE_RETRY_BELOW = 0.9


def _ingest(src: Path, work_images: Path, video_every: int, left_out: dict[str, str] | None = None) -> dict:
    """Oriented copies of the photos (or every k-th video frame) in ``work_images``; what SfM needs of them."""
    from .ingest import ingest_folder
    from .video import VIDEO_SUFFIXES, video_frames

    photos = [src] if src.is_file() else [p for p in src.iterdir() if p.is_file()]
    check_space(work_images, 2 * sum(p.stat().st_size for p in photos) + MB)  # WebP becomes a larger PNG
    with atomic_dir(work_images) as tmp:
        if src.is_file() and src.suffix.lower() in VIDEO_SUFFIXES:
            ing = video_frames(src, tmp, video_every)
        else:
            ing = ingest_folder(src, tmp, min_images=1, left_out=left_out)
    return {"images": [[im.name, im.width, im.height, im.focal_prior_px] for im in ing.images],
            "skipped": ing.skipped, "renamed": ing.renamed}


def _remove_leftovers(work: Path, out: Path) -> None:
    """Temporary files of a run that died in COLMAP's native code (a full disk aborts SQLite's writer):
    the half-written databases and their journals (also the upsampled pass's), the upsampled copies for SIFT,
    the mapper's and the undistorter's folders, half-written stage folders."""
    leftovers = [*work.glob(".features*.db*"), *work.glob(".database*.db*"), *work.glob(".mapper*"),
                 *work.glob(".upscaled*"), *work.glob(".*.partial"), *out.glob(".undistort*")]
    for p in leftovers:
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    if leftovers:
        log.debug("removed %d temporary file(s) of an earlier run", len(leftovers))


def run_sfm(images_dir: str | Path, out: str | Path, cfg: SfMConfig | None = None, force: bool = False,
            masks: str | Path | None = None) -> SfMResult:
    """Run SfM on ``images_dir`` (a folder or a video) into ``out`` (see the module docstring).

    ``masks``: a folder of masks (NAME.png or NAME.EXT.png, 0 = ignore); they, or else the images' alpha
    channels, go to feature extraction in COLMAP's layout (``out/colmap/masks/NAME.EXT.png``) and, undistorted,
    to ``out/masks/NAME.png``. Each stage is reused from ``out/colmap`` while its inputs (file names, sizes and
    times) and settings are unchanged, unless ``force``. Raises ``NoImagesError`` / ``SfMError`` with one
    clear line on failure, ``InputDataError`` for a mask folder that does not fit the images."""
    from .photos import IngestedImage

    pycolmap = _pycolmap()
    cfg = expect_config(cfg, SfMConfig, "cfg")
    if not 0 <= cfg.min_registered <= 1:
        raise BadArgumentError(f"--min-registered: expected a fraction of the images, 0 to 1, got {cfg.min_registered:g}")
    _quiet(pycolmap)
    src, out = Path(images_dir), Path(out)
    masks = Path(masks) if masks else None
    left_out: dict[str, str] = {}
    if masks is not None:
        from .photos import MASKED_OUT

        left_out = {name: MASKED_OUT for name in sfm_masks(src, masks)[1]}
    layout = Layout(out)
    work = layout.colmap  # COLMAP's working files, laid out as sfm's stages want them
    _remove_leftovers(work, out)
    stages = Stages(work / ".stages", force, label="SfM ")

    # "gate": the image gate's version (which photos it leaves out); a change re-runs the ingest
    ingest_params = {"source": fingerprint(src), "video_every": cfg.video_every if src.is_file() else None,
                     "gate": 2, "left_out": sorted(left_out)}
    ing = stages.run("ingest", ingest_params, lambda: _ingest(src, work / "images", cfg.video_every, left_out),
                     outputs=[work / "images"])
    renamed = ing.get("renamed", {})  # working name -> photo name, for photos ingested as PNG copies (WebP)
    images = [IngestedImage(name, src if src.is_file() else src / renamed.get(name, name), w, h, f)
              for name, w, h, f in ing["images"]]
    if len(images) < 2:
        raise SfMError(f"{images_dir}: only one readable image ({images[0].name}); SfM needs at least 2 "
                       "overlapping photos")
    names = [im.name for im in images]

    cameras = camera_groups(images, cfg)
    sift = {k: getattr(cfg, k) for k in ("max_image_size", "max_features", "affine_sift", "dsp_sift")}
    sift["octave0_pixels_per_feature"] = OCTAVE0_PIXELS_PER_FEATURE
    work_masks = work / "masks"
    fixed = _given_intrinsics(cfg, images[0].width, images[0].height) is not None and not cfg.refine_intrinsics
    mapper = choose_mapper(cfg, len(names))

    def sift_pass(cams: list[dict], suffix: str = "") -> tuple[Path, dict, str, int]:
        """Extraction, matching and mapping of ``cams`` (stages and files named with ``suffix``): (the model's
        folder, the extraction's record, the matching, photos with GPS)."""
        features, database, model_dir = work / f"features{suffix}.db", work / f"database{suffix}.db", work / f"sparse{suffix}"

        def extraction() -> dict:
            with atomic_dir(work_masks) as tmp:
                n = write_colmap_masks([(im.name, im.width, im.height) for im in images], work / "images", masks, tmp,
                                       renamed)
            extract(work / "images", features, cams, cfg, work_masks if n else None)
            return {"masks": n}

        ext = stages.run(f"extraction{suffix}", {"cameras": cams, "sift": sift, "masks": masks and fingerprint(masks)},
                         extraction, outputs=[features, work_masks], optional=[work_masks])
        with_gps = gps_priors(features) if cfg.matching in ("auto", "spatial") and len(names) > 2 else 0
        matching = choose_matching(cfg, len(names), with_gps, video=src.is_file())
        if matching == "spatial" and with_gps < len(names) and not suffix:
            log.warning("--matching spatial: %d of %d photos carry no EXIF GPS and get no pairs",
                        len(names) - with_gps, len(names))
        # the extraction's settings: a change re-runs matching
        guided = any(c["sift_upscale"] > 1 or c.get("guided") for c in cams)
        pairing = {"sequential": {"overlap": cfg.sequential_overlap, "loops": cfg.sequential_loops},
                   "spatial": {"neighbors": cfg.spatial_neighbors, "max_distance": cfg.spatial_max_distance,
                               "ignore_z": cfg.spatial_ignore_z},
                   "retrieval": {"neighbors": cfg.retrieval_neighbors}}.get(matching)
        stages.run(f"matching{suffix}", {"matching": matching, "pairing": pairing, "seed": cfg.seed},
                   lambda: match(features, database, matching, cfg, guided), outputs=[database])
        stages.run(f"mapping{suffix}", {"mapper": mapper, "seed": cfg.seed, "fixed_intrinsics": fixed},
                   lambda: map_model(database, work / "images", model_dir, cfg, fixed, mapper), outputs=[model_dir])
        return model_dir, ext, matching, with_gps

    def registered(model_dir: Path) -> list[str]:
        rec = pycolmap.Reconstruction(str(model_dir))
        return sorted(rec.images[i].name for i in rec.reg_image_ids())

    # A pass that leaves images out is followed by SIFT again on the small photos upsampled 2x (guided
    # matching), then, while fewer than LOW_CONTRAST_RETRY_BELOW register, with a lower contrast threshold (a
    # ring of 12 grey 1280x1024 photos of a small object: 1.7k -> 6.9k features per image, 25-90 -> 100-200
    # inliers between neighbours), then, while fewer than WIDE_BASELINE_RETRY_BELOW register, with the best
    # pass's settings plus domain-size pooled descriptors and guided matching (a dark walnut ring, 30 degrees
    # between cameras: 0-40 -> 44-146 inliers between neighbours). The pass that registers the most images is kept.
    best: tuple | None = None  # (model_dir, extraction record, matching, photos with GPS, cameras, registered)
    error: SfMError | None = None

    def attempt(cams: list[dict], suffix: str = "") -> None:
        nonlocal best, error
        try:
            result = sift_pass(cams, suffix)
        except SfMError as exc:
            error = exc
            return
        reg = registered(result[0])
        if best is None or len(reg) > len(best[5]):
            best = (*result, cams, reg)

    def n_registered() -> int:
        return len(best[5]) if best else 0

    attempt(cameras)
    up = camera_groups(images, cfg, upscale_small=True)
    if any(c["sift_upscale"] > 1 for c in up) and n_registered() < len(names):
        log.info("%d of %d images registered; SIFT again on the photos under %d pixels upsampled 2x",
                 n_registered(), len(names), cfg.small_image_size)
        attempt(up, "_upsampled")
    if cfg.low_contrast_peak and n_registered() < LOW_CONTRAST_RETRY_BELOW * len(names):
        log.info("%d of %d images registered; SIFT again with a lower contrast threshold (%g)",
                 n_registered(), len(names), cfg.low_contrast_peak)
        attempt([dict(c, sift_peak=cfg.low_contrast_peak) for c in (best[4] if best else cameras)], "_lowcontrast")
    if cfg.wide_baseline_retry and n_registered() < WIDE_BASELINE_RETRY_BELOW * len(names):
        log.info("%d of %d images registered; SIFT again with domain-size pooling, matched guided (wide baselines)",
                 n_registered(), len(names))
        attempt([dict(c, dsp_sift=True, guided=True) for c in (best[4] if best else cameras)], "_widebaseline")
    if best is None:
        raise error or SfMError(no_model_message(work / "database.db", len(names)))
    model_dir, ext, matching, with_gps, cameras, reg_names = best
    unreg = [n for n in names if n not in set(reg_names)]
    if len(reg_names) < max(2, cfg.min_registered * len(names)):
        raise SfMError(f"{len(reg_names)} of {len(names)} images registered; not registered: "
                       + ", ".join(unreg[:10]) + (" ..." if len(unreg) > 10 else "")
                       + " (too little overlap or texture?)")
    if unreg:
        log.warning("%d of %d images not registered: %s", len(unreg), len(names), ", ".join(unreg))

    undistorted = work / "undistorted"
    stages.run("undistortion", {}, lambda: undistort(model_dir, work / "images", out, undistorted,
                                                     work_masks if ext.get("masks") else None),
               outputs=[layout.images, undistorted, layout.masks], optional=[layout.masks])
    model = publish(undistorted, out)
    secs = {name: s["seconds"] for name, s in stages.stats.items()}
    atomic_write_json(work / "sfm_report.json", {"registered": reg_names, "unregistered": unreg,
                                                 "skipped_files": ing["skipped"], "matching": matching,
                                                 "mapper": mapper, "photos_with_gps": with_gps,
                                                 "cameras": cameras, "seconds": secs, "cached": stages.cached})
    return SfMResult(model, reg_names, unreg, secs, stages.cached)
