"""Sparse points for **given** cameras: SIFT features, matching, and triangulation with the poses and
intrinsics held fixed (COLMAP's point triangulator, through pycolmap).

Users who bring their own cameras (a COLMAP model with an empty ``points3D.txt``, a ``transforms.json``, a
Strecha ``*.camera`` folder) have no sparse points, but the depth stage wants them for view selection and
depth ranges. ``triangulate_given`` adds them without moving any camera::

    model = read_model("cams/transforms.json")                  # views, no points
    model = triangulate_given("photos/", model, "out/triangulate")
    model.points, model.observations                            # now filled; model.views unchanged

Like ``photorecon.sfm``, this module imports pycolmap lazily, inside the functions (pycolmap 4.x API:
rigs and frames, ``image.cam_from_world()`` is a method).
"""
from __future__ import annotations

import logging
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from ..arrays import position_order
from ..cameras import View
from ..conventions import colmap_from_intrinsics
from ..errors import BadArgumentError, InputDataError, OutputError
from ..io.colmap_text import SparseModel
from ..io.paths import IMAGE_SUFFIXES, inside
from ..progress import running
from .extract import _number_images_by_name
from ..config_checks import check_config

log = logging.getLogger("photorecon")


@dataclass
class TriangulateConfig:
    """Settings of the triangulation of given cameras."""

    max_image_size: int = field(default=1600, metadata={"help": "feature extraction works on images downscaled to this longest side, pixels", "range": (64, 65536)})
    max_features: int = field(default=8192, metadata={"help": "most SIFT features per image", "range": (16, 1_000_000)})
    affine_sift: bool = field(default=False, metadata={"help": "estimate affine feature shapes (wide baselines; more points, slower)"})
    matcher: Literal["auto", "exhaustive", "overlap"] = field(default="auto", metadata={
        "help": "auto: exhaustive up to exhaustive_max images, else only pairs whose frusta overlap"})
    exhaustive_max: int = field(default=40, metadata={"help": "largest image count matched exhaustively by auto", "range": (0, 1_000_000)})
    overlap_neighbors: int = field(default=20, metadata={"help": "overlap matcher: partners per image (most overlap first)", "range": (1, 100_000)})
    max_view_angle_deg: float = field(default=90.0, metadata={"help": "overlap matcher: skip pairs whose optical axes differ by more, degrees", "range": (0.0, 180.0)})
    contrast: Literal["clahe", "stretch", "none"] = field(default="clahe", metadata={
        "help": "contrast normalisation of the images feature extraction sees (dark or low-contrast photos give few features otherwise); point colours come from the originals"})
    use_alpha_mask: bool = field(default=True, metadata={"help": "no features where an image's alpha channel is 0"})
    min_points: int = field(default=50, metadata={"help": "fewer triangulated points than this: warn and return the model unchanged", "range": (0, 100_000_000)})
    threads: int = field(default=-1, metadata={"help": "SIFT extraction and matching threads (-1 = all cores; the same points with any number; the triangulation runs on one thread)", "range": (1, 4096), "also": (-1,)})
    seed: int = field(default=0, metadata={"help": "random seed of the pairs' RANSAC and of the triangulator (the same points run after run, as SfM's --seed)", "range": (0, 2**31 - 1)})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.config_checks)


@dataclass
class TriangulateStats:
    """What ``triangulate_given`` did (also logged): counts and seconds per step."""

    points: int = 0
    pairs: int = 0
    matcher: str = ""
    seconds: dict = field(default_factory=dict)
    warning: str | None = None


def find_image(images_dir: Path, view: View) -> Path:
    """The image file of ``view``: ``view.image_path`` if it exists, else ``images_dir/<view.image_file>``,
    else ``images_dir/<name>.<any image suffix>``. Raises ``InputDataError`` naming the view when none exists."""
    if view.image_path and Path(view.image_path).is_file():
        return Path(view.image_path)
    name = view.image_file or view.name
    for cand in [name, Path(name).name] + [view.name + suf for suf in IMAGE_SUFFIXES + tuple(s.upper() for s in IMAGE_SUFFIXES)]:
        p = inside(images_dir, cand, f"view {view.name}")  # the one path rule: no file outside images_dir
        if p.is_file():
            return p
    raise InputDataError(f"view {view.name}: image {name} not found in {images_dir}")


