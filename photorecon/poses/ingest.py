"""Ingest an image folder: find images (any letter case), decode them, apply EXIF orientation, read EXIF focal
length priors, and copy them into a working folder (the user's folder is never written to). A video file
gives every k-th frame instead. Given cameras (``--poses``) bring their images in through ``ingest_given``.

Photos given by camera files (``--poses``) are read from inside the image folder (``io.paths.inside``); every
photo needs a name photorecon can name its files after (``io.paths.check_name_length``), and no two
photos may be one view (``view_000.png`` and ``view_000.jpg``: ``io.paths.check_distinct_views``)."""
from __future__ import annotations

import hashlib
import logging
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..cameras import Intrinsics
from ..errors import BadArgumentError, InputDataError, NoImagesError, SfMError
from ..io.atomic import atomic_path
from ..io.images import image_write_failed, open_photo, read_bgr
from ..io.paths import HEIF_SUFFIXES, IMAGE_SUFFIXES, check_distinct_views, check_name_length, inside

log = logging.getLogger("photorecon")

# formats COLMAP's image reader cannot decode (pycolmap 4.x): ingested as PNG copies
COLMAP_UNREADABLE = (".webp",) + HEIF_SUFFIXES
VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm")
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


def not_a_folder(path: str | Path) -> str:
    """Why ``path``, given as the folder of photos, is none: a missing path, an image file (pass its folder)
    or another file."""
    path = Path(path)
    if path.is_file() and path.suffix.lower() in IMAGE_SUFFIXES:
        return f"{path}: is an image file, not a folder; pass the folder that holds the photos ({path.parent})"
    if path.exists():
        return (f"{path}: is not a folder of photos nor a video ({' '.join(VIDEO_SUFFIXES)}); pass the folder "
                "that holds the photos")
    return f"{path}: no such image folder (or video file)"


