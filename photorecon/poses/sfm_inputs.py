"""What SfM reads besides the pixels: the masks (checked against the images, written as COLMAP wants them,
undistorted with the images) and upscaled copies of small images with their EXIF.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputDataError, SfMError
from ..io.colmap import read_colmap_binary
from ..io.colmap_text import SparseModel


def check_sfm_masks(images: str | Path, masks: str | Path) -> dict[str, Path]:
    """A user's mask folder against an image folder, before anything is written: ``{image name: mask}``.
    Raises ``InputDataError`` naming the folder (missing, no mask matches an image name), the mask (not at its
    image's size) or the photos whose masks exclude every pixel when fewer than 2 photos are left with pixels
    to use. For a video only the folder is checked here; its frames' masks are checked when they are converted
    (``write_colmap_masks``)."""
    return sfm_masks(images, masks)[0]


def sfm_masks(images: str | Path, masks: str | Path) -> tuple[dict[str, Path], list[str]]:
    """``check_sfm_masks``, and the names of the photos whose masks exclude every pixel (the image gate leaves
    them out: ``ingest.ingest_folder``)."""
    from .ingest import list_images
    from .video import VIDEO_SUFFIXES
    from ..io.images import MASK_HELP, image_size, match_masks, read_mask

    images, masks = Path(images), Path(masks)
    if images.is_file() and images.suffix.lower() in VIDEO_SUFFIXES:
        if not masks.is_dir():
            raise InputDataError(f"{masks}: no such mask folder ({MASK_HELP})")
        return {}, []
    paths, _ = list_images(images)
    found = match_masks(masks, {p.name: image_size(p) for p in paths})
    empty = [name for name, m in found.items() if not read_mask(m).any()]
    if empty and len(paths) - len(empty) < 2:
        listed = ", ".join(empty[:10]) + (" ..." if len(empty) > 10 else "")
        raise InputDataError(f"{masks}: the masks exclude every pixel of {len(empty)} photo(s) ({listed}), "
                             f"leaving {len(paths) - len(empty)} of {len(paths)} with pixels to use (SfM needs 2); "
                             "a mask's 0 pixels are ignored and the others used: are the masks inverted?")
    return found, empty


def write_colmap_masks(images: list[tuple[str, int, int]], images_dir: Path, masks: Path | None, dst: Path,
                       photo_names: dict[str, str] | None = None) -> int:
    """COLMAP's mask layout in ``dst``: ``NAME.EXT.png`` (uint8, 0 = no features there, 255 = use) for each of
    ``images`` ((name, width, height) in ``images_dir``) that has a mask in the user's folder ``masks``
    (NAME.EXT.png or NAME.png of the photo's name: ``photo_names`` maps a working name to it where they
    differ), else an alpha channel (RGBA, grey + alpha). When any image has one, every other image gets an
    all-255 mask (used whole): COLMAP skips an image without a mask file once it is given a mask folder.
    Returns how many masks came from the user's folder or alpha channels."""
    from ..io.images import mask_file, read_alpha, read_mask, write_image

    photo_names = photo_names or {}
    n, unmasked = 0, []
    for name, w, h in images:
        p = mask_file(masks, photo_names.get(name, name)) if masks else None
        if p is not None:
            m = read_mask(p, (w, h), f"image {name}")
        else:
            alpha = read_alpha(images_dir / name)
            if alpha is None:
                unmasked.append((name, w, h))
                continue
            if alpha.shape != (h, w):
                raise InputDataError(f"{images_dir / name}: alpha is {alpha.shape[1]}x{alpha.shape[0]}, image is {w}x{h}")
            m = alpha > 0
        write_image(dst / f"{name}.png", np.where(m, 255, 0).astype(np.uint8))
        n += 1
    if n:
        for name, w, h in unmasked:
            write_image(dst / f"{name}.png", np.full((h, w), 255, np.uint8))
    return n


def _exif(path: Path) -> bytes | None:
    from PIL import Image

    try:
        with Image.open(path) as im:
            return im.info.get("exif")
    except OSError:
        return None


def _upscaled_copies(images_dir: Path, mask_dir: Path | None, names: list[str], s: int, dst: Path) -> Path | None:
    """``names`` of ``images_dir`` upsampled ``s`` times (bicubic; same file names) into ``dst/images``, and their
    COLMAP-layout masks of ``mask_dir`` (nearest) into ``dst/masks``. Returns the mask folder, or None."""
    import cv2

    (dst / "images").mkdir()
    masks = None
    for name in names:
        img = cv2.imread(str(images_dir / name), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputDataError(f"{images_dir / name}: cannot read the image")
        h, w = img.shape[:2]
        up = cv2.resize(img, (w * s, h * s), interpolation=cv2.INTER_CUBIC)
        jpeg = Path(name).suffix.lower() in (".jpg", ".jpeg")
        exif = _exif(images_dir / name) if jpeg and up.ndim == 3 and up.shape[2] == 3 and up.dtype == np.uint8 else None
        if exif:  # COLMAP reads the GPS position (spatial matching) and focal length from it
            from PIL import Image

            Image.fromarray(cv2.cvtColor(up, cv2.COLOR_BGR2RGB)).save(dst / "images" / name, quality=100, exif=exif)
        elif not cv2.imwrite(str(dst / "images" / name), up, [cv2.IMWRITE_JPEG_QUALITY, 100] if jpeg else []):
            raise SfMError(f"{dst / 'images' / name}: could not write the upsampled copy for SIFT")
        m = mask_dir / f"{name}.png" if mask_dir is not None else None
        if m is not None and m.is_file():
            masks = dst / "masks"
            masks.mkdir(exist_ok=True)
            mask = cv2.imread(str(m), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(masks / f"{name}.png"), cv2.resize(mask, (w * s, h * s), interpolation=cv2.INTER_NEAREST))
    return masks


def _undistort_masks(model_dir: Path, model: SparseModel, mask_dir: Path, out: Path) -> int:
    """The COLMAP-layout masks of ``mask_dir`` (NAME.EXT.png) undistorted like their images onto the
    undistorted cameras of ``model`` (OpenCV maps, COLMAP's distortion models): ``out/NAME.png`` (0/255;
    outside the source image 0). Returns how many were written."""
    import cv2

    from ..io.images import read_mask, write_image

    distorted = {v.image_file: v.intrinsics for v in read_colmap_binary(model_dir).views}
    n = 0
    for v in model.views:
        name = v.image_file
        src = mask_dir / f"{name}.png"
        if not src.is_file() or name not in distorted:
            continue
        d, u = distorted[name], v.intrinsics
        m = np.where(read_mask(src, d.size, f"image {name}"), 255, 0).astype(np.uint8)
        map_x, map_y = cv2.initUndistortRectifyMap(d.K, np.array([d.k1, d.k2, d.p1, d.p2]), None, u.K,
                                                   u.size, cv2.CV_32FC1)
        m = cv2.remap(m, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        write_image(out / f"{v.name}.png", np.where(m >= 128, 255, 0).astype(np.uint8))
        n += 1
    return n
