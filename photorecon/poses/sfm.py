"""Structure from motion through pycolmap (with ``io.colmap``, ``triangulate`` and ``retrieval``, the only modules that import it; its API changes
between versions; pycolmap 4.x: ``image.cam_from_world()`` is a method).

Stages, each a function that writes one output and returns its path (hloc's style), run by the stage runner
(``photorecon.stages``) so that a re-run reuses a stage while its inputs and settings are unchanged:
ingest (oriented copies of the images, ``OUT/colmap/images``) -> ``extract`` (SIFT, ``OUT/colmap/features.db``)
-> ``match`` (exhaustive / retrieval (``retrieval.py``) / sequential / spatial by EXIF GPS, chosen by count, video and GPS;
``OUT/colmap/database.db``)
-> ``map`` (incremental, or global (GLOMAP) for large sets; the largest model, ``OUT/colmap/sparse``) -> ``undistort`` to pinhole images. Outputs in the synth
layout: ``OUT/images/`` (undistorted), ``OUT/sparse/0/`` (COLMAP text, pinhole) and ``OUT/transforms.json``.
Masks (a user's folder, else the images' alpha) go to extraction as ``OUT/colmap/masks/NAME.EXT.png`` (COLMAP's
naming) and, undistorted, to ``OUT/masks/NAME.png``.
Stage markers (settings hash, seconds, peak memory): ``OUT/colmap/.stages/``.
"""
from __future__ import annotations

import logging
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ..cameras import Intrinsics
from ..conventions import colmap_from_intrinsics
from ..errors import BadArgumentError, InputDataError, SfMError
from ..io.atomic import atomic_path, atomic_write_json
from ..io.colmap import sparse_from_pycolmap
from ..io.colmap_text import SparseModel, read_colmap_text, write_colmap_text
from ..io.space import check_space
from ..layout import Layout
from ..progress import running
from ..stages import Stages, atomic_dir, fingerprint, replace_dir
from .sfm_inputs import _exif, _undistort_masks, _upscaled_copies, check_sfm_masks, sfm_masks, write_colmap_masks
from ..fields import check_config, expect_config

log = logging.getLogger("photorecon")


def _pycolmap():
    import cv2  # noqa: F401  (first: OpenCV loaded after pycolmap crashes in its PNG writer, two zlib builds)
    import pycolmap

    return pycolmap


# --mapper auto maps globally from this many images: on 200 synthetic views GLOMAP was more accurate than
# incremental mapping with every matching (0.057-0.076 deg vs 0.078-0.102) at 0.9-1.7x its time (bench_sfm.py --large)
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
    mapper: Literal["auto", "incremental", "global"] = field(default="auto", metadata={"help": "COLMAP incremental or global (GLOMAP) mapping; auto = global from --global-min images on"})
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


def _quiet(pycolmap) -> None:
    """COLMAP logs every step, and its recoverable errors ("Failed to create any sparse model" before a retry
    with relaxed thresholds), to stderr; photorecon reports what failed in its own line, so COLMAP's log shows
    only with --verbose (its fatal errors always)."""
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 3


# --- the SfM stages: extract -> match -> map -> undistort, each writing one output and returning its path ----
@dataclass
class SfMResult:
    model: SparseModel  # undistorted (pinhole) cameras + sparse points, what the depth stage uses
    registered: list[str]
    unregistered: list[str]
    seconds: dict = field(default_factory=dict)
    cached: list[str] = field(default_factory=list)


def _given_intrinsics(cfg: SfMConfig, width: int, height: int) -> Intrinsics | None:
    from .ingest import read_K

    if cfg.intrinsics:
        return read_K(cfg.intrinsics, width, height)
    flags = (cfg.fx, cfg.fy, cfg.cx, cfg.cy)
    if any(v is not None for v in flags):
        if cfg.fx is None:
            raise BadArgumentError("intrinsics flags: --fx is required (with optional --fy, --cx, --cy)")
        return Intrinsics(width, height, cfg.fx, cfg.fy or cfg.fx,
                          (width - 1) / 2 if cfg.cx is None else cfg.cx, (height - 1) / 2 if cfg.cy is None else cfg.cy)
    return None


