"""What the user gives about the cameras: the images of given cameras (``--poses``), copied and undistorted
into the output folder with their masks (``ingest_given``), and a K matrix file (``--intrinsics``: ``read_K``).

Every image of a given camera is read from inside the image folder (``io.paths.inside``), under a name
photorecon can name its files after (``io.paths.check_name_length``), and no two of them may be one view
(``view_000.png`` and ``view_000.jpg``: ``io.paths.check_distinct_views``)."""
from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from ..cameras import Intrinsics
from ..errors import BadArgumentError, InputDataError
from ..io.paths import IMAGE_SUFFIXES, check_distinct_views, check_name_length, inside

log = logging.getLogger("photorecon")


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