def _read_rgb_alpha(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """(8-bit BGR image (H, W, 3), alpha (H, W) or None) of any 8/16-bit grey, grey+alpha, RGB or RGBA file,
    turned upright by its EXIF orientation (as ``ingest_given`` and the depth stage see it)."""
    from ..io.images import read_unchanged

    img = read_unchanged(path)  # upright by its EXIF orientation, as every other reader sees it
    if img is None or img.size == 0:
        raise InputDataError(f"{path}: cannot read image (missing, corrupt or not an image)")
    if img.dtype != np.uint8:  # 16-bit PNG / TIFF, float TIFF: scale to 8 bit
        img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(np.nanmax(img)), 1e-12))
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR), None
    if img.shape[2] == 2:  # grey + alpha
        return cv2.cvtColor(np.ascontiguousarray(img[..., 0]), cv2.COLOR_GRAY2BGR), img[..., 1]
    if img.shape[2] == 4:
        return np.ascontiguousarray(img[..., :3]), img[..., 3]
    return np.ascontiguousarray(img[..., :3]), None


def _normalize_contrast(bgr: np.ndarray, how: str, valid: np.ndarray | None) -> np.ndarray:
    if how == "none":
        return bgr
    lab = cv2.cvtColor(bgr, cv2.COLOR_BGR2LAB)
    L = lab[..., 0]
    if how == "stretch":
        vals = L[valid] if valid is not None and valid.any() else L
        lo, hi = np.percentile(vals, [0.5, 99.5])
        L = cv2.convertScaleAbs(L, alpha=255.0 / max(hi - lo, 1.0), beta=-lo * 255.0 / max(hi - lo, 1.0))
    else:
        tiles = max(2, round(max(L.shape) / 160))
        L = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(tiles, tiles)).apply(L)
    lab[..., 0] = L
    return cv2.cvtColor(lab, cv2.COLOR_LAB2BGR)


def _prepare_images(images_dir: Path, views: list[View], work: Path, use_alpha: bool,
                    contrast: str) -> tuple[list[str], bool]:
    """Write 8-bit 3-channel PNG copies ``work/images/<view name>.png`` (contrast-normalised) and alpha masks
    (``work/masks/<view name>.png.png``, COLMAP's naming; all 255 for the views without alpha when any has one).
    Returns (names in the work folder, any mask?)."""
    img_dir, mask_dir = work / "images", work / "masks"
    img_dir.mkdir(parents=True)
    names, any_mask = [], False
    for v in views:
        src = find_image(images_dir, v)
        bgr, alpha = _read_rgb_alpha(src)
        H, W = bgr.shape[:2]
        if (W, H) != v.intrinsics.size:
            raise InputDataError(f"view {v.name}: image {src} is {W}x{H}, but its camera is "
                                 f"{v.intrinsics.width}x{v.intrinsics.height}")
        name = f"{v.name}.png"
        bgr = _normalize_contrast(bgr, contrast, None if alpha is None else alpha > 0)
        if not cv2.imwrite(str(img_dir / name), bgr):
            raise OutputError(f"{img_dir / name}: could not write the working copy")
        if use_alpha and alpha is not None and (alpha == 0).any():
            mask_dir.mkdir(exist_ok=True)
            cv2.imwrite(str(mask_dir / f"{name}.png"), np.where(alpha > 0, 255, 0).astype(np.uint8))
            any_mask = True
        names.append(name)
    if any_mask:  # COLMAP skips an image without a mask file once it is given a mask folder: use those whole
        for v, name in zip(views, names):
            if not (mask_dir / f"{name}.png").is_file():
                cv2.imwrite(str(mask_dir / f"{name}.png"), np.full(v.intrinsics.size[::-1], 255, np.uint8))
    return names, any_mask