def camera_groups(images: list, cfg: SfMConfig, upscale_small: bool = False) -> list[dict]:
    """One COLMAP camera per image size (and EXIF focal prior): ``[{"model", "params", "images", "size",
    "sift_upscale"}]`` with ``params`` in COLMAP's convention ("" lets COLMAP guess), ``images`` the file names
    sharing it, ``size`` their [width, height] and ``sift_upscale`` the factor its images are upsampled by for
    SIFT (with ``upscale_small``: 2 below ``cfg.small_image_size`` pixels, else 1)."""
    groups: dict[tuple, list] = {}
    for im in images:
        groups.setdefault((im.width, im.height, round(im.focal_prior_px or 0, 1)), []).append(im.name)
    cameras = []
    for (w, h, f_prior), names in groups.items():
        given = _given_intrinsics(cfg, w, h)
        if given is not None:
            if (w, h) != (given.width, given.height) and cfg.intrinsics:
                raise InputDataError(f"{cfg.intrinsics}: intrinsics given for one image size, but "
                                     f"{names[0]} is {w}x{h}; give images of one size")
            model, params = "PINHOLE", colmap_from_intrinsics(given)[3]
        else:
            model, params = cfg.camera_model, []
            if f_prior:
                params = colmap_from_intrinsics(Intrinsics(w, h, f_prior, f_prior, (w - 1) / 2, (h - 1) / 2, model=model))[3]
        small = upscale_small and 0 < max(w, h) < cfg.small_image_size
        cameras.append({"model": model, "params": ",".join(repr(float(p)) for p in params), "images": names,
                        "size": [w, h], "sift_upscale": 2 if small else 1})
    return cameras


def _downscale_features(database: Path, names: list[str], s: int, width: int, height: int, params: str) -> None:
    """Features found on ``s``-times upsampled copies back to the original images: keypoint positions and affine
    shapes / ``s`` (COLMAP's pixel corner convention scales exactly), the camera back to ``width`` x ``height``
    (its given ``params``, else COLMAP's guess rescaled)."""
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(database))
    try:
        cams = set()
        for name in names:
            im = db.read_image_with_name(name)
            kp = db.read_keypoints(im.image_id).astype(np.float32)
            db.update_keypoints(im.image_id, kp / np.float32(s))
            cams.add(im.camera_id)
        for cid in cams:
            cam = db.read_camera(cid)
            cam.rescale(width, height)
            if params:
                cam.params = [float(p) for p in params.split(",")]
            db.update_camera(cam)
    finally:
        db.close()


# SIFT starts on the image upsampled 2x (first octave -1, COLMAP's default) only where the working image has fewer
# than this many pixels per feature wanted: above it the octaves from the image's own size already give
# --max-features, and COLMAP keeps the largest-scale features, so the upsampled octave's are computed to be
# thrown away (gold_cape, 1600x1600: 8.6k features from octave 0 alone; 3.6 -> 1.3 CPU s per photo).
OCTAVE0_PIXELS_PER_FEATURE = 250


def sift_first_octave(width: int, height: int, max_image_size: int, max_features: int) -> int:
    """SIFT's first octave for a ``width`` x ``height`` image (before any upsampled copy) worked on at
    ``max_image_size``: 0 where it has ``OCTAVE0_PIXELS_PER_FEATURE`` pixels per feature of ``max_features``,
    else -1 (COLMAP's default, the image upsampled 2x first)."""
    s = min(1.0, max_image_size / max(width, height, 1))
    return 0 if width * height * s * s >= OCTAVE0_PIXELS_PER_FEATURE * max_features else -1


