"""Depth frames: a dataset's depth maps (masked, range-limited, with their confidence and normals) loaded as
``DepthFrame``s in the view's camera, and the scene scale they imply (diagonal, pixel footprint).
"""
from __future__ import annotations

import logging
import shutil
import tempfile
import weakref

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..cameras import View, backproject_pixels, depth_footprint, valid_depth_mask
from ..errors import BadArgumentError, InputDataError, NoDepthError
from ..layout import DEPTH_RESOLUTIONS
from .config import DepthFrame, FusionConfig

log = logging.getLogger("photorecon")


def prepare_depth(view: View, depth: np.ndarray, cfg: FusionConfig, mask: np.ndarray | None = None,
                  confidence: np.ndarray | None = None) -> np.ndarray:
    """Validate and filter a depth map: NaN/inf/negative values raise (naming the view); masked,
    out-of-range and low-confidence pixels become 0."""
    d = np.asarray(depth, np.float32)
    H, W = view.intrinsics.height, view.intrinsics.width
    if d.shape != (H, W):
        raise BadArgumentError(f"view {view.name}: depth shape {d.shape} does not match its camera (H, W) = ({H}, {W})")
    if not np.all(np.isfinite(d)) or (d < 0).any():
        raise BadArgumentError(f"view {view.name}: depth has NaN, inf or negative values; use 0 for missing depth")
    d = d.copy()
    if mask is not None and cfg.use_masks:
        d[~mask] = 0
    if cfg.depth_min > 0:
        d[d < cfg.depth_min] = 0
    if cfg.depth_max:
        d[d > cfg.depth_max] = 0
    if confidence is not None and cfg.conf_threshold > 0:
        d[confidence < cfg.conf_threshold] = 0
    return d


def _sample_depth_points(f: DepthFrame, n: int) -> np.ndarray:
    """World points of about ``n`` pixels of a depth map, on a regular grid (the invalid ones dropped)."""
    step = max(1, int(np.sqrt(f.depth.size / n)))
    sub = np.asarray(f.depth[::step, ::step])
    valid = valid_depth_mask(sub)
    uv = f.view.intrinsics.pixel_grid(step)[valid]
    return backproject_pixels(uv, sub[valid], f.view.intrinsics, f.view.cam_from_world)


def scene_diagonal(frames: list[DepthFrame], sparse_points: np.ndarray | None = None) -> float:
    """Robust scene size: diagonal of the 1-99 percentile box of the sparse points, else of depth samples."""
    if sparse_points is not None and len(sparse_points) >= 20:
        pts = np.asarray(sparse_points)
    else:
        samples = [_sample_depth_points(f, 2000) for f in frames]
        pts = np.concatenate(samples) if samples else np.zeros((0, 3))
    if len(pts) < 4:
        raise NoDepthError("no valid depth in any view: nothing to fuse")
    lo, hi = np.percentile(pts, 1, axis=0), np.percentile(pts, 99, axis=0)
    return float(np.linalg.norm(hi - lo)) * 1.02


def pixel_footprint(frames: list[DepthFrame]) -> float:
    """The depth maps' pixel footprint on the surfaces the cameras look at, in scene units: per view the
    median ``z / f`` of the valid pixels of its central window (half the width and height; the whole map when
    that window has under 5% valid pixels), with ``f`` of the depth map's own intrinsics, as it would be at its
    view's working resolution (``DEPTH_LEVEL``: a depth map the depth stage left at half or quarter resolution counts
    with half or a quarter of its own footprint, and does not coarsen the voxel); the median over views.
    Far background at the image borders and outlying sparse points do not move it."""
    per_view = [own / 2 ** f.view.extra.get(DEPTH_LEVEL, 0) for f in frames
                if (own := frame_footprint(f)) is not None]
    if not per_view:
        raise NoDepthError("no valid depth in any view: nothing to fuse")
    return float(np.median(per_view))


def frame_footprint(f: DepthFrame) -> float | None:
    """One depth map's pixel footprint at its own resolution (``pixel_footprint``'s per view,
    ``cameras.depth_footprint``), or None without valid depth."""
    return depth_footprint(f.depth, f.view.intrinsics)


DEPTH_LEVEL = "depth_level"  # View.extra of a depth frame's view: the pyramid level of its depth map below its view's
# working resolution (the depth stage's ``mvs_report.json``, ``per_view[NAME]["resolution"]``: 1 = half, 2 = quarter),
# absent = 0