def images_in_subfolders(folder: str | Path) -> list[tuple[Path, int]]:
    """(subfolder, image files in it) for each subfolder of ``folder`` (one level down, hidden ones skipped)
    that holds images: what a user who passed a project folder (``images/``) or a camera card (``DCIM/`` with
    ``100CANON/``, ``101CANON/``) meant. photorecon reads only the folder's own photos."""
    out = []
    for sub in sorted(p for p in Path(folder).iterdir() if p.is_dir() and not p.name.startswith(".")):
        try:
            n = sum(1 for p in sub.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
        except OSError:  # a subfolder that cannot be listed holds nothing photorecon could read
            continue
        if n:
            out.append((sub, n))
    return out


def subfolders_hint(folder: str | Path, subs: list[tuple[Path, int]]) -> str:
    """What to pass instead, for the subfolders ``images_in_subfolders`` found: a project's ``images/`` (next
    to ``masks/``, ``depth/``) when there is one."""
    named = [(s, n) for s, n in subs if s.name.lower() == "images"]
    subs = named or subs
    if len(subs) == 1:
        sub, n = subs[0]
        return f"its subfolder {sub.name}/ holds {n} image(s): pass {sub}"
    listed = ", ".join(f"{s.name}/ ({n})" for s, n in subs[:6]) + (" ..." if len(subs) > 6 else "")
    return (f"its subfolders {listed} hold images: photorecon reads the photos of one folder; pass one, or "
            "put the photos together in one folder")


def list_images(folder: str | Path) -> tuple[list[Path], list[Path]]:
    """(image files sorted by name, other files) in ``folder`` (not recursive; hidden files skipped). The photos
    are the folder's own entries, named by nobody but the user who made it: a link to a photo elsewhere (a common
    way to pick a subset) is read. Names written in camera or dataset files go through ``io.paths.inside``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise NoImagesError(not_a_folder(folder))
    files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    imgs = [p for p in files if p.suffix.lower() in IMAGE_SUFFIXES]
    return imgs, [p for p in files if p.suffix.lower() not in IMAGE_SUFFIXES]


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


def check_photo_name(path: Path) -> None:
    """Refuse a photo whose name holds a line break or another control character: COLMAP's text models (and
    photorecon's, ``sparse/0/images.txt``) hold one image name per line. Raises ``InputDataError``."""
    name = path.name
    if len(name.splitlines()) != 1 or any(ord(c) < 32 or ord(c) == 127 for c in name):
        raise InputDataError(f"{path.parent / repr(name)[1:-1]}: the photo's name holds a line break or a control "
                             "character, which COLMAP's text models (one image name per line) cannot hold; rename it")


# why a photo is left out: the reasons of the one warning, in its order
TRUNCATED = "truncated or damaged (an incomplete copy or download?)"
UNREADABLE = "not readable images"
TOO_SMALL = f"under {MIN_SIDE} pixels a side (too small for SIFT)"
TOO_NARROW = f"longer than {MAX_ASPECT:g}:1 (too narrow for SIFT)"
FLAT = "a single flat colour (nothing to match in them)"
MASKED_OUT = "their masks exclude every pixel"


@dataclass
class _Photo:
    """What the gate learnt of a photo that passed it (``_inspect``)."""

    sample: np.ndarray  # BGR pixels: the whole image, or its 1/8-scale thumbnail (JPEG)
    size: tuple[int, int]  # (width, height), EXIF orientation applied
    orientation: int
    focal_frac: float | None  # EXIF focal length / the long side


def _inspect(p: Path) -> _Photo | tuple[str, str]:
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


def _listed(names: list[str], most: int = 20) -> str:
    return ", ".join(names[:most]) + (" ..." if len(names) > most else "")


def ingest_folder(folder: str | Path, work: str | Path, min_images: int = 1,
                  left_out: dict[str, str] | None = None) -> Ingest:
    """The image gate: every photo of ``folder`` is decoded once and checked (``_inspect``: readable and
    complete, EXIF orientation applied, a size and shape COLMAP's SIFT takes, not one flat colour); the photos
    that pass are copied to ``work``, upright. A JPEG upright as stored is byte-copied; a photo turned by its
    EXIF orientation is written turned, its other EXIF (GPS, focal length) kept. A format COLMAP cannot read
    (``COLMAP_UNREADABLE``: WebP, HEIC) becomes a PNG copy named NAME.png (NAME.EXT.png when another photo is
    named NAME.png); ``Ingest.renamed`` maps such working names to the photos' names. ``left_out``: photos
    already judged unusable, {name: reason} (their masks exclude every pixel: ``check_sfm_masks``).

    What is left out, and why, is named in one warning; so are EXIF focal lengths too implausible to be a prior
    (``FOCAL_FRAC_RANGE``), which SfM then estimates. A name COLMAP's text format cannot hold is refused before
    any photo is read (``check_photo_name``). Raises ``NoImagesError`` when fewer than ``min_images`` usable
    images remain."""
    folder, work = Path(folder), Path(work)
    paths, others = list_images(folder)
    working = _working_names(paths, others)
    for p in paths:
        check_name_length(p)
        check_photo_name(p)
    check_distinct_views(((Path(working[p]).stem, p.name) for p in paths), str(folder))
    work.mkdir(parents=True, exist_ok=True)
    left_out = left_out or {}
    out, left, implausible = [], {}, []
    names, pictures = set(), set()
    renamed: dict[str, str] = {}  # working name -> the photo's name, for photos converted to PNG
    for p in paths:
        photo = (left_out[p.name], p.name) if p.name in left_out else _inspect(p)
        if isinstance(photo, tuple):
            left.setdefault(photo[0], []).append((p.name, photo[1]))
            continue
        if p.name.lower() in names:
            raise InputDataError(f"{folder}: two images named {p.name!r} differing only in letter case")
        names.add(p.name.lower())
        pictures.add(hashlib.blake2b(photo.sample.data, digest_size=16).digest())
        focal_frac = photo.focal_frac
        if focal_frac and not FOCAL_FRAC_RANGE[0] <= focal_frac <= FOCAL_FRAC_RANGE[1]:
            fov = np.degrees(2 * np.arctan(0.5 / focal_frac))
            implausible.append(f"{p.name} ({focal_frac * 36:.4g} mm equivalent, {fov:.2g} degrees across)")
            focal_frac = None
        name = working[p]
        if name != p.name:
            renamed[name] = p.name
        dst = work / name
        W, H = photo.size
        if not dst.exists():
            with atomic_path(dst) as tmp:
                if name != p.name:
                    W, H = _png_copy(p, tmp)
                elif photo.orientation in (0, 1):
                    shutil.copyfile(p, tmp)  # byte copy keeps EXIF for COLMAP
                else:
                    _oriented_copy(p, tmp)
        out.append(IngestedImage(name, p, W, H, focal_frac * max(W, H) if focal_frac else None))
    if others:
        left.setdefault(UNREADABLE, []).extend((p.name, p.name) for p in others)
    reasons = [r for r in (TRUNCATED, UNREADABLE, TOO_SMALL, TOO_NARROW, FLAT, MASKED_OUT) if r in left]
    skipped = [name for r in reasons for name, _ in left[r]]

    def listed(r: str, most: int = 20) -> str:
        return f"{r}: {_listed([label for _, label in left[r]], most)}"

    if left:
        log.warning("left out %d of %d file(s): %s", len(skipped), len(paths) + len(others),
                    "; ".join(listed(r) for r in reasons))
    if implausible:
        log.warning("EXIF focal length not used as a prior for %d photo(s), outside what lenses and sensors allow "
                    "(a field of view of 1 to about 160 degrees); SfM estimates it: %s", len(implausible),
                    _listed(implausible, 5))
    subs = images_in_subfolders(folder)
    if len(out) < min_images:
        decodable = sum(len(left.get(r, [])) for r in (TOO_SMALL, TOO_NARROW, FLAT, MASKED_OUT))
        if not out and decodable and decodable == len(left.get(FLAT, [])):
            n = len(left[FLAT])
            raise NoImagesError(f"{folder}: all {n} photo(s) are a single flat colour (all black? a lens cap, a "
                                "failed exposure?): SfM finds nothing to match in them; check the photos")
        word = "usable" if decodable else "readable"  # photos left out by the gate, or none that decodes
        found = f"{len(out)} {word} image(s)" if out else f"no {word} image"
        need = f"; at least {min_images} needed" if out else ""  # none: the count needed says nothing more
        why = f"; left out: {'; '.join(listed(r, 5) for r in reasons)}" if decodable else ""
        hint = f"; {subfolders_hint(folder, subs)}" if subs else ""
        formats = ", ".join(x.lstrip(".") for x in IMAGE_SUFFIXES)
        raise NoImagesError(f"{folder}: {found} ({formats}){need}{why}{hint}")
    if subs:
        log.warning("%s: the images in its subfolders are not read (%s); only the %d photo(s) in the folder "
                    "itself are used", folder, ", ".join(f"{s.name}/: {n}" for s, n in subs[:6])
                    + (" ..." if len(subs) > 6 else ""), len(out))
    if len(out) >= 2 and len(pictures) == 1:
        raise SfMError(f"{folder}: all {len(out)} photos are the same picture (copies of one file?); SfM needs "
                       "photos of the scene from several viewpoints")
    return Ingest(out, skipped, renamed)


def _working_names(paths: list[Path], others: list[Path]) -> dict[Path, str]:
    """Each photo's name in the working folder: its own, or for a format COLMAP cannot read
    (``COLMAP_UNREADABLE``) a PNG copy's, NAME.png (NAME.EXT.png when another file is named NAME.png)."""
    taken = {p.name.lower() for p in paths + others}
    working = {}
    for p in paths:
        name = p.name
        if p.suffix.lower() in COLMAP_UNREADABLE:
            name = f"{p.stem}.png" if f"{p.stem}.png".lower() not in taken else f"{p.name}.png"
            taken.add(name.lower())
        working[p] = name
    return working


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


def _oriented_copy(src: Path, dst: Path) -> None:
    """``src`` turned upright by its EXIF orientation, in its own format at ``dst`` (a JPEG at quality 95), its
    other EXIF kept (the GPS position that spatial matching reads, the focal length), its orientation reset;
    alpha kept."""
    from PIL import Image, ImageOps

    try:
        with open_photo(src) as im:
            fmt = im.format
            im = ImageOps.exif_transpose(im)
            exif = im.getexif()
            exif[0x0112] = 1
            kw = {"exif": exif.tobytes()} if fmt in ("JPEG", "PNG", "WEBP") else {}
            if fmt == "JPEG":
                im = im.convert("L" if im.mode in ("L", "I;16", "I", "1") else "RGB")
                kw.update(quality=95)
            im.save(dst, fmt or Image.registered_extensions().get(src.suffix.lower(), "PNG"), **kw)
    except OSError as exc:
        raise InputDataError(f"{src}: could not write it upright (its EXIF orientation) for SfM ({exc})") from None


def _png_copy(src: Path, dst: Path) -> tuple[int, int]:
    """``src`` as a PNG at ``dst``, EXIF orientation applied, alpha kept (a mask for SfM and depth); returns
    its (width, height)."""
    from PIL import ImageOps

    try:
        with open_photo(src) as im:
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
    """Every ``every``-th decoded frame of a video file as PNG images in ``work`` (frame_00000.png, ...). Frames
    that do not decode are passed over, and a warning says how many of the video's frames could be decoded.
    Frames COLMAP's SIFT cannot take (under ``MIN_SIDE`` pixels a side, longer than ``MAX_ASPECT``:1) raise
    ``NoImagesError``."""
    video, work = Path(video), Path(work)
    if every < 1:
        raise BadArgumentError(f"--video-every: expected a positive frame step, got {every}")
    if video.is_file() and video.stat().st_size == 0:
        raise NoImagesError(f"{video}: the video file is empty (0 bytes)")
    # FFmpeg prints its own line about a file it cannot read (``moov atom not found``): photorecon's one line
    # says it; the level is read when OpenCV first opens a video, and a level the user set is kept
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise NoImagesError(f"{video}: cannot open the video (unsupported codec or not a video)")
    work.mkdir(parents=True, exist_ok=True)
    total = max(0, int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0))  # the container's count (0: not known)
    out, k, failed = [], 0, 0
    try:
        while True:
            ok, frame = cap.read()
            if not ok:  # the end, or a frame that does not decode: read on while the count says more follow
                failed += 1
                if k + failed >= total:
                    break
                continue
            if k == 0 and (min(frame.shape[:2]) < MIN_SIDE or max(frame.shape[:2]) > MAX_ASPECT * min(frame.shape[:2])):
                H, W = frame.shape[:2]
                raise NoImagesError(f"{video}: its frames are {W}x{H}, "
                                    + (TOO_SMALL if min(H, W) < MIN_SIDE else TOO_NARROW))
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
        raise NoImagesError(f"{video}: no frame could be decoded" + (f" (of {total})" if total else ""))
    if k < total:
        log.warning("%s: %d of %d frames could be decoded (a damaged or incomplete video?); %d of them taken "
                    "(every %d-th)", video, k, total, len(out), every)
    else:
        log.info("video: %d of %d frames taken (every %d-th)", len(out), k, every)
    return Ingest(out)