def extract(images_dir: Path, database: Path, cameras: list[dict], cfg: SfMConfig, mask_dir: Path | None = None) -> Path:
    """SIFT features of the images in ``cameras`` (see ``camera_groups``) into a new COLMAP database; none
    where a mask in ``mask_dir`` (COLMAP's layout, ``write_colmap_masks``) is 0. A camera with ``sift_upscale``
    s > 1 is extracted on s-times upsampled copies (``_upscaled_copies``), its keypoints then scaled back: small
    photos give several times more features (12 views of the blob at 320x240: 0.8-1.3k -> 1.7-2.8k)."""
    pycolmap = _pycolmap()
    check_space(database, sum(features_bytes(images_dir, cam["images"], cfg, int(cam.get("sift_upscale", 1))) - MB
                              for cam in cameras) + MB)
    threads = sift_threads(cameras, cfg)  # as many SIFT threads as fit in memory (OutOfMemoryError: not one)
    with atomic_path(database) as tmp, tempfile.TemporaryDirectory(dir=database.parent, prefix=".upscaled") as up, \
            running(f"SfM feature extraction ({sum(len(c['images']) for c in cameras)} photos)"):
        for i, cam in enumerate(cameras):
            s = int(cam.get("sift_upscale", 1))
            src, masks, params = images_dir, mask_dir, cam["params"]
            if s > 1:
                work = Path(up) / str(i)
                work.mkdir()
                masks = _upscaled_copies(images_dir, mask_dir, cam["images"], s, work)
                src = work / "images"
                if params:
                    w, h = cam["size"]
                    c = pycolmap.Camera(model=cam["model"], width=w, height=h, params=[float(p) for p in params.split(",")])
                    c.rescale(w * s, h * s)
                    params = ",".join(repr(float(p)) for p in c.params)
            reader = pycolmap.ImageReaderOptions()
            reader.camera_model = cam["model"]
            reader.camera_params = params
            if masks is not None:
                reader.mask_path = str(masks)
            ext = pycolmap.FeatureExtractionOptions()
            ext.max_image_size = sift_max_size(cfg.max_image_size, *cam["size"]) * s
            ext.sift.max_num_features = cfg.max_features
            if cam.get("sift_peak"):
                ext.sift.peak_threshold = float(cam["sift_peak"])
            ext.sift.first_octave = sift_first_octave(*cam["size"], cfg.max_image_size, cfg.max_features)
            ext.sift.estimate_affine_shape = cfg.affine_sift
            ext.sift.domain_size_pooling = bool(cam.get("dsp_sift", cfg.dsp_sift))
            ext.num_threads = threads
            pycolmap.extract_features(str(tmp), str(src), image_names=cam["images"],
                                      camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                                      extraction_options=ext, device=pycolmap.Device.cpu)
            if s > 1:
                _downscale_features(tmp, cam["images"], s, *cam["size"], cam["params"])
            if not params:
                _drop_implausible_focal(tmp, cam["images"][0])
        _number_images_by_name(tmp)
    return database


# the shortest side SIFT works on: COLMAP's SIFT crashes (SIGSEGV) under 16 pixels (ingest.MIN_SIDE)
SIFT_MIN_SIDE = 32


