"""What several camera formats share: an image's size from its header; the sorted image files that IDR / NeuS
and LLFF pair with their cameras."""
from __future__ import annotations

from pathlib import Path

from ...cameras import View
from ...errors import InputDataError
from ..paths import IMAGE_SUFFIXES, files_inside


def image_size(path: Path, what: str) -> tuple[int, int]:
    """(width, height) of an image file, from its header (the pixels are not decoded)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return im.size
    except FileNotFoundError:
        raise InputDataError(f"{what}: image {path} not found; its size is needed for the focal length") from None
    except (OSError, UnidentifiedImageError) as exc:
        raise InputDataError(f"{what}: cannot read image {path} ({exc})") from None


def sorted_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` in sorted name order (as the NeuS / IDR / LLFF loaders list them; hidden files
    skipped, as their ``glob`` does); a link to a file outside ``folder`` raises ``InputDataError``."""
    return files_inside(folder, IMAGE_SUFFIXES)


def check_count(path: Path, n: int, images: list[Path], folder: Path):
    if not images:
        raise InputDataError(f"{path}: no images in {folder}; the i-th camera belongs to the i-th sorted image there")
    if len(images) != n:
        raise InputDataError(f"{path}: {n} cameras but {len(images)} images in {folder}; camera i belongs to the "
                             "i-th sorted image, so the counts must match (remove the extra images or cameras)")


def file_order(views: list[View]) -> list[View]:
    return sorted(views, key=lambda v: v.image_file or v.name)
