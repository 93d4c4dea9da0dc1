"""The one path rule of every reader: a file named by a camera or dataset file, or found in a folder the user
named, is read only when it lies inside that folder.

Camera and dataset files name other files: COLMAP ``images.txt`` / ``images.bin`` (image names, relative to the
image folder), transforms.json and its dialects (``file_path``, ``depth_file_path``, ``mask_path``, relative to
the file's folder), NeRF Blender-synthetic splits; IDR / NeuS, LLFF and Strecha pair cameras with the files of a
folder. Every such name goes through ``inside``: an absolute path, a ``..`` that leaves the folder, or a link
whose target lies outside it is refused with an ``InputDataError`` (exit 3) naming the file, the name and the
folder, before anything is read or copied. The same holds for the photos of an image folder.

The names photorecon derives from a photo's name are checked here too: two photos whose names differ only by
their extension would share a view name (depth maps, masks and undistorted images are named after it), and a
name near the file system's length limit leaves no room for ``NAME.normal.npy`` or a temporary copy.
"""
from __future__ import annotations

import os
from pathlib import Path

from ..errors import InputDataError

HEIF_SUFFIXES = (".heic", ".heif")  # decoded by Pillow with pillow-heif (io.images.open_photo), not by OpenCV
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp") + HEIF_SUFFIXES
# photorecon names files after a view: NAME.normal.npy, NAME.EXT.png masks, and writes each through a temporary
# ".NAME.XXXXXXXX.EXT" next to it (io/atomic.py): a photo's name may use the file system's limit less this
NAME_MARGIN = 32


def inside(root: str | Path | None, name: str | os.PathLike, what: str) -> Path:
    """``root / name``, when that names a file inside ``root``: ``name`` is relative, does not leave ``root``
    through ``..`` and, links followed, still lies inside ``root`` (checked on the file system). ``root=None``:
    the folder is not known yet (a COLMAP model names files of an image folder given apart), the name alone is
    checked; the caller checks it again against the folder before reading. Raises ``InputDataError`` naming
    ``what`` (the file or view the name comes from), the name and the folder."""
    text = os.fspath(name)
    where = str(root) if root is not None else "the image folder"
    if not text or "\0" in text:
        raise InputDataError(f"{what}: file name {text!r} is empty or holds a NUL character; expected a file "
                             f"name relative to {where}")
    if Path(text).is_absolute():
        raise InputDataError(f"{what}: absolute path {text!r} refused; files are named relative to {where} and "
                             "must lie inside it")
    if os.path.normpath(text).split(os.sep)[0] == "..":
        raise InputDataError(f"{what}: {text!r} leaves {where}; refused (files must lie inside it)")
    if root is None:
        return Path(text)
    root = Path(root)
    path = root / text
    real, top = path.resolve(), root.resolve()
    if not real.is_relative_to(top):
        raise InputDataError(f"{what}: {text!r} is a link to {real}, outside {root}; refused (files must lie "
                             f"inside {root}: copy the file in)")
    return path


def files_inside(folder: str | Path, suffixes: tuple[str, ...], what: str | None = None) -> list[Path]:
    """The files of ``folder`` (not recursive, hidden ones skipped) whose suffix, in any letter case, is one of
    ``suffixes``, sorted by name; each through ``inside`` (a link to a file outside ``folder`` raises). An
    empty list when ``folder`` is not a folder."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes and not p.name.startswith(".")
                   and p.is_file())
    return [inside(folder, p.name, what or str(folder)) for p in found]


def check_distinct_views(items, where: str) -> None:
    """Refuse two files that would be one view: ``items`` are (view name, file name) pairs, and a view's depth
    map, mask and undistorted image are named after its view name, the file name without its extension
    (``view_000.png`` and ``view_000.jpg`` are both ``view_000``). Letter case does not tell views apart (it
    does not on every file system). Raises ``InputDataError`` naming both files."""
    seen: dict[str, str] = {}
    for view, file in items:
        key = str(view).lower()
        if key in seen and seen[key] != file:
            one, two = sorted((seen[key], file))
            raise InputDataError(f"{where}: {one!r} and {two!r} would both be view {view!r} (a view, its "
                                 "depth map and mask are named after the file name without its extension); rename "
                                 "or remove one of them")
        seen[key] = file


def check_name_length(path: str | Path, what: str | None = None) -> None:
    """Refuse a file whose name leaves less than ``NAME_MARGIN`` bytes below its file system's name limit
    (the files photorecon names after it would not fit). Raises ``InputDataError`` naming the file."""
    path = Path(path)
    try:
        limit = os.pathconf(path.parent if str(path.parent) else ".", "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        limit = 255
    n = len(os.fsencode(path.name))
    if n + NAME_MARGIN > limit:
        short = path.name if len(path.name) <= 60 else f"{path.name[:30]}...{path.name[-20:]}"
        raise InputDataError(f"{what + ': ' if what else ''}{path.parent / short}: file name is {n} bytes long; "
                             f"rename it to at most {limit - NAME_MARGIN} bytes (photorecon names files after it, "
                             f"NAME.normal.npy and temporary copies, within the file system's {limit}-byte limit)")