def sift_max_size(max_image_size: int, width: int, height: int) -> int:
    """The longest side SIFT may downsize a ``width`` x ``height`` image to: ``max_image_size``, or more where
    that would leave its short side under ``SIFT_MIN_SIDE`` pixels (a long, narrow photo with a small
    --max-image-size)."""
    short, long = sorted((max(width, 1), max(height, 1)))
    return max(max_image_size, -(-SIFT_MIN_SIDE * long // short))


def _drop_implausible_focal(database: Path, image_name: str) -> None:
    """The camera of ``image_name`` without the focal length prior COLMAP read from its EXIF, where that is
    outside what lenses allow (``ingest.FOCAL_FRAC_RANGE``, which the image gate named in its warning): its
    focal length set to COLMAP's guess (1.2 times the long side) and not treated as known. A prior of 10000 mm
    (0.2 degrees) let 29 pairs match but no model start."""
    from .ingest import FOCAL_FRAC_RANGE

    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(database))
    try:
        cam = db.read_camera(db.read_image_with_name(image_name).camera_id)
        long = max(cam.width, cam.height)
        if not cam.has_prior_focal_length or FOCAL_FRAC_RANGE[0] <= cam.mean_focal_length() / long <= FOCAL_FRAC_RANGE[1]:
            return
        params = np.array(cam.params, np.float64)
        params[list(cam.focal_length_idxs())] = 1.2 * long
        cam.params = params
        cam.has_prior_focal_length = False
        db.update_camera(cam)
    finally:
        db.close()


def _number_images_by_name(database: Path) -> None:
    """Renumber the images of a features database in name order (with their frames and pose priors): COLMAP's
    extraction threads number them in the order they finish, and matching and mapping follow the numbers, so
    the same photos would give a slightly different model each run (poses apart by 1e-14 and the mesh by 0.1%
    of its faces on 16 synthetic views). A database with several images per frame (a rig) is left as it is."""
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(database))
    try:
        images = sorted(db.read_all_images(), key=lambda im: im.name)
        frames = {f.frame_id: f for f in db.read_all_frames()}
        if [im.image_id for im in images] == list(range(1, len(images) + 1)) or any(
                len(list(f.data_ids)) != 1 for f in frames.values()):
            return
        cameras, rigs, priors = db.read_all_cameras(), db.read_all_rigs(), db.read_all_pose_priors()
        data = [(im, db.read_keypoints(im.image_id), db.read_descriptors(im.image_id)) for im in images]
    finally:
        db.close()
    new_id = {im.image_id: k for k, (im, _, _) in enumerate(data, 1)}
    with atomic_path(database) as tmp:
        new = pycolmap.Database.open(str(tmp))
        try:
            for c in cameras:
                new.write_camera(c, use_camera_id=True)
            for r in rigs:
                new.write_rig(r, use_rig_id=True)
            for k, (im, keypoints, descriptors) in enumerate(data, 1):
                frame = pycolmap.Frame()
                frame.frame_id, frame.rig_id = k, frames[im.frame_id].rig_id
                frame.add_data_id(pycolmap.data_t(sensor_id=pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA,
                                                                              id=im.camera_id), id=k))
                new.write_frame(frame, use_frame_id=True)
                image = pycolmap.Image(name=im.name, camera_id=im.camera_id, image_id=k)
                image.frame_id = k
                new.write_image(image, use_image_id=True)
                new.write_keypoints(k, keypoints)
                new.write_descriptors(k, descriptors)
            for p in priors:
                p.corr_data_id = pycolmap.data_t(sensor_id=p.corr_data_id.sensor_id, id=new_id[p.corr_data_id.id])
                new.write_pose_prior(p)
        finally:
            new.close()


# SIFT extraction's memory per thread and working pixel (COLMAP's CPU SIFT, affine shapes, first octave
# upsampled): one 1600x1200 image in one thread, 470 MB above the process's 150 MB
SIFT_BYTES_PER_PIXEL = 250