def ingest_given(model, images_dir: Path, out: Path, masks_dir: Path | None = None):
    """Given cameras (``--poses``): copy each view's image from ``images_dir`` into OUT/images as NAME.png,
    undistorted with OpenCV for a distorted camera (``cv2.undistort``; ``cv2.fisheye`` for OPENCV_FISHEYE),
    and return the model with undistorted pinhole cameras. An image's mask in ``masks_dir`` (NAME.EXT.png or
    NAME.png, 0 = ignore), else its alpha channel (RGBA, grey + alpha), becomes OUT/masks/NAME.png (255 where
    > 0), undistorted like the image, so the depth and fusion stages use it as a mask.

    Every image is found first, before anything is written: inside ``images_dir`` (``io.paths.inside``), under
    a name photorecon can name its files after; a view's camera file names it (``image_file``), else NAME.EXT
    for any image extension. Truncated or damaged images are skipped with a warning."""
    from ..cameras import View
    from ..io.colmap_text import SparseModel
    from ..io.images import damaged_image, mask_file, read_alpha, read_image, read_mask, write_image
    from ..layout import Layout

    images_dir = Path(images_dir)
    sources, missing = {}, []
    for v in model.views:
        try:
            sources[v.name] = _given_image(images_dir, v)
        except _MissingImage as exc:
            missing.append((v.name, exc))
    if missing:
        first = str(missing[0][1])
        if len(missing) > 1:
            names = ", ".join(n for n, _ in missing[:5]) + (" ..." if len(missing) > 5 else "")
            first += f" ({len(missing)} of the {len(model.views)} views' images are not there: {names})"
        raise InputDataError(f"{first}; pass the folder that holds the photos the cameras file names, or take "
                             "those views out of it")
    check_distinct_views(((Path(p.name).stem, str(p.relative_to(images_dir))) for p in sources.values()),
                         str(images_dir))
    layout = Layout(out)
    img_out, mask_out = layout.images, layout.masks
    img_out.mkdir(parents=True, exist_ok=True)
    views, damaged = [], []
    for v in model.views:
        src = sources[v.name]
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
            img = undistort_image(img, intr)
            if mask is not None:  # same maps; outside the source image -> 0 (no data)
                mask = np.where(undistort_image(mask, intr) >= 128, 255, 0).astype(np.uint8)
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


