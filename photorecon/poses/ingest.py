"""Ingest an image folder: find images (any letter case), decode them, apply EXIF orientation, read EXIF focal
length priors, and copy them into a working folder (the user's folder is never written to). A video file
gives every k-th frame instead."""
from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..cameras import Intrinsics
from ..errors import BadArgumentError, InputDataError, NoImagesError
from ..io.atomic import atomic_path
from ..io.images import image_write_failed

log = logging.getLogger("photorecon")

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
# formats COLMAP's image reader cannot decode (pycolmap 4.x): ingested as PNG copies
COLMAP_UNREADABLE = (".webp",)
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm")



@dataclass
class IngestedImage:
    name: str  # file name in the working folder
    source: Path
    width: int
    height: int
    focal_prior_px: float | None = None  # from EXIF, in pixels of the oriented image


@dataclass
class Ingest:
    images: list[IngestedImage]
    skipped: list[str] = field(default_factory=list)
    renamed: dict[str, str] = field(default_factory=dict)  # working name -> photo's name (converted to PNG)


def list_images(folder: str | Path) -> tuple[list[Path], list[Path]]:
    """(image files sorted by name, other files) in ``folder`` (not recursive)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise NoImagesError(f"{folder}: no such image folder")
    files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    imgs = [p for p in files if p.suffix.lower() in IMAGE_SUFFIXES]
    return imgs, [p for p in files if p.suffix.lower() not in IMAGE_SUFFIXES]


def _exif(path: Path) -> tuple[int, float | None]:
    """(EXIF orientation, focal length prior as a fraction of the long side) or (1, None)."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            exif = im.getexif()
            orientation = int(exif.get(0x0112, 1) or 1)
            sub = exif.get_ifd(0x8769) if hasattr(exif, "get_ifd") else {}
            f35 = sub.get(0xA405) or exif.get(0xA405)
            if f35:
                return orientation, float(f35) / 36.0
            f_mm = sub.get(0x920A) or exif.get(0x920A)
            xres = sub.get(0xA20E)  # FocalPlaneXResolution
            unit = sub.get(0xA210, 2)  # FocalPlaneResolutionUnit: 2 = inch, 3 = cm, 4 = mm
            w = sub.get(0xA002) or im.width
            if f_mm and xres:
                mm_per_unit = {2: 25.4, 3: 10.0, 4: 1.0}.get(int(unit), 25.4)
                sensor_w_mm = float(w) / float(xres) * mm_per_unit
                if sensor_w_mm > 0:
                    return orientation, float(f_mm) / sensor_w_mm * (float(w) / max(im.width, im.height))
            return orientation, None
    except Exception:  # no EXIF or a format PIL cannot parse: no prior
        return 1, None


def ingest_folder(folder: str | Path, work: str | Path, min_images: int = 1) -> Ingest:
    """Decode every image of ``folder``; copy the readable ones to ``work`` (EXIF orientation applied). A
    format COLMAP cannot read (``COLMAP_UNREADABLE``: WebP) becomes a PNG copy named NAME.png (NAME.EXT.png when
    another photo is named NAME.png); ``Ingest.renamed`` maps such working names to the photos' names.

    Truncated or damaged images (``io.images.damaged_image``) are skipped with one warning that names them;
    unreadable and non-image files with one more. Raises ``NoImagesError``
    when fewer than ``min_images`` readable images remain.
    """
    from ..io.images import damaged_image

    folder, work = Path(folder), Path(work)
    paths, others = list_images(folder)
    work.mkdir(parents=True, exist_ok=True)
    out, bad, truncated = [], [], []
    names = set()
    all_names = {p.name.lower() for p in paths + others}
    renamed: dict[str, str] = {}  # working name -> the photo's name, for photos converted to PNG
    for p in paths:
        # OpenCV decodes a truncated JPEG without an error (grey from where the data stops): check it first
        jpeg = p.suffix.lower() in (".jpg", ".jpeg")
        why = damaged_image(p) if jpeg else None
        orientation, focal_frac = _exif(p)
        # a JPEG byte-copied as it is was decoded to its end (at 1/8 scale) by damaged_image: its size is enough
        # (a full decode of a 24 MP photo costs about 0.2 CPU s, and COLMAP decodes it again)
        img = None if why else _header_only(p) if jpeg and orientation in (0, 1) else cv2.imread(str(p), cv2.IMREAD_COLOR)
        if img is None or img.size == 0:  # OpenCV applies EXIF orientation
            why = why or damaged_image(p)
            (truncated if why else bad).append(p.name)
            continue
        if p.name.lower() in names:
            raise InputDataError(f"{folder}: two images named {p.name!r} differing only in letter case")
        names.add(p.name.lower())
        name = p.name
        if p.suffix.lower() in COLMAP_UNREADABLE:  # a PNG copy, named NAME.png (NAME.EXT.png if that is taken)
            name = f"{p.stem}.png" if f"{p.stem}.png".lower() not in all_names else f"{p.name}.png"
            all_names.add(name.lower())
            renamed[name] = p.name
        dst = work / name
        H, W = img.shape[:2]
        if not dst.exists():
            with atomic_path(dst) as tmp:
                if name != p.name:
                    W, H = _png_copy(p, tmp)
                elif orientation in (0, 1):
                    shutil.copyfile(p, tmp)  # byte copy keeps EXIF for COLMAP
                elif not cv2.imwrite(str(tmp), img):
                    image_write_failed(dst, img.nbytes)
        out.append(IngestedImage(name, p, W, H, focal_frac * max(W, H) if focal_frac else None))
    if truncated:
        log.warning("skipped %d truncated or damaged image file(s) (an incomplete copy or download?): %s",
                    len(truncated), ", ".join(truncated[:20]) + (" ..." if len(truncated) > 20 else ""))
    skipped = truncated + bad + [p.name for p in others]
    if len(skipped) > len(truncated):
        rest = skipped[len(truncated):]
        log.warning("skipped %d file(s) that are not readable images: %s", len(rest),
                    ", ".join(rest[:20]) + (" ..." if len(rest) > 20 else ""))
    if len(out) < min_images:
        found = f"{len(out)} readable image(s)" if out else "no readable image"
        need = f"; at least {min_images} needed" if out else ""  # none: the count needed says nothing more
        raise NoImagesError(f"{folder}: {found} (jpg, jpeg, png, tif, tiff, bmp, webp){need}")
    return Ingest(out, skipped, renamed)