def overlap_pairs(views: list[View], neighbors: int = 20, max_angle_deg: float = 90.0) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, of views whose viewing frusta plausibly overlap, from the cameras alone.

    Each camera's frustum is sampled (a 5x5 pixel grid at depths 0.5, 1 and 1.5 times its distance to the
    scene centre, the point nearest to all optical axes; for forward-facing sets, whose axes do not meet,
    ten times the median spacing of neighbouring cameras). A pair's score is the smaller of the two fractions
    of samples that one camera sees inside the other's image; each view keeps its ``neighbors`` best partners
    with score > 0 and optical axes less than ``max_angle_deg`` apart.
    """
    n = len(views)
    if n < 2:
        return []
    C = np.array([v.center for v in views])
    D = np.array([v.world_from_cam[:3, 2] for v in views])  # optical axes (unit)
    # least-squares point nearest to all optical axes
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(C, D):
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c
    spacing = np.median(np.sort(np.linalg.norm(C[:, None] - C[None], axis=-1), axis=1)[:, 1]) if n > 1 else 1.0
    depth = np.full(n, 10.0 * max(spacing, 1e-9))
    if np.linalg.cond(A) < 1e6:
        centre = np.linalg.solve(A, b)
        along = np.einsum("ij,ij->i", centre - C, D)
        if np.median(along) > 0:
            depth = np.where(along > 0, along, np.median(along))
    samples, in_view = [], np.zeros((n, n))
    for i, v in enumerate(views):
        W, H = v.intrinsics.size
        u, w = np.meshgrid(np.linspace(0, W - 1, 5), np.linspace(0, H - 1, 5))
        rays = v.intrinsics.pixel_rays(np.stack([u.ravel(), w.ravel()], 1))  # camera frame, z = 1
        pts_cam = np.concatenate([rays * depth[i] * s for s in (0.5, 1.0, 1.5)])
        samples.append(pts_cam @ v.world_from_cam[:3, :3].T + v.world_from_cam[:3, 3])
    for i in range(n):
        for j, vj in enumerate(views):
            if i == j:
                continue
            pc = samples[i] @ vj.cam_from_world[:3, :3].T + vj.cam_from_world[:3, 3]
            z = pc[:, 2]
            ok = z > 1e-9
            if not ok.any():
                continue
            uv, _ = vj.intrinsics.project_cam(pc[ok])
            W, H = vj.intrinsics.size
            inside = (uv[:, 0] >= -0.5) & (uv[:, 0] <= W - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= H - 0.5)
            in_view[i, j] = inside.sum() / len(pc)
    score = np.minimum(in_view, in_view.T)
    cos_max = np.cos(np.radians(max_angle_deg))
    pairs = set()
    for i in range(n):
        cand = [j for j in np.argsort(-score[i]) if j != i and score[i, j] > 0 and D[i] @ D[j] > cos_max]
        for j in cand[:neighbors]:
            pairs.add((min(i, j), max(i, j)))
    return sorted(pairs)


def _first_line(exc: Exception) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _check_work_dir(images_dir: Path, work: Path) -> None:
    img, wd = images_dir.resolve(), work.resolve()
    if wd == img or img in wd.parents:
        raise OutputError(f"{work}: the working folder is inside the image folder {images_dir}; photorecon "
                          "never writes into its input: choose another work_dir")


def triangulate_given(images_dir: str | Path, model: SparseModel, work_dir: str | Path,
                      cfg: TriangulateConfig | None = None, stats: TriangulateStats | None = None) -> SparseModel:
    """Sparse points for the given, **fixed** cameras of ``model``.

    Args:
        images_dir: folder holding the images (8/16-bit RGB, grey, grey+alpha or RGBA; alpha 0 = no
            features). Each view's image is ``view.image_path`` if that file exists, else
            ``images_dir / view.image_file``, else ``images_dir / (view.name + <image suffix>)``.
            Only read, never written.
        model: the cameras (any COLMAP camera model photorecon supports, one camera per view is fine).
            Its points, if any, are ignored and replaced.
        work_dir: working folder (database, 8-bit image copies, masks, the triangulated COLMAP model in
            ``work_dir/sparse``); emptied of these files first. Must not lie inside ``images_dir``.
        cfg: ``TriangulateConfig`` (matching strategy, SIFT settings, threads, ``min_points``).
        stats: optional ``TriangulateStats`` filled in place (points, pairs matched, seconds per step).

    Returns:
        A new ``SparseModel`` with **the same** ``views`` objects (names, intrinsics, ``cam_from_world``
        untouched) plus ``points`` (K, 3) world coordinates, ``colors`` (K, 3) uint8, ``point_ids`` (K,),
        ``errors`` (K,) mean reprojection error in pixels, and ``observations[view.name] = (uv (M, 2) in
        photorecon pixels (COLMAP - 0.5), point ids (M,), -1 where a feature has no point)``.
        When triangulation fails or yields fewer than ``cfg.min_points`` points, it logs one warning line
        and returns ``model`` itself, unchanged (the caller then falls back, e.g. to depth ranges without
        points).

    Raises:
        InputDataError: an image is missing, unreadable or of another size than its camera.
        OutputError: ``work_dir`` lies inside ``images_dir`` or cannot be written.
        BadArgumentError: fewer than 2 views, or duplicate view names.
    """
    import pycolmap

    cfg = cfg or TriangulateConfig()
    stats = stats if stats is not None else TriangulateStats()
    images_dir, work = Path(images_dir), Path(work_dir)
    views = model.views
    if len(views) < 2:
        raise BadArgumentError(f"triangulate_given: expected at least 2 views, got {len(views)}")
    names_seen = [v.name for v in views]
    if len(set(names_seen)) != len(names_seen):
        dup = sorted({n for n in names_seen if names_seen.count(n) > 1})
        raise BadArgumentError(f"triangulate_given: view names must be unique, found duplicates {dup[:5]}")
    if not images_dir.is_dir():
        raise InputDataError(f"{images_dir}: no such image folder")
    _check_work_dir(images_dir, work)
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 3  # COLMAP's log with -v only
    db_path = work / "database.db"
    try:
        for sub in ("images", "masks", "sparse"):
            if (work / sub).exists():
                shutil.rmtree(work / sub)
        work.mkdir(parents=True, exist_ok=True)
        for f in (db_path, work / "pairs.txt"):
            if f.exists():
                f.unlink()
    except OSError as exc:
        raise OutputError(f"{work}: cannot use as the working folder ({exc})") from None

    def fail(msg: str) -> SparseModel:
        stats.warning = msg
        log.warning("triangulating the given cameras: %s; continuing without sparse points", msg)
        return model

    # 1. 8-bit working copies named <view name>.png, alpha -> mask; SIFT
    t0 = time.perf_counter()
    names, any_mask = _prepare_images(images_dir, views, work, cfg.use_alpha_mask, cfg.contrast)
    reader = pycolmap.ImageReaderOptions()
    if any_mask:
        reader.mask_path = str(work / "masks")
    ext = pycolmap.FeatureExtractionOptions()
    ext.max_image_size = cfg.max_image_size
    ext.sift.max_num_features = cfg.max_features
    ext.sift.estimate_affine_shape = cfg.affine_sift
    ext.num_threads = cfg.threads
    try:
        with running(f"sparse points for the given cameras: feature extraction ({len(names)} photos)"):
            pycolmap.extract_features(str(db_path), str(work / "images"), image_names=names,
                                      camera_mode=pycolmap.CameraMode.PER_IMAGE, reader_options=reader,
                                      extraction_options=ext, device=pycolmap.Device.cpu)
    except Exception as exc:  # pycolmap raises RuntimeError / ValueError with COLMAP's check message
        return fail(f"SIFT extraction failed ({_first_line(exc)})")
    # the extraction threads number the images in the order they finish; the pairs' ids, the direction each
    # pair is matched in and the order the triangulator builds its tracks in follow the numbers
    _number_images_by_name(db_path)
    stats.seconds["extraction"] = time.perf_counter() - t0

    # 2. matching: all pairs, or those whose frusta overlap
    t0 = time.perf_counter()
    matcher = cfg.matcher
    if matcher == "auto":
        matcher = "exhaustive" if len(views) <= cfg.exhaustive_max else "overlap"
    mopt = pycolmap.FeatureMatchingOptions()
    # all threads: they write the pairs into the database in the order they finish, but the database keys each
    # pair's matches and geometry by its pair id (a rowid), so the triangulator reads them back in pair order
    # whatever the order of writing; each pair's RANSAC is seeded: the same points whichever thread runs it
    mopt.num_threads = cfg.threads
    vopt = pycolmap.TwoViewGeometryOptions()
    vopt.ransac.random_seed = cfg.seed  # each pair's RANSAC seeded: the same inliers, the same points, run after run
    pycolmap.set_random_seed(cfg.seed)
    stats.matcher = matcher
    try:
        if matcher == "exhaustive":
            stats.pairs = len(views) * (len(views) - 1) // 2
            with running(f"sparse points for the given cameras: matching ({stats.pairs} pairs)"):
                pycolmap.match_exhaustive(str(db_path), matching_options=mopt, verification_options=vopt,
                                          device=pycolmap.Device.cpu)
        else:
            pairs = overlap_pairs(views, cfg.overlap_neighbors, cfg.max_view_angle_deg)
            stats.pairs = len(pairs)
            if not pairs:
                return fail("no two cameras look at the same part of the scene")
            pair_file = work / "pairs.txt"
            pair_file.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
            popt = pycolmap.ImportedPairingOptions()
            popt.match_list_path = str(pair_file)
            with running(f"sparse points for the given cameras: matching ({len(pairs)} pairs)"):
                pycolmap.match_image_pairs(str(db_path), matching_options=mopt, pairing_options=popt,
                                           verification_options=vopt, device=pycolmap.Device.cpu)
    except Exception as exc:
        return fail(f"feature matching failed ({_first_line(exc)})")
    stats.seconds["matching"] = time.perf_counter() - t0

    # 3. a reconstruction holding the given cameras, with the database's ids; triangulate, poses fixed
    t0 = time.perf_counter()
    db = pycolmap.Database.open(str(db_path))
    try:
        rec = _given_reconstruction(pycolmap, db, views, names, work)
    finally:
        db.close()
    sparse_dir = work / "sparse"
    sparse_dir.mkdir()
    # COLMAP ignores features seen in two views only (fewer, surer points); a pair has no other tracks, and a
    # sparse capture may have too few longer ones: then the two-view tracks count too
    for two_view in ((True,) if len(views) == 2 else (False, True)):
        opt = pycolmap.IncrementalPipelineOptions()
        # one thread: the bundle adjustment's threads sum residuals in any order, and a point near the
        # reprojection filter's threshold then stays in one run and goes in the next; with the poses fixed,
        # this step is a small part of the triangulation's time
        opt.num_threads = 1
        opt.random_seed = cfg.seed
        opt.extract_colors = False  # the working copies are contrast-normalised: colours come from the originals
        opt.triangulation.ignore_two_view_tracks = not two_view
        try:
            with running("sparse points for the given cameras: triangulation"):
                tri = pycolmap.triangulate_points(rec, str(db_path), str(work / "images"), str(sparse_dir),
                                                  clear_points=True, options=opt, refine_intrinsics=False)
        except Exception as exc:  # pycolmap raises RuntimeError / ValueError with COLMAP's check message
            return fail(f"COLMAP's point triangulator failed ({_first_line(exc)})")
        if tri.num_points3D() >= cfg.min_points:
            break
    rec = tri
    stats.seconds["triangulation"] = time.perf_counter() - t0

    result, moved = _to_model(rec, views, names)
    if moved > 1e-6:  # the triangulator is told to keep every pose constant; never hand back moved cameras
        return fail(f"COLMAP's triangulator moved a given camera by {moved:.3g}")
    result.colors = _point_colors(images_dir, result)
    stats.points = len(result.points)
    log.info("triangulated %d points for %d given cameras (%s matching, %d pairs) in %.1f s", stats.points,
             len(views), matcher, stats.pairs, sum(stats.seconds.values()))
    if stats.points < cfg.min_points:
        return fail(f"only {stats.points} points triangulated (fewer than {cfg.min_points}; too little "
                    "texture or overlap?)")
    return result


def _given_reconstruction(pycolmap, db, views: list[View], names: list[str], work: Path):
    """A pycolmap ``Reconstruction`` of the given cameras and poses that mirrors the database's ids (camera,
    rig, frame, image), so that COLMAP's triangulator finds every image's features and matches."""
    db_images = {im.name: im for im in db.read_all_images()}
    frame_of = {}
    for fr in db.read_all_frames():
        for d in fr.image_ids:
            frame_of[d.id] = fr
    rigs = {r.rig_id: r for r in db.read_all_rigs()}
    rec = pycolmap.Reconstruction()
    for v, name in zip(views, names):
        dbim = db_images.get(name)
        fr = frame_of.get(dbim.image_id) if dbim is not None else None
        if dbim is None or fr is None:
            raise InputDataError(f"view {v.name}: COLMAP could not read its working copy {work / 'images' / name}")
        rig = rigs[fr.rig_id]
        if rig.num_sensors() != 1 or rig.ref_sensor_id.id != dbim.camera_id:
            raise InputDataError(f"view {v.name}: unexpected COLMAP rig {rig.rig_id} for camera {dbim.camera_id}")
        m, w, h, params = colmap_from_intrinsics(v.intrinsics)
        cam = pycolmap.Camera(model=m, width=w, height=h, params=params, camera_id=dbim.camera_id)
        db.update_camera(cam)  # keep the database consistent with the given intrinsics
        rec.add_camera(cam)
        rec.add_rig(rig)
        fr.rig_from_world = pycolmap.Rigid3d(v.cam_from_world[:3, :4])  # trivial rig: rig = camera
        rec.add_frame(fr)
        image = pycolmap.Image(name=name, camera_id=dbim.camera_id, image_id=dbim.image_id)
        image.frame_id = fr.frame_id
        rec.add_image(image)
        rec.register_frame(fr.frame_id)
    return rec


def _point_colors(images_dir: Path, model: SparseModel) -> np.ndarray:
    """(K, 3) uint8 RGB of each point: the mean of the original images' pixels at its observations."""
    index = model.point_index()
    acc = np.zeros((len(model.points), 3))
    cnt = np.zeros(len(model.points))
    for v in model.views:
        uv, ids = model.observations.get(v.name, (np.zeros((0, 2)), np.zeros(0, np.int64)))
        keep = ids >= 0
        if not keep.any():
            continue
        bgr, _ = _read_rgb_alpha(find_image(images_dir, v))
        H, W = bgr.shape[:2]
        px = np.clip(np.rint(uv[keep]).astype(int), 0, [W - 1, H - 1])
        rows = np.array([index[int(p)] for p in ids[keep]])
        np.add.at(acc, rows, bgr[px[:, 1], px[:, 0], ::-1].astype(float))
        np.add.at(cnt, rows, 1.0)
    return np.clip(np.rint(acc / np.maximum(cnt, 1)[:, None]), 0, 255).astype(np.uint8)