def sift_threads(cameras: list[dict], cfg: SfMConfig) -> int:
    """The threads for SIFT extraction: ``cfg.threads`` (all cores for -1, at most one per image), fewer when
    that many images at once would not fit in the available memory; ``OutOfMemoryError`` when not even one
    does."""
    import os

    from ..errors import out_of_memory
    from ..resources import available_bytes

    per_thread = 0
    for cam in cameras:
        s = int(cam.get("sift_upscale", 1))
        w, h = (x * s for x in cam["size"])
        scale = min(1.0, cfg.max_image_size * s / max(w, h))
        per_thread = max(per_thread, SIFT_BYTES_PER_PIXEL * w * h * scale * scale)
    n_images = sum(len(cam["images"]) for cam in cameras)
    wanted = max(1, min((os.cpu_count() or 1) if cfg.threads == -1 else cfg.threads, n_images))
    avail = available_bytes()
    fit = int(avail // per_thread) if per_thread else wanted
    if fit < 1:
        raise out_of_memory("SfM feature extraction", per_thread, avail)
    if fit < wanted:
        log.info("SfM feature extraction: %d threads (memory for %d images at once)", fit, fit)
    return min(wanted, fit)


def gps_priors(database: Path) -> int:
    """How many images of a COLMAP database carry a position prior (COLMAP reads EXIF GPS at extraction)."""
    import math

    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(database))
    try:
        return sum(1 for p in db.read_all_pose_priors()
                   if p.has_position() and all(math.isfinite(x) for x in p.position))
    finally:
        db.close()


def choose_matching(cfg: SfMConfig, num_images: int, with_gps: int = 0, video: bool = False) -> str:
    """``cfg.matching``, or for ``auto``: exhaustive up to ``cfg.exhaustive_max`` images; above it sequential
    for the frames of a ``video``, spatial when every image has a GPS prior (``with_gps`` of them), else
    retrieval. Raises ``BadArgumentError`` for ``spatial`` with fewer than 2 geotagged images."""
    if cfg.matching == "spatial" and with_gps < 2:
        raise BadArgumentError(f"--matching spatial: {with_gps} of {num_images} photos carry EXIF GPS; "
                               "use --matching retrieval (unordered photos), sequential (ordered captures) or exhaustive")
    if cfg.matching != "auto":
        return cfg.matching
    if num_images <= cfg.exhaustive_max:
        return "exhaustive"
    if video:
        return "sequential"
    return "spatial" if with_gps >= num_images else "retrieval"


def choose_mapper(cfg: SfMConfig, num_images: int) -> str:
    if cfg.mapper != "auto":
        return cfg.mapper
    return "global" if num_images >= cfg.global_min else "incremental"


def match(features: Path, database: Path, matching: str, cfg: SfMConfig, guided: bool = False) -> Path:
    """Match the features of the ``features`` database into a copy of it, ``database``; ``matching``:
    exhaustive, retrieval (the most similar photos by a visual index of the photos' own features, plus
    loop-closing pairs: ``retrieval.match_retrieval``), sequential (file-name order; loops closed by matching
    keyframes, ``_match_keyframes``, since COLMAP's loop detection needs a vocabulary tree, a download) or
    spatial (nearest by the GPS position priors COLMAP read from EXIF). ``guided``: matches are searched again
    along the verified two-view geometry (small photos: 12 views of the blob at 320x240, the weakest pair's
    inliers 16 -> 39)."""
    from .retrieval import match_retrieval

    pycolmap = _pycolmap()
    check_space(database, 2 * features.stat().st_size + MB)  # a copy of the features, then the matches
    with atomic_path(database) as tmp, running(f"SfM matching ({matching})"):
        shutil.copyfile(features, tmp)
        mopt = pycolmap.FeatureMatchingOptions()
        mopt.num_threads = cfg.threads
        mopt.guided_matching = guided
        vopt = pycolmap.TwoViewGeometryOptions()
        vopt.ransac.random_seed = cfg.seed  # each pair's RANSAC seeded: the same inliers whichever thread runs it
        if matching == "exhaustive":
            pycolmap.match_exhaustive(str(tmp), matching_options=mopt, verification_options=vopt,
                                      device=pycolmap.Device.cpu)
        elif matching == "retrieval":
            match_retrieval(tmp, cfg.retrieval_neighbors, mopt, cfg.seed, cfg.threads, vopt)
        elif matching == "spatial":
            popt = pycolmap.SpatialPairingOptions()
            popt.max_num_neighbors = cfg.spatial_neighbors
            popt.max_distance = cfg.spatial_max_distance
            popt.ignore_z = cfg.spatial_ignore_z
            pycolmap.match_spatial(str(tmp), matching_options=mopt, pairing_options=popt, verification_options=vopt,
                                   device=pycolmap.Device.cpu)
        elif matching == "sequential":
            popt = pycolmap.SequentialPairingOptions()
            popt.overlap = cfg.sequential_overlap
            popt.quadratic_overlap = True
            pycolmap.match_sequential(str(tmp), matching_options=mopt, pairing_options=popt,
                                      verification_options=vopt, device=pycolmap.Device.cpu)
            if cfg.sequential_loops:
                _match_keyframes(tmp, max(1, cfg.sequential_overlap), mopt, vopt)
        else:
            raise BadArgumentError(f"--matching: unknown choice {matching!r}")
    return database


