"""SfM's third stage, mapping (``map_model``): incremental mapping, tried again with relaxed thresholds while it
leaves images out; hierarchical mapping (the photos split into clusters mapped side by side, then merged) for
larger sets, which falls back to incremental mapping when it registers too few; or global mapping (GLOMAP) for
the largest (``choose_mapper``). The largest model is kept."""
from __future__ import annotations

import logging
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import SfMError
from ..io.space import check_space
from ..progress import running
from ..stages import atomic_dir
from ._colmap import MB, _pycolmap, no_model_message

if TYPE_CHECKING:
    from .sfm import SfMConfig

log = logging.getLogger("photorecon")


# --mapper auto maps hierarchically from this many images (below --global-min): pycolmap's hierarchical mapping
# splits the view graph into clusters of at most HIERARCHICAL_LEAF_MAX images, maps them side by side (one thread
# each, as incremental mapping) and merges them. On gold_cape's 119 handheld photos (the same matches,
# tools/bench_mappers.py, 2026-11-29, 2-core host, shared): 117 registered at 0.095 deg mean rotation error in
# 101-104 CPU s (two runs, the same poses) against incremental mapping's 118 at 0.087 deg in 281 CPU s. Below
# 100 images incremental mapping takes minutes at most and a split has little to gain.
HIERARCHICAL_MIN = 100
HIERARCHICAL_LEAF_MAX = 60
# a hierarchical mapping whose largest model registers fewer than this share of the images with verified matches
# (``_matched``) is discarded and the images mapped incrementally (with its relaxed retries) instead
HIERARCHICAL_MIN_SHARE = 0.98


def choose_mapper(cfg: SfMConfig, num_images: int) -> str:
    if cfg.mapper != "auto":
        return cfg.mapper
    if num_images >= cfg.global_min:
        return "global"
    return "hierarchical" if num_images >= HIERARCHICAL_MIN else "incremental"


# Incremental mapping tried again with these thresholds, one set after the other, while a model leaves images
# out: COLMAP's defaults ignore two-view tracks and want 100 inliers to start and 30 to register, too many for
# a few small photos (12 views of the blob at 320x240, 53-60 degrees apart: 7 -> 12 registered with the first).
RELAXED_MAPPING = (
    {"triangulation.ignore_two_view_tracks": False, "mapper.init_min_num_inliers": 50,
     "mapper.abs_pose_min_num_inliers": 15},
    {"triangulation.ignore_two_view_tracks": False, "mapper.init_min_num_inliers": 30,
     "mapper.init_min_tri_angle": 8.0, "mapper.abs_pose_min_num_inliers": 12, "mapper.abs_pose_min_inlier_ratio": 0.15},
)


# Incremental mapping runs on one thread, whatever --threads: bundle adjustment's threads sum in the order they
# finish, so the same matches gave cameras apart in their last digits (48 synthetic ring views at 320x240, two
# threads: 3 different models in 3 runs, poses 2e-15 apart) and, from there, now and then another model (another
# coordinate frame, another mesh). On one thread: the same model, byte for byte, 3 runs of 3, whatever the
# output folder's history; 9.3-11.0 CPU s against 11.4-12.2 on two threads (2026-11-28, 2 shared cores). On a
# machine with many cores the mapping's wall time grows towards its CPU time. Global mapping keeps its threads.
MAPPER_THREADS = 1


def _incremental_options(pycolmap, cfg: SfMConfig, fixed_intrinsics: bool, relaxed: dict | None = None):
    opt = pycolmap.IncrementalPipelineOptions()
    opt.random_seed = cfg.seed
    opt.num_threads = MAPPER_THREADS
    if fixed_intrinsics:
        opt.ba_refine_focal_length = False
        opt.ba_refine_principal_point = False
        opt.ba_refine_extra_params = False
    for key, value in (relaxed or {}).items():
        group, _, name = key.rpartition(".")
        setattr(getattr(opt, group) if group else opt, name, value)
    return opt


def _global_options(pycolmap, cfg: SfMConfig, fixed_intrinsics: bool):
    gopt = pycolmap.GlobalPipelineOptions()
    gopt.random_seed = cfg.seed
    gopt.num_threads = cfg.threads
    if fixed_intrinsics:
        gopt.mapper.bundle_adjustment.refine_focal_length = False
        gopt.mapper.bundle_adjustment.refine_principal_point = False
        gopt.mapper.bundle_adjustment.refine_extra_params = False
    return gopt


def _matched(pycolmap, database: Path, min_matches: int) -> tuple[dict, set]:
    """The images of ``database`` (id -> name) and the ids of those with at least ``min_matches`` verified matches
    with some other image."""
    db = pycolmap.Database.open(str(database))
    try:
        pairs, counts = db.read_two_view_geometry_num_inliers()
        names = {im.image_id: im.name for im in db.read_all_images()}
    finally:
        db.close()
    matched = set()
    for pair, count in zip(pairs, counts):
        if count >= min_matches:
            matched.update(pycolmap.pair_id_to_image_pair(pair))
    return names, matched