def _to_model(rec, views: list[View], names: list[str]) -> tuple[SparseModel, float]:
    """(the triangulated points on the original ``views``, the largest change of a camera's [R|t] in COLMAP)."""
    by_name = {rec.images[i].name: rec.images[i] for i in rec.images}
    obs, moved = {}, 0.0
    for v, name in zip(views, names):
        image = by_name.get(name)
        if image is None:
            obs[v.name] = (np.zeros((0, 2)), np.zeros(0, np.int64))
            continue
        moved = max(moved, float(np.abs(image.cam_from_world().matrix() - v.cam_from_world[:3, :4]).max()))
        pts = image.points2D
        xy = np.array([p.xy for p in pts], float).reshape(-1, 2) - 0.5
        ids = np.array([p.point3D_id if p.has_point3D() else -1 for p in pts], np.int64)
        obs[v.name] = (xy, ids)
    pids = np.array(sorted(rec.point3D_ids()), np.int64) if rec.num_points3D() else np.zeros(0, np.int64)
    xyz = np.array([rec.points3D[int(i)].xyz for i in pids], float).reshape(-1, 3)
    rgb = np.array([rec.points3D[int(i)].color for i in pids], np.uint8).reshape(-1, 3)
    err = np.array([rec.points3D[int(i)].error for i in pids], float)
    # numbered by position (1, 2, ...), not in the order COLMAP created them
    order, rank = position_order(xyz)
    rank += 1
    for name, (xy, ids) in obs.items():
        seen = ids >= 0
        new = ids.copy()
        new[seen] = rank[np.searchsorted(pids, ids[seen])]
        obs[name] = (xy, new)
    return SparseModel(views, xyz[order], rgb[order], rank[order], err[order], obs), moved