class _MissingImage(InputDataError):
    """A given camera's image is not in the image folder (``ingest_given`` names them all at once)."""


def _given_image(images_dir: Path, view) -> Path:
    """The image file of a given camera in ``images_dir``: the name its camera file gives, else the view's name
    with any image extension (in any letter case); inside ``images_dir`` and with a usable name."""
    name = view.image_file or view.name
    src = inside(images_dir, name, f"view {view.name}")
    if not src.is_file():
        stem = Path(name).stem
        cands = sorted(p for p in src.parent.iterdir() if p.stem == stem and p.suffix.lower() in IMAGE_SUFFIXES) \
            if src.parent.is_dir() else []
        if not cands:
            raise _MissingImage(f"view {view.name}: image {name} not found in {images_dir}")
        src = inside(images_dir, str(cands[0].relative_to(images_dir)), f"view {view.name}")
    check_name_length(src)
    return src


def undistort_image(img: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """``img`` taken through ``intr`` as its pinhole camera (same K) sees it: ``cv2.fisheye.undistortImage``
    for an OPENCV_FISHEYE camera, else ``cv2.undistort`` (k1 k2 p1 p2). Bilinear; outside the image = 0."""
    if intr.fisheye:
        return cv2.fisheye.undistortImage(img, intr.K, intr.dist_coeffs.reshape(4, 1), Knew=intr.K)
    return cv2.undistort(img, intr.K, intr.dist_coeffs, None, intr.K)