def _match_keyframes(database: Path, every: int, mopt, vopt=None) -> int:
    """Loop closure for sequential matching: every ``every``-th image in name order (sequential's order) matched
    with every other one not already matched with it. Returns the number of pairs added."""
    from .retrieval import database_images, match_pairs

    key = sorted(database_images(database).values())[::every]
    return match_pairs(database, [(a, b) for i, a in enumerate(key) for b in key[i + 1:]], mopt, vopt)


# The second SIFT pass with a lower contrast threshold runs when fewer than this fraction of the images register
# (a few unrelated photos among many do not cost a second extraction and matching).
LOW_CONTRAST_RETRY_BELOW = 0.75
# ... and the wide-baseline pass (domain-size pooling, guided matching) when fewer than this fraction register
WIDE_BASELINE_RETRY_BELOW = 0.9

# Incremental mapping tried again with these thresholds, one set after the other, while a model leaves images
# out: COLMAP's defaults ignore two-view tracks and want 100 inliers to start and 30 to register, too many for
# a few small photos (12 views of the blob at 320x240, 53-60 degrees apart: 7 -> 12 registered with the first).
RELAXED_MAPPING = (
    {"triangulation.ignore_two_view_tracks": False, "mapper.init_min_num_inliers": 50,
     "mapper.abs_pose_min_num_inliers": 15},
    {"triangulation.ignore_two_view_tracks": False, "mapper.init_min_num_inliers": 30,
     "mapper.init_min_tri_angle": 8.0, "mapper.abs_pose_min_num_inliers": 12, "mapper.abs_pose_min_inlier_ratio": 0.15},
)


# Incremental mapping runs on one thread, whatever --threads: bundle adjustment's threads sum in the order they
# finish, so the same matches gave cameras apart in their last digits (48 synthetic ring views at 320x240, two
# threads: 3 different models in 3 runs, poses 2e-15 apart) and, from there, now and then another model (another
# coordinate frame, another mesh). On one thread: the same model, byte for byte, 3 runs of 3, whatever the
# output folder's history; 9.3-11.0 CPU s against 11.4-12.2 on two threads (2026-11-28, 2 shared cores). On a
# machine with many cores the mapping's wall time grows towards its CPU time. Global mapping keeps its threads.
MAPPER_THREADS = 1


def _incremental_options(pycolmap, cfg: SfMConfig, fixed_intrinsics: bool, relaxed: dict | None = None):
    opt = pycolmap.IncrementalPipelineOptions()
    opt.random_seed = cfg.seed
    opt.num_threads = MAPPER_THREADS
    if fixed_intrinsics:
        opt.ba_refine_focal_length = False
        opt.ba_refine_principal_point = False
        opt.ba_refine_extra_params = False
    for key, value in (relaxed or {}).items():
        group, _, name = key.rpartition(".")
        setattr(getattr(opt, group) if group else opt, name, value)
    return opt


