"""SfM's second stage, matching (``match``): the features database copied and its image pairs matched and
verified, the pairs chosen by ``choose_matching`` (exhaustive, retrieval, sequential or spatial by EXIF GPS)."""
from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import BadArgumentError
from ..io.atomic import atomic_path
from ..io.space import check_space
from ..progress import running
from ._colmap import MB, _pycolmap

if TYPE_CHECKING:
    from .sfm import SfMConfig


def gps_priors(database: Path) -> int:
    """How many images of a COLMAP database carry a position prior (COLMAP reads EXIF GPS at extraction)."""
    import math

    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(database))
    try:
        return sum(1 for p in db.read_all_pose_priors()
                   if p.has_position() and all(math.isfinite(x) for x in p.position))
    finally:
        db.close()


def choose_matching(cfg: SfMConfig, num_images: int, with_gps: int = 0, video: bool = False) -> str:
    """``cfg.matching``, or for ``auto``: exhaustive up to ``cfg.exhaustive_max`` images; above it sequential
    for the frames of a ``video``, spatial when every image has a GPS prior (``with_gps`` of them), else
    retrieval. Raises ``BadArgumentError`` for ``spatial`` with fewer than 2 geotagged images."""
    if cfg.matching == "spatial" and with_gps < 2:
        raise BadArgumentError(f"--matching spatial: {with_gps} of {num_images} photos carry EXIF GPS; "
                               "use --matching retrieval (unordered photos), sequential (ordered captures) or exhaustive")
    if cfg.matching != "auto":
        return cfg.matching
    if num_images <= cfg.exhaustive_max:
        return "exhaustive"
    if video:
        return "sequential"
    return "spatial" if with_gps >= num_images else "retrieval"


def match(features: Path, database: Path, matching: str, cfg: SfMConfig, guided: bool = False) -> Path:
    """Match the features of the ``features`` database into a copy of it, ``database``; ``matching``:
    exhaustive, retrieval (the most similar photos by a visual index of the photos' own features, plus
    loop-closing pairs: ``retrieval.match_retrieval``), sequential (file-name order; loops closed by matching
    keyframes, ``_match_keyframes``, since COLMAP's loop detection needs a vocabulary tree, a download) or
    spatial (nearest by the GPS position priors COLMAP read from EXIF). ``guided``: matches are searched again
    along the verified two-view geometry (small photos: 12 views of the blob at 320x240, the weakest pair's
    inliers 16 -> 39)."""
    from .retrieval import match_retrieval

    pycolmap = _pycolmap()
    check_space(database, 2 * features.stat().st_size + MB)  # a copy of the features, then the matches
    with atomic_path(database) as tmp, running(f"SfM matching ({matching})"):
        shutil.copyfile(features, tmp)
        mopt = pycolmap.FeatureMatchingOptions()
        mopt.num_threads = cfg.threads
        mopt.guided_matching = guided
        vopt = pycolmap.TwoViewGeometryOptions()
        vopt.ransac.random_seed = cfg.seed  # each pair's RANSAC seeded: the same inliers whichever thread runs it
        if matching == "exhaustive":
            pycolmap.match_exhaustive(str(tmp), matching_options=mopt, verification_options=vopt,
                                      device=pycolmap.Device.cpu)
        elif matching == "retrieval":
            match_retrieval(tmp, cfg.retrieval_neighbors, mopt, cfg.seed, cfg.threads, vopt)
        elif matching == "spatial":
            popt = pycolmap.SpatialPairingOptions()
            popt.max_num_neighbors = cfg.spatial_neighbors
            popt.max_distance = cfg.spatial_max_distance
            popt.ignore_z = cfg.spatial_ignore_z
            pycolmap.match_spatial(str(tmp), matching_options=mopt, pairing_options=popt, verification_options=vopt,
                                   device=pycolmap.Device.cpu)
        elif matching == "sequential":
            popt = pycolmap.SequentialPairingOptions()
            popt.overlap = cfg.sequential_overlap
            popt.quadratic_overlap = True
            pycolmap.match_sequential(str(tmp), matching_options=mopt, pairing_options=popt,
                                      verification_options=vopt, device=pycolmap.Device.cpu)
            if cfg.sequential_loops:
                _match_keyframes(tmp, max(1, cfg.sequential_overlap), mopt, vopt)
        else:
            raise BadArgumentError(f"--matching: unknown choice {matching!r}")
    return database


def _match_keyframes(database: Path, every: int, mopt, vopt=None) -> int:
    """Loop closure for sequential matching: every ``every``-th image in name order (sequential's order) matched
    with every other one not already matched with it. Returns the number of pairs added."""
    from .retrieval import database_images, match_pairs

    key = sorted(database_images(database).values())[::every]
    return match_pairs(database, [(a, b) for i, a in enumerate(key) for b in key[i + 1:]], mopt, vopt)