def _unmatchable(pycolmap, database: Path, recs: list, min_matches: int) -> list[str]:
    """The images of ``database`` that the largest of ``recs`` leaves out, when each of them has fewer than
    ``min_matches`` verified matches with every other image (no incremental mapping registers those, whatever
    its thresholds: RELAXED_MAPPING keeps ``min_num_matches``); else []."""
    names, matched = _matched(pycolmap, database, min_matches)
    best = max(recs, key=lambda r: r.num_reg_images())
    left_out = set(names) - {best.images[i].image_id for i in best.reg_image_ids()}
    return [] if left_out & matched else sorted(names[i] for i in left_out)


def _hierarchical(pycolmap, database: Path, images_dir: Path, runs: Path, cfg: SfMConfig,
                  fixed_intrinsics: bool) -> list:
    """pycolmap's hierarchical mapping: clusters of at most ``HIERARCHICAL_LEAF_MAX`` images, as many mapped at
    once as ``cfg.threads`` allows (each on one thread, with the incremental mapping's options), then merged.
    Returns its models, or [] when it registers fewer than ``HIERARCHICAL_MIN_SHARE`` of the images with verified
    matches (then ``map_model`` maps incrementally)."""
    opt = pycolmap.HierarchicalPipelineOptions()
    opt.incremental_options = _incremental_options(pycolmap, cfg, fixed_intrinsics)
    opt.clustering_options.leaf_max_num_images = HIERARCHICAL_LEAF_MAX
    opt.num_workers = cfg.threads if cfg.threads > 0 else (os.cpu_count() or 1)
    opt.num_threads = MAPPER_THREADS
    recs = list(pycolmap.hierarchical_mapping(str(database), str(images_dir), str(runs), opt).values())
    names, matched = _matched(pycolmap, database, opt.incremental_options.min_num_matches)
    got = max((r.num_reg_images() for r in recs), default=0)
    if got >= HIERARCHICAL_MIN_SHARE * len(matched):
        return recs
    log.info("mapping: hierarchical mapping registered %d of %d images (%d with verified matches); mapping them "
             "incrementally instead", got, len(names), len(matched))
    return []


def map_model(database: Path, images_dir: Path, model_dir: Path, cfg: SfMConfig, fixed_intrinsics: bool,
              mapper: str = "incremental") -> Path:
    """Incremental or global (``mapper``) mapping; writes the largest model, COLMAP binary, to ``model_dir``.
    Incremental mapping that leaves images out is tried again with relaxed thresholds (``RELAXED_MAPPING``);
    the model with the most images is kept."""
    pycolmap = _pycolmap()
    pycolmap.set_random_seed(cfg.seed)
    check_space(model_dir, database.stat().st_size // 2 + MB)
    n = sum(1 for _ in images_dir.iterdir())
    with tempfile.TemporaryDirectory(dir=model_dir.parent, prefix=".mapper") as runs, atomic_dir(model_dir) as tmp, \
            running(f"SfM {mapper} mapping ({n} photos)"):
        if mapper == "global":
            gopt = _global_options(pycolmap, cfg, fixed_intrinsics)
            recs = list(pycolmap.global_mapping(str(database), str(images_dir), runs, gopt).values())
        else:
            recs = []
            if mapper == "hierarchical":
                (Path(runs) / "h").mkdir()
                recs = _hierarchical(pycolmap, database, images_dir, Path(runs) / "h", cfg, fixed_intrinsics)
            for i, relaxed in enumerate((None,) + RELAXED_MAPPING if not recs else ()):
                if recs and max(r.num_reg_images() for r in recs) >= n:
                    break
                if recs and (lost := _unmatchable(pycolmap, database, recs, opt.min_num_matches)):
                    log.info("mapping: %d of %d images registered; not mapped again: the others (%s) have no "
                             "verified matches", max(r.num_reg_images() for r in recs), n, ", ".join(lost))
                    break
                if relaxed:
                    log.info("mapping: %d of %d images registered; again with relaxed thresholds (%d)",
                             max((r.num_reg_images() for r in recs), default=0), n, i)
                run_dir = Path(runs) / str(i)
                run_dir.mkdir()
                opt = _incremental_options(pycolmap, cfg, fixed_intrinsics, relaxed)
                recs += list(pycolmap.incremental_mapping(str(database), str(images_dir), str(run_dir), opt).values())
        if not recs:
            raise SfMError(no_model_message(database, n))
        max(recs, key=lambda r: r.num_reg_images()).write_binary(str(tmp))
    return model_dir
