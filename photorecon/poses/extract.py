"""SfM's first stage, feature extraction (``extract``): one COLMAP camera per image size (``camera_groups``),
SIFT into a new COLMAP database, on 2x upsampled copies for small photos, as many threads as fit in memory
(``sift_threads``), the images then numbered by name (the same photos give the same model every run)."""
from __future__ import annotations

import logging
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..cameras import Intrinsics
from ..conventions import colmap_from_intrinsics
from ..errors import BadArgumentError, InputDataError
from ..io.atomic import atomic_path
from ..io.space import check_space
from ..progress import running
from ._colmap import MB, _pycolmap
from .sfm_inputs import _upscaled_copies

if TYPE_CHECKING:
    from .sfm import SfMConfig

log = logging.getLogger("photorecon")


def _given_intrinsics(cfg: SfMConfig, width: int, height: int) -> Intrinsics | None:
    from .given import read_K

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


# the shortest side SIFT works on: COLMAP's SIFT crashes (SIGSEGV) under 16 pixels (photos.MIN_SIDE)
SIFT_MIN_SIDE = 32


def sift_max_size(max_image_size: int, width: int, height: int) -> int:
    """The longest side SIFT may downsize a ``width`` x ``height`` image to: ``max_image_size``, or more where
    that would leave its short side under ``SIFT_MIN_SIDE`` pixels (a long, narrow photo with a small
    --max-image-size)."""
    short, long = sorted((max(width, 1), max(height, 1)))
    return max(max_image_size, -(-SIFT_MIN_SIDE * long // short))


def _drop_implausible_focal(database: Path, image_name: str) -> None:
    """The camera of ``image_name`` without the focal length prior COLMAP read from its EXIF, where that is
    outside what lenses allow (``photos.FOCAL_FRAC_RANGE``, which the image gate named in its warning): its
    focal length set to COLMAP's guess (1.2 times the long side) and not treated as known. A prior of 10000 mm
    (0.2 degrees) let 29 pairs match but no model start."""
    from .photos import FOCAL_FRAC_RANGE

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