def resolution_weights(frames, need: float | None = None) -> list[float]:
    """Per frame its fusion weight factor: 1 for a depth map at its view's working resolution, 4 ** -level for one
    at a coarser pyramid level (``DEPTH_LEVEL``: a view the depth stage left at half resolution, where finer views
    see its surface, weighs 0.25: its depth noise grows with its footprint), so that where both see a surface the
    finer depths set it. ``need``: the footprint the voxel asks for (voxel / voxel footprints); a coarser map whose
    own footprint is finer than that resolves all the mesh keeps and weighs 1 (``(need / own)**2`` in between)."""
    out = []
    for f in frames:
        level = f.view.extra.get(DEPTH_LEVEL, 0)
        w = 0.25 ** level
        if level and need:
            own = frame_footprint(f)
            if own:
                w = max(w, min(1.0, (need / own) ** 2))
        out.append(w)
    return out


def depth_levels(dataset) -> dict[str, int]:
    """Per view of ``dataset`` whose depth map the depth stage left at a coarser level than its working resolution:
    that level (from ``mvs_report.json`` in the depth folder; {} without one)."""
    import json

    path = Path(dataset.depth_dir) / "mvs_report.json" if getattr(dataset, "depth_dir", None) else None
    try:
        per_view = json.loads(path.read_text()).get("per_view", {}) if path is not None and path.is_file() else {}
    except (OSError, ValueError, AttributeError):
        return {}
    by_name = {name: lvl for lvl, name in DEPTH_RESOLUTIONS.items()}
    return {n: by_name[r] for n, s in per_view.items()
            if isinstance(s, dict) and (r := s.get("resolution")) in by_name and by_name[r]}


def depth_view(view: View, shape: tuple[int, int]) -> View:
    """``view`` with its intrinsics scaled to a depth map of ``shape`` = (H, W) (a working resolution with
    the camera's aspect ratio); ``view`` itself when the sizes agree."""
    h, w = shape
    if (h, w) == (view.intrinsics.height, view.intrinsics.width):
        return view
    return replace(view, intrinsics=view.intrinsics.scaled(w, h))


def _resize_to(img: np.ndarray | None, shape: tuple[int, int], nearest: bool = False) -> np.ndarray | None:
    if img is None or img.shape[:2] == tuple(shape):
        return img
    import cv2

    h, w = shape
    if img.dtype == bool:
        return cv2.resize(img.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)


def load_frame(dataset, v: View, cfg: FusionConfig, full: bool = True, level: int = 0) -> DepthFrame | None:
    """One view's depth frame (see ``load_frames``); None when no pixel is left valid. ``full=False``: the
    filtered depth map alone (no colour, confidence or normals). ``level``: its depth map's pyramid level below
    its working resolution (``depth_levels``), kept in its view's ``extra[DEPTH_LEVEL]``."""
    raw = dataset.depth(v)
    dv = depth_view(v, raw.shape)
    if level:
        dv = replace(dv, extra={**dv.extra, DEPTH_LEVEL: level})
    conf = dataset.confidence(v)
    if conf is not None and conf.shape != raw.shape:
        raise InputDataError(f"view {v.name}: confidence map has shape {conf.shape}, its depth map {raw.shape}; "
                             "expected the same (H, W)")
    depth = prepare_depth(dv, raw, cfg, _resize_to(dataset.mask(v), raw.shape), conf)
    if not np.count_nonzero(depth):
        return None
    if not full:
        return DepthFrame(dv, depth)
    try:
        color = _resize_to(dataset.image(v), raw.shape)
    except InputDataError:  # colour is optional for fusion
        color = None
    normal = dataset.normals(v)
    if normal is not None and normal.shape != raw.shape + (3,):
        raise InputDataError(f"view {v.name}: normal map has shape {normal.shape}, its depth map {raw.shape}; "
                             "expected (H, W, 3)")
    if normal is not None:
        normal = normal.astype(np.float16)  # as PatchMatch writes them: half the memory of a frame's largest map
    return DepthFrame(dv, depth, color, conf, normal)


