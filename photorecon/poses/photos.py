"""The image gate for one photo: decoded once (a JPEG at 1/8 scale), its EXIF orientation and focal length prior
read, and judged usable by SfM or not (damaged, undecodable, too small or too narrow for COLMAP's SIFT, one flat
colour), with the reasons ``ingest.ingest_folder`` names in its one warning; and the images the pose stage takes
in (``IngestedImage``, ``Ingest``)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..io.images import open_photo, read_bgr

FLAT_STD = 2.0  # grey levels: a photo whose pixels vary less than this is one flat colour (nothing to match)
# COLMAP's SIFT (pycolmap 4.2, VLFeat's affine-shape detector) crashes the process (SIGSEGV) on an image whose short
# side is under 16 pixels as it works on it, whatever the first octave (measured: 15x15, 1600x15 crash; 16x16,
# 1600x16 do not): photos under twice that are left out, and extraction never downsizes one below it (sift_max_size)
MIN_SIDE = 32
# long side / short side: a 20000x20 strip is 1600x1.6 once downsized for SIFT; beyond 20:1 (a 360-degree
# panorama is 2:1 to 8:1) a photo is no view SfM can use
MAX_ASPECT = 20.0
# EXIF focal length priors outside these fractions of the long side are not trusted: over 57 is a field of view
# under 1 degree, under 0.1 wider than a fisheye's (a 3.6 mm lens on a 35 mm frame)
FOCAL_FRAC_RANGE = (0.1, 57.0)


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


def _exif(path: Path) -> tuple[int, float | None]:
    """(EXIF orientation, focal length prior as a fraction of the long side) or (1, None). A HEIC photo's
    orientation is applied by its decoder (1 here)."""
    try:
        with open_photo(path) as im:
            return _exif_of(im)
    except Exception:  # no EXIF or a format PIL cannot parse: no prior
        return 1, None


def _exif_of(im) -> tuple[int, float | None]:
    """``_exif`` of an open Pillow image."""
    try:
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
    except Exception:  # unparsable EXIF: no prior
        return 1, None


# why a photo is left out: the reasons of the one warning, in its order
TRUNCATED = "truncated or damaged (an incomplete copy or download?)"
UNREADABLE = "not readable images"
TOO_SMALL = f"under {MIN_SIDE} pixels a side (too small for SIFT)"
TOO_NARROW = f"longer than {MAX_ASPECT:g}:1 (too narrow for SIFT)"
FLAT = "a single flat colour (nothing to match in them)"
MASKED_OUT = "their masks exclude every pixel"


@dataclass
class _Photo:
    """What the gate learnt of a photo that passed it (``inspect_photo``)."""

    sample: np.ndarray  # BGR pixels: the whole image, or its 1/8-scale thumbnail (JPEG)
    size: tuple[int, int]  # (width, height), EXIF orientation applied
    orientation: int
    focal_frac: float | None  # EXIF focal length / the long side


def inspect_photo(p: Path) -> _Photo | tuple[str, str]:
    """The gate for one photo, which it decodes once: a ``_Photo``, or (reason, how to name it) when SfM cannot
    use it: damaged or truncated, not decodable, under ``MIN_SIDE`` pixels a side, longer than ``MAX_ASPECT``:1
    (COLMAP's SIFT crashes on both), or one flat colour (nothing to match)."""
    from ..io.images import damaged_image

    # a JPEG (copied as it is where it is upright) needs no full decode: Pillow's 1/8-scale DCT decode reads
    # every byte of its data (OpenCV decodes a truncated JPEG without an error, grey from where the data
    # stops: Pillow says so) and gives its size, its EXIF and a look at its content, in one opening
    look = _jpeg_look(p) if p.suffix.lower() in (".jpg", ".jpeg") else None
    if isinstance(look, str):
        return TRUNCATED, p.name
    if look is not None:
        img, size, orientation, focal_frac = look
    else:
        orientation, focal_frac = _exif(p)
        img = read_bgr(p)  # EXIF orientation applied
        if img is None or img.size == 0:
            return (TRUNCATED if damaged_image(p) else UNREADABLE), p.name
        size = (img.shape[1], img.shape[0])
        img = np.ascontiguousarray(img[::4, ::4])  # every 16th pixel (7 ms for 12 MP)
    w, h = size
    if min(w, h) < MIN_SIDE:
        return TOO_SMALL, f"{p.name} ({w}x{h})"
    if max(w, h) > MAX_ASPECT * min(w, h):
        return TOO_NARROW, f"{p.name} ({w}x{h})"
    if float(cv2.meanStdDev(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))[1][0, 0]) < FLAT_STD:
        return FLAT, p.name
    return _Photo(img, size, orientation, focal_frac)


def _jpeg_look(path: Path):
    """A JPEG in one opening: (its pixels at 1/8 scale, BGR, upright; its (width, height) upright; its EXIF
    orientation; its focal length prior as a fraction of the long side), or why it is damaged or truncated
    (a str, ``io.images.damaged_image``'s words), or None where Pillow cannot judge it (the caller decodes)."""
    from PIL import ImageFile, ImageOps

    keep = ImageFile.LOAD_TRUNCATED_IMAGES
    ImageFile.LOAD_TRUNCATED_IMAGES = False
    try:
        with open_photo(path) as im:
            orientation, focal = _exif_of(im)
            w, h = im.size
            im.draft("RGB", (max(1, w // 8), max(1, h // 8)))
            try:
                im.load()
            except (OSError, SyntaxError, ValueError) as exc:
                text = str(exc)
                if "truncated" in text or "broken" in text or "end of" in text.lower():
                    return "truncated: the file ends before the image data does (an incomplete copy or download?)"
                return f"damaged: {text}"
            thumb = ImageOps.exif_transpose(im) if orientation not in (0, 1) else im
            rgb = np.asarray(thumb.convert("RGB"))
            size = (h, w) if orientation in (5, 6, 7, 8) else (w, h)
            return np.ascontiguousarray(rgb[..., ::-1]), size, orientation, focal
    except Exception:  # not readable by Pillow, or beyond its limits: the caller's full decode decides
        return None
    finally:
        ImageFile.LOAD_TRUNCATED_IMAGES = keep
