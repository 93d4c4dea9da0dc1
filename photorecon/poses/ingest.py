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
    working = _working_names(paths, others)
    for p in paths:
        check_name_length(p)
    check_distinct_views(((Path(working[p]).stem, p.name) for p in paths), str(folder))
    work.mkdir(parents=True, exist_ok=True)
    out, bad, truncated, flat = [], [], [], []
    names, pictures = set(), set()
    renamed: dict[str, str] = {}  # working name -> the photo's name, for photos converted to PNG
    for p in paths:
        # OpenCV decodes a truncated JPEG without an error (grey from where the data stops): check it first
        jpeg = p.suffix.lower() in (".jpg", ".jpeg")
        why = damaged_image(p) if jpeg else None
        orientation, focal_frac = _exif(p)
        # a JPEG byte-copied as it is needs its size and a look at its content, not a full decode (about 0.2 CPU s
        # for 24 MP, and COLMAP decodes it again): its 1/8-scale DCT decode serves both
        img, size = _jpeg_thumbnail(p) if not why and jpeg and orientation in (0, 1) else (None, (0, 0))
        if img is None and not why:
            img, size = read_bgr(p), (0, 0)  # EXIF orientation applied
        if img is None or img.size == 0:
            why = why or damaged_image(p)
            (truncated if why else bad).append(p.name)
            continue
        if p.name.lower() in names:
            raise InputDataError(f"{folder}: two images named {p.name!r} differing only in letter case")
        names.add(p.name.lower())
        # every 16th pixel of a full decode (7 ms for 12 MP), all of a thumbnail
        sample = img if size[0] else np.ascontiguousarray(img[::4, ::4])
        if float(cv2.meanStdDev(cv2.cvtColor(sample, cv2.COLOR_BGR2GRAY))[1][0, 0]) < FLAT_STD:
            flat.append(p.name)
        pictures.add(hashlib.blake2b(sample.data, digest_size=16).digest())
        name = working[p]
        if name != p.name:
            renamed[name] = p.name
        dst = work / name
        W, H = size if size[0] else (img.shape[1], img.shape[0])
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
    subs = images_in_subfolders(folder)
    if len(out) < min_images:
        found = f"{len(out)} readable image(s)" if out else "no readable image"
        need = f"; at least {min_images} needed" if out else ""  # none: the count needed says nothing more
        hint = f"; {subfolders_hint(folder, subs)}" if subs else ""
        formats = ", ".join(x.lstrip(".") for x in IMAGE_SUFFIXES)
        raise NoImagesError(f"{folder}: {found} ({formats}){need}{hint}")
    if subs:
        log.warning("%s: the images in its subfolders are not read (%s); only the %d photo(s) in the folder "
                    "itself are used", folder, ", ".join(f"{s.name}/: {n}" for s, n in subs[:6])
                    + (" ..." if len(subs) > 6 else ""), len(out))
    _check_content(folder, len(out), flat, len(pictures))
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


def _check_content(folder: Path, n: int, flat: list[str], distinct: int) -> None:
    """Refuse photos SfM cannot match, naming the likely cause: every one a single flat colour (black frames,
    a lens cap, a blown exposure) is ``NoImagesError``; two or more that are all the same picture is
    ``SfMError``. Some flat photos among good ones are only named in a warning."""
    if flat and len(flat) == n:
        raise NoImagesError(f"{folder}: all {n} photo(s) are a single flat colour (all black? a lens cap, a failed "
                            "exposure?): SfM finds nothing to match in them; check the photos")
    if flat:
        log.warning("%d photo(s) are a single flat colour (nothing to match in them): %s", len(flat),
                    ", ".join(flat[:20]) + (" ..." if len(flat) > 20 else ""))
    if n >= 2 and distinct == 1:
        raise SfMError(f"{folder}: all {n} photos are the same picture (copies of one file?); SfM needs photos "
                       "of the scene from several viewpoints")


def _jpeg_thumbnail(path: Path) -> tuple[np.ndarray | None, tuple[int, int]]:
    """A JPEG copied as it is needs no full decode: (its pixels at 1/8 scale, BGR, from the DCT (``draft``),
    its (width, height) from the header); (None, (0, 0)) where Pillow cannot open it (the caller decodes)."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            size = im.size
            im.draft("RGB", (max(1, size[0] // 8), max(1, size[1] // 8)))
            return np.ascontiguousarray(np.asarray(im.convert("RGB"))[..., ::-1]), size
    except Exception:  # not readable by Pillow: the caller's full decode decides
        return None, (0, 0)


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
    """Every ``every``-th frame of a video file as PNG images in ``work`` (frame_00000.png, ...)."""
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