class FrameStore(Sequence):
    """Depth frames kept on disk and read when used: memory for one frame whatever the view count. Each frame is
    read from the dataset and prepared once (``load_frame``: masked, range-limited, its image resized) and its
    maps written as .npy files to a folder of its own (in ``folder``, default the system's temporary folder;
    removed with the store, or by ``close``); a use memory-maps them, so only the pages it reads come into
    memory, and the frame costs disk (about 30 MB at 1600x1067), not RAM. Indexing or iterating gives the depth
    map alone (what the scene's scale, the depth limit, the block estimate and the surface report read);
    ``full(i)`` gives frame ``i`` with its colour, confidence and normals (what integration reads). Holds only
    views with a valid pixel; ``views`` are the dataset's views (a frame's own view is scaled to its depth map).
    Normals are kept as float16, as ``load_frame`` and PatchMatch give them."""

    MAPS = ("depth", "color", "confidence", "normal")

    def __init__(self, folder=None):
        self.views: list[View] = []
        self.bytes_per_frame: list[int] = []
        self._frame_views: list[View] = []
        self._maps: list[tuple[str, ...]] = []  # per frame: the maps it has
        if folder is not None:
            Path(folder).mkdir(parents=True, exist_ok=True)
        self.folder = Path(tempfile.mkdtemp(prefix="photorecon_frames_", dir=folder))
        self._cleanup = weakref.finalize(self, shutil.rmtree, str(self.folder), True)

    def _path(self, i: int, name: str):
        return self.folder / f"{i:06d}.{name}.npy"

    def _write(self, i: int, f: DepthFrame) -> tuple[str, ...]:
        maps = tuple(m for m in self.MAPS if getattr(f, m) is not None)
        for m in maps:
            a = getattr(f, m)
            np.save(self._path(i, m), np.ascontiguousarray(a, np.float16 if m == "normal" else a.dtype))
        return maps

    def append(self, view: View, f: DepthFrame) -> None:
        """Keep frame ``f`` (of the dataset's ``view``) on disk."""
        self._maps.append(self._write(len(self.views), f))
        self.views.append(view)
        self._frame_views.append(f.view)
        self.bytes_per_frame.append(frame_bytes(f))

    def replace_frame(self, i: int, f: DepthFrame) -> None:
        """Frame ``i`` from now on: its maps as ``f`` has them (normals kept as float16), its view unchanged."""
        for m in self._maps[i]:
            self._path(i, m).unlink(missing_ok=True)
        self._maps[i] = self._write(i, f)

    def _load(self, i: int, name: str) -> np.ndarray | None:
        # copy-on-write: writable arrays (the compiled kernels take them as any array), the file never changes
        return np.load(self._path(i, name), mmap_mode="c") if name in self._maps[i] else None

    def __len__(self) -> int:
        return len(self.views)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        return DepthFrame(self._frame_views[i], self._load(i, "depth"))

    def full(self, i: int) -> DepthFrame:
        return DepthFrame(self._frame_views[i], *(self._load(i, m) for m in self.MAPS))

    def close(self) -> None:
        """Remove the frames' files (the store is empty afterwards)."""
        self._cleanup()
        self.views, self.bytes_per_frame, self._frame_views, self._maps = [], [], [], []


def full_frame(frames, i: int) -> DepthFrame:
    """Frame ``i`` with everything it carries (a ``FrameStore`` reads it now)."""
    return frames.full(i) if isinstance(frames, FrameStore) else frames[i]


def nonempty(frames):
    """The frames with a valid pixel (a ``FrameStore`` holds only those)."""
    return frames if isinstance(frames, FrameStore) else [f for f in frames if np.count_nonzero(f.depth)]


def frame_bytes(f: DepthFrame) -> int:
    """Bytes a frame holds (its maps)."""
    return sum(a.nbytes for a in (f.depth, f.color, f.confidence, f.normal) if a is not None)


def load_frames(dataset, cfg: FusionConfig, views: list[View] | None = None,
                hold_bytes: float | None = None, folder=None) -> list[DepthFrame] | FrameStore:
    """Depth frames of a ``Dataset`` (views without a depth map are skipped with a warning).

    A depth map may come at a working resolution other than its camera's (same aspect ratio, e.g. MVS at
    1600 px for 3072 px photos): its frame then gets the camera's intrinsics scaled to the depth map
    (``Intrinsics.scaled``), and the image and mask are resized to it.

    ``hold_bytes``: when the frames together would hold more than this, a ``FrameStore`` (in ``folder``: a work
    folder, default the system's temporary one) is returned instead of a list: each frame is prepared once and
    kept on disk, and read from there when used (TSDF fusion streams them), so the memory they take does not
    grow with the view count."""
    frames, missing, store = [], [], None
    levels = depth_levels(dataset)  # depth maps the depth stage left at half or quarter resolution
    held, originals = 0, []  # the dataset's views of ``frames`` (a frame's view is scaled to its depth map)
    for v in views or dataset.views:
        if not dataset.has_depth(v):
            missing.append(v.name)
            continue
        f = load_frame(dataset, v, cfg, level=levels.get(v.name, 0))
        if f is None:
            log.warning("view %s: depth map has no valid pixel; skipped", v.name)
            continue
        held += frame_bytes(f)
        if store is None and hold_bytes is not None and held > hold_bytes:
            store = FrameStore(folder)
            for g, w in zip(frames, originals):
                store.append(w, g)
            frames = []
        if store is not None:
            store.append(v, f)
            continue
        frames.append(f)
        originals.append(v)
    if missing:
        log.warning("%d view(s) without a depth map in %s skipped: %s", len(missing), dataset.depth_dir,
                    ", ".join(missing[:10]) + (" ..." if len(missing) > 10 else ""))
    if store is not None:
        log.info("fusion: %d depth frames (%.1f GB with their images) are kept on disk and read when used",
                 len(store), held / 2**30)
        return store
    if not frames:
        raise NoDepthError(f"no usable depth map in {dataset.depth_dir}: nothing to fuse")
    return frames
