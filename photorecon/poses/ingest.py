"""Ingest an image folder: find images (any letter case), pass each through the image gate (``photos``: decoded
once, EXIF orientation applied, EXIF focal length priors read, unusable photos left out) and copy them into a
working folder (the user's folder is never written to). A video file gives every k-th frame instead
(``video.video_frames``); given cameras (``--poses``) bring their images in through ``given.ingest_given``.
This module's names include theirs (``video_frames``, ``ingest_given``, ``read_K``, the gate's constants)."""
from __future__ import annotations

import hashlib
import logging
import shutil
from pathlib import Path

import numpy as np

from ..errors import InputDataError, NoImagesError, SfMError
from ..io.atomic import atomic_path
from ..io.images import open_photo
from ..io.paths import HEIF_SUFFIXES, IMAGE_SUFFIXES, check_distinct_views, check_name_length
from .given import ingest_given, read_K  # noqa: F401  (imported from here)
from .photos import (FLAT, FOCAL_FRAC_RANGE, MASKED_OUT, MAX_ASPECT, MIN_SIDE,  # noqa: F401
                     TOO_NARROW, TOO_SMALL, TRUNCATED, UNREADABLE, Ingest, IngestedImage, inspect_photo)
from .video import VIDEO_SUFFIXES, video_frames  # noqa: F401  (imported from here)

log = logging.getLogger("photorecon")

# formats COLMAP's image reader cannot decode (pycolmap 4.x): ingested as PNG copies
COLMAP_UNREADABLE = (".webp",) + HEIF_SUFFIXES


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


def check_photo_name(path: Path) -> None:
    """Refuse a photo whose name holds a line break or another control character: COLMAP's text models (and
    photorecon's, ``sparse/0/images.txt``) hold one image name per line. Raises ``InputDataError``."""
    name = path.name
    if len(name.splitlines()) != 1 or any(ord(c) < 32 or ord(c) == 127 for c in name):
        raise InputDataError(f"{path.parent / repr(name)[1:-1]}: the photo's name holds a line break or a control "
                             "character, which COLMAP's text models (one image name per line) cannot hold; rename it")


def _listed(names: list[str], most: int = 20) -> str:
    return ", ".join(names[:most]) + (" ..." if len(names) > most else "")


def ingest_folder(folder: str | Path, work: str | Path, min_images: int = 1,
                  left_out: dict[str, str] | None = None) -> Ingest:
    """The image gate: every photo of ``folder`` is decoded once and checked (``photos.inspect_photo``: readable
    and complete, EXIF orientation applied, a size and shape COLMAP's SIFT takes, not one flat colour); the photos
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
        photo = (left_out[p.name], p.name) if p.name in left_out else inspect_photo(p)
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