# named after the step, as hloc does; this module does not use the builtin map
def map(database: Path, images_dir: Path, model_dir: Path, cfg: SfMConfig, fixed_intrinsics: bool,  # noqa: A001
        mapper: str = "incremental") -> Path:
    """Incremental or global (``mapper``) mapping; writes the largest model, COLMAP binary, to ``model_dir``.
    Incremental mapping that leaves images out is tried again with relaxed thresholds (``RELAXED_MAPPING``);
    the model with the most images is kept."""
    pycolmap = _pycolmap()
    pycolmap.set_random_seed(cfg.seed)
    check_space(model_dir, database.stat().st_size // 2 + MB)
    n = sum(1 for _ in images_dir.iterdir())
    with tempfile.TemporaryDirectory(dir=model_dir.parent, prefix=".mapper") as runs, atomic_dir(model_dir) as tmp, \
            running(f"SfM {mapper} mapping ({n} photos)"):
        if mapper == "global":
            gopt = pycolmap.GlobalPipelineOptions()
            gopt.random_seed = cfg.seed
            gopt.num_threads = cfg.threads
            if fixed_intrinsics:
                gopt.mapper.bundle_adjustment.refine_focal_length = False
                gopt.mapper.bundle_adjustment.refine_principal_point = False
                gopt.mapper.bundle_adjustment.refine_extra_params = False
            recs = list(pycolmap.global_mapping(str(database), str(images_dir), runs, gopt).values())
        else:
            recs = []
            for i, relaxed in enumerate((None,) + RELAXED_MAPPING):
                if recs and max(r.num_reg_images() for r in recs) >= n:
                    break
                if relaxed:
                    log.info("mapping: %d of %d images registered; again with relaxed thresholds (%d)",
                             max((r.num_reg_images() for r in recs), default=0), n, i)
                run_dir = Path(runs) / str(i)
                run_dir.mkdir()
                opt = _incremental_options(pycolmap, cfg, fixed_intrinsics, relaxed)
                recs += list(pycolmap.incremental_mapping(str(database), str(images_dir), str(run_dir), opt).values())
        if not recs:
            raise SfMError(no_model_message(database, n))
        max(recs, key=lambda r: r.num_reg_images()).write_binary(str(tmp))
    return model_dir


def no_model_message(database: Path, n: int) -> str:
    """Why mapping made no model of ``n`` images, from the matches in ``database``: none verified (the photos
    do not overlap), or pairs matched that no model could start from."""
    pycolmap = _pycolmap()
    try:
        db = pycolmap.Database.open(str(database))
        try:
            pairs, inliers = db.num_verified_image_pairs(), db.num_inlier_matches()
        finally:
            db.close()
    except Exception:  # no database to read: say what is known
        pairs = inliers = 0
    if not pairs:
        return (f"0 of {n} images registered: no two images could be matched (do the photos overlap? are they "
                "all identical?)")
    return (f"0 of {n} images registered: {pairs} image pairs were matched ({inliers:,} inlier matches), but no "
            "model could be started from any of them (too little parallax between the photos, or a wrong focal "
            "length: check --intrinsics / --fx and the photos' EXIF)")


def undistort(model_dir: Path, images_dir: Path, out: Path, model_out: Path, mask_dir: Path | None = None) -> Path:
    """Undistort the model's images to pinhole cameras: ``out/images`` and the pinhole model (COLMAP text) in
    ``model_out``; and the masks of ``mask_dir`` (COLMAP's layout, NAME.EXT.png) into ``out/masks/NAME.png``
    (removed when there are none). Returns ``model_out``. ``publish`` then copies the model to
    ``out/sparse/0`` and ``out/transforms.json``, where metric scaling may rewrite it: the stage's own copy
    stays unscaled, so scaling never compounds and never invalidates this stage."""
    pycolmap = _pycolmap()
    layout = Layout(out)
    check_space(layout.images, 2 * sum(f.stat().st_size for f in images_dir.iterdir()) + MB)
    with tempfile.TemporaryDirectory(dir=out, prefix=".undistort") as und, running("SfM undistortion"):
        pycolmap.undistort_images(und, str(model_dir), str(images_dir))
        model = sparse_from_pycolmap(pycolmap.Reconstruction(f"{und}/sparse"))
        masks = Path(und) / "masks"
        masks.mkdir()
        n_masks = _undistort_masks(model_dir, model, mask_dir, masks) if mask_dir is not None else 0
        replace_dir(f"{und}/images", layout.images)
        if n_masks:
            replace_dir(masks, layout.masks)
        else:
            shutil.rmtree(layout.masks, ignore_errors=True)
    with atomic_dir(model_out) as tmp:
        write_colmap_text(model, tmp)
    return model_out


def publish(model_dir: Path, out: Path) -> SparseModel:
    """The undistorted model of ``model_dir`` (COLMAP text) as ``out/sparse/0`` and ``out/transforms.json``."""
    from ..io.nerf import write_transforms

    model = read_colmap_text(model_dir)
    layout = Layout(out)
    with atomic_dir(layout.sparse) as tmp:
        write_colmap_text(model, tmp)
    write_transforms(model.views, layout.transforms, world="none")
    return model


def _ingest(src: Path, work_images: Path, video_every: int, left_out: dict[str, str] | None = None) -> dict:
    """Oriented copies of the photos (or every k-th video frame) in ``work_images``; what SfM needs of them."""
    from .ingest import VIDEO_SUFFIXES, ingest_folder, video_frames

    photos = [src] if src.is_file() else [p for p in src.iterdir() if p.is_file()]
    check_space(work_images, 2 * sum(p.stat().st_size for p in photos) + MB)  # WebP becomes a larger PNG
    with atomic_dir(work_images) as tmp:
        if src.is_file() and src.suffix.lower() in VIDEO_SUFFIXES:
            ing = video_frames(src, tmp, video_every)
        else:
            ing = ingest_folder(src, tmp, min_images=1, left_out=left_out)
    return {"images": [[im.name, im.width, im.height, im.focal_prior_px] for im in ing.images],
            "skipped": ing.skipped, "renamed": ing.renamed}


MB = 1 << 20


def features_bytes(images_dir: Path, names: list[str], cfg: SfMConfig, upscale: int = 1) -> int:
    """About the most a COLMAP feature database of these images takes: per image
    min(max_features, pixels at max_image_size / 25) features of 160 bytes (128-byte descriptor, 6-float
    keypoint, SQLite's overhead; measured 156 on 320x240 renders, which gave one feature per 40-80 pixels).
    ``upscale`` s > 1 (SIFT on s-times upsampled copies, ``_upscaled_copies``): s times the features (measured
    2x for s = 2), plus the copies themselves: s^2 times the file or half a byte per upsampled pixel, whichever
    is more (measured on 320x240 renders: PNG 3.3x the file, JPEG at quality 95 4.9x)."""
    from ..io.images import image_size

    total = MB
    for n in names:
        try:
            w, h = image_size(images_dir / n)
        except Exception:  # unreadable here: the extraction will say so
            w, h = cfg.max_image_size, cfg.max_image_size
        s = min(1.0, cfg.max_image_size / max(w, h, 1))
        total += int(min(cfg.max_features, w * h * s * s / 25 * upscale) * 160)
        if upscale > 1:
            try:
                size = (images_dir / n).stat().st_size
            except OSError:
                size = 0
            total += upscale * upscale * max(size, w * h // 2)
    return total


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
    from .ingest import IngestedImage

    pycolmap = _pycolmap()
    cfg = expect_config(cfg, SfMConfig, "cfg")
    if not 0 <= cfg.min_registered <= 1:
        raise BadArgumentError(f"--min-registered: expected a fraction of the images, 0 to 1, got {cfg.min_registered:g}")
    _quiet(pycolmap)
    src, out = Path(images_dir), Path(out)
    masks = Path(masks) if masks else None
    left_out: dict[str, str] = {}
    if masks is not None:
        from .ingest import MASKED_OUT

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
                   lambda: map(database, work / "images", model_dir, cfg, fixed, mapper), outputs=[model_dir])
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
