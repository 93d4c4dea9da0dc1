"""A dataset folder in the synth layout: cameras (sparse/0 or transforms.json), images, depth maps, masks.

    DATASET/images/NAME.png|jpg   DATASET/depth/NAME.npy (+ optional NAME.conf.npy)   DATASET/masks/NAME.png
    DATASET/sparse/0/             (COLMAP text or binary)  or  DATASET/transforms.json

Every file a camera file names is read from inside the dataset folder (``paths.inside``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..cameras import View
from ..errors import InputDataError
from ..layout import Layout
from . import cameras as camera_formats
from .cameras import SparseModel
from .images import mask_file, match_masks, read_alpha, read_depth, read_image, read_mask
from .paths import IMAGE_SUFFIXES, check_distinct_views, inside
MIN_DEPTH_SIDE = 64  # a depth map at a working resolution: at least this long side (MVS's smallest --max-size)


def read_model(path: str | Path, neus_world: str = "normalized") -> SparseModel:
    """``_read_model``, with a model without cameras and two images that would be one view (``view_000.png``,
    ``view_000.jpg``) refused (``InputDataError`` naming the file or both images)."""
    model = _read_model(path, neus_world)
    if not model.views:  # every reader's empty file (a COLMAP model without images, ...): nothing to use
        raise InputDataError(f"{path}: the camera file has no cameras; it must list one camera (pose and "
                             "intrinsics) per image")
    check_distinct_views(((v.name, v.image_file or v.name) for v in model.views), str(path))
    return model


def _read_model(path: str | Path, neus_world: str = "normalized") -> SparseModel:
    """Cameras (and sparse points, if any) in the first camera format of the registry (``io.cameras.FORMATS``)
    that finds them at ``path``, in this order:

    * a file: ``*.json`` (transforms.json, including NeRF Blender-synthetic ``transforms_SPLIT.json``),
      ``*.npz`` (IDR / NeuS ``cameras_sphere.npz``, in the ``neus_world`` "normalized" or "original" world),
      ``*.npy`` (LLFF ``poses_bounds.npy``);
    * a folder: a COLMAP model (text or binary), or one holding ``sparse/0``, ``transforms.json``,
      ``transforms_{train,val,test}.json`` (Blender, all splits), ``cameras_sphere.npz`` / ``cameras.npz``
      (NeuS), ``poses_bounds.npy`` (LLFF), or Strecha ``*.camera`` files (also in ``gt_dense_cameras/``)."""
    return camera_formats.read(path, neus_world=neus_world)


@dataclass
class Dataset:
    root: Path
    model: SparseModel
    depth_dir: Path
    masks_dir: Path | None = None  # None: DATASET/masks (and the frames' mask_path)

    def __post_init__(self):
        if self.masks_dir is None:
            self.masks_dir = self.layout.masks

    @property
    def layout(self) -> Layout:
        return Layout(self.root)

    @classmethod
    def open(cls, root: str | Path, depth_dir: str | Path | None = None,
             masks_dir: str | Path | None = None) -> "Dataset":
        """``masks_dir``: a folder of masks (NAME.png or NAME.EXT.png, 0 = ignore) instead of DATASET/masks;
        checked here (it exists, some mask matches a view, each matching one has its camera's size), so a
        bad folder fails before anything is written."""
        root = Path(root)
        if not root.is_dir():
            raise InputDataError(f"{root}: no such dataset folder")
        model = read_model(root)
        if not model.views:
            raise InputDataError(f"{root}: the camera model has no images")
        ds = cls(root, model, Path(depth_dir) if depth_dir else Layout(root).depth, Path(masks_dir) if masks_dir else None)
        for v in ds.views:  # every image inside the dataset (``paths.inside``), before anything is written
            ds.image_path(v)
        if masks_dir:
            match_masks(masks_dir, {ds._image_name(v): v.intrinsics.size for v in ds.views})
        return ds

    @property
    def views(self) -> list[View]:
        return self.model.views

    def image_path(self, view: View) -> Path:
        """The view's image: the path its camera file gave (a transforms.json's, already inside the dataset),
        else ``images/FILE`` (the file a COLMAP model names), else ``images/NAME.EXT`` for any image
        extension; each inside ``images/`` (``paths.inside``)."""
        if view.image_path:
            return Path(view.image_path)
        name = view.image_file or view.name
        p = inside(self.layout.images, name, f"view {view.name}")
        if p.is_file():
            return p
        for suf in IMAGE_SUFFIXES:
            q = self.layout.images / (view.name + suf)
            if q.is_file():
                return inside(self.layout.images, q.name, f"view {view.name}")
        return p

    def image(self, view: View) -> np.ndarray:
        img = read_image(self.image_path(view))
        W, H = view.intrinsics.size
        if img.shape[:2] != (H, W):
            raise InputDataError(f"view {view.name}: image is {img.shape[1]}x{img.shape[0]} but its camera is {W}x{H}")
        return img

    def depth_path(self, view: View) -> Path:
        """DEPTH_DIR/NAME.npy, else (when the depth folder is the default one) the frame's ``depth_file_path``
        from a transforms.json (confined to its folder)."""
        p = inside(self.depth_dir, f"{view.name}.npy", f"view {view.name}")
        if not p.is_file() and view.depth_file and self.depth_dir == self.layout.depth:
            return Path(view.depth_file)
        return p

    def depth(self, view: View) -> np.ndarray:
        """float32 z-depth (H, W) of ``view``: at its camera's size, or at a working resolution with the
        camera's aspect ratio (within 1 px of rounding per axis, at least ``MIN_DEPTH_SIDE`` px on its long side;
        fusion then scales the intrinsics)."""
        path = self.depth_path(view)
        d = read_depth(path, None, view.name)
        W, H = view.intrinsics.size
        h, w = d.shape
        # |h - w H / W| <= 1 and |w - h W / H| <= 1, in integers; a resize keeps MIN_DEPTH_SIDE px on its long side
        if (h, w) != (H, W) and (abs(h * W - w * H) > min(W, H) or max(h, w) < min(MIN_DEPTH_SIDE, max(W, H))):
            raise InputDataError(f"view {view.name}: depth map {path} has shape {d.shape}, but the camera is {W}x{H}: "
                                 f"expected (H, W) = {(H, W)} or a resize with the same aspect ratio and at least "
                                 f"{min(MIN_DEPTH_SIDE, max(W, H))} px on its long side")
        return d

    def has_depth(self, view: View) -> bool:
        return self.depth_path(view).is_file()

    def confidence(self, view: View) -> np.ndarray | None:
        p = inside(self.depth_dir, f"{view.name}.conf.npy", f"view {view.name}")
        return np.load(p).astype(np.float32) if p.is_file() else None

    def normals(self, view: View) -> np.ndarray | None:
        """PatchMatch's per-pixel normals (H, W, 3) float32 in the camera frame (DEPTH_DIR/NAME.normal.npy),
        or None when there are none (rendered, monocular or sensor depth)."""
        p = inside(self.depth_dir, f"{view.name}.normal.npy", f"view {view.name}")
        if not p.is_file():
            return None
        try:
            return np.load(p, allow_pickle=False).astype(np.float32)
        except (ValueError, OSError) as exc:
            raise InputDataError(f"view {view.name}: {p} is not a readable .npy normal map ({exc})") from None

    def _image_name(self, view: View) -> str:
        """The view's image file name (NAME.EXT), what a COLMAP-style mask NAME.EXT.png is named after."""
        return Path(view.image_path).name if view.image_path else Path(view.image_file or view.name).name

    def mask_path(self, view: View) -> Path | None:
        """The mask file of ``view``: in the masks folder NAME.EXT.png or NAME.png; with the default folder,
        a transforms.json frame's ``mask_path`` comes first. None when there is none."""
        default = self.masks_dir == self.layout.masks
        if default and view.mask_file and Path(view.mask_file).is_file():
            return Path(view.mask_file)
        p = mask_file(self.masks_dir, self._image_name(view))
        if p is None and (self.masks_dir / f"{view.name}.png").is_file():  # a view named apart from its file
            p = self.masks_dir / f"{view.name}.png"
        if p is not None:
            p = inside(self.masks_dir, p.name, f"view {view.name}")
        return p

    def mask(self, view: View) -> np.ndarray | None:
        """Boolean (H, W) foreground of ``view`` (True = use the pixel), or None when it has no mask: its
        mask file (``mask_path``) > 0 when present, else the alpha channel > 0 of its image when that is
        RGBA or grey + alpha."""
        size = view.intrinsics.size
        p = self.mask_path(view)
        if p is not None:
            return read_mask(p, size, f"the camera of view {view.name}")
        p = self.image_path(view)
        if not p.is_file():
            return None
        m = read_alpha(p)
        if m is None:
            return None
        if (m.shape[1], m.shape[0]) != tuple(size):
            raise InputDataError(f"view {view.name}: alpha of image {p} is {m.shape[1]}x{m.shape[0]}, camera is "
                                 f"{size[0]}x{size[1]}")
        return m > 0