def _header_only(path: Path) -> np.ndarray | None:
    """A stand-in for the pixels of a JPEG that is copied as it is: a zero array of its shape (height, width,
    3) from its header (no decode); OpenCV's full decode where Pillow cannot open it."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            w, h = im.size
    except Exception:  # not readable by Pillow: the caller's full decode decides
        return cv2.imread(str(path), cv2.IMREAD_COLOR)
    return np.broadcast_to(np.zeros(1, np.uint8), (h, w, 3))


def _png_copy(src: Path, dst: Path) -> tuple[int, int]:
    """``src`` as a PNG at ``dst``, EXIF orientation applied, alpha kept (a mask for SfM and depth); returns
    its (width, height)."""
    from PIL import Image, ImageOps

    try:
        with Image.open(src) as im:
            im = ImageOps.exif_transpose(im)
            if im.mode not in ("1", "L", "LA", "I;16", "RGB", "RGBA"):
                im = im.convert("RGBA" if "A" in im.getbands() else "RGB")
            im.save(dst, "PNG", compress_level=1)
            return im.size
    except OSError as exc:
        raise InputDataError(f"{src}: could not convert it to PNG for SfM ({exc})") from None


def read_K(path: str | Path, width: int, height: int) -> Intrinsics:
    """A 3x3 K text file (pixel (0, 0) at the centre of the top-left pixel) -> ``Intrinsics``."""
    path = Path(path)
    try:
        K = np.loadtxt(path, dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise InputDataError(f"{path}: cannot read a 3x3 K matrix ({exc})") from None
    if K.shape != (3, 3):
        raise InputDataError(f"{path}: expected a 3x3 K matrix, got shape {K.shape}")
    try:
        return Intrinsics.from_K(K, width, height)
    except BadArgumentError as exc:
        raise InputDataError(f"{path}: {exc}") from None


def video_frames(video: str | Path, work: str | Path, every: int = 10) -> Ingest:
    """Every ``every``-th frame of a video file as PNG images in ``work`` (frame_00000.png, ...)."""
    video, work = Path(video), Path(work)
    if every < 1:
        raise BadArgumentError(f"--video-every: expected a positive frame step, got {every}")
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise NoImagesError(f"{video}: cannot open the video (unsupported codec or not a video)")
    work.mkdir(parents=True, exist_ok=True)
    out, k = [], 0
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if k % every == 0:
                name = f"frame_{k:05d}.png"
                if not (work / name).exists():
                    with atomic_path(work / name) as tmp:
                        if not cv2.imwrite(str(tmp), frame):
                            image_write_failed(work / name, frame.nbytes)
                H, W = frame.shape[:2]
                out.append(IngestedImage(name, video, W, H))
            k += 1
    finally:
        cap.release()
    if not out:
        raise NoImagesError(f"{video}: no frame could be decoded")
    log.info("video: %d of %d frames taken (every %d-th)", len(out), k, every)
    return Ingest(out)
