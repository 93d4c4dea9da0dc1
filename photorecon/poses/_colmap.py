"""What the structure-from-motion modules share about pycolmap: its lazy import (``_pycolmap``; pycolmap's API
changes between versions, so it is imported inside functions, here and in ``poses/triangulate.py`` and
``io/cameras/colmap_bin.py``), COLMAP's log level (``_quiet``) and the message for a mapping that made no model
(``no_model_message``)."""
from __future__ import annotations

import logging
from pathlib import Path

log = logging.getLogger("photorecon")

MB = 1 << 20


def _pycolmap():
    import cv2  # noqa: F401  (first: OpenCV loaded after pycolmap crashes in its PNG writer, two zlib builds)
    import pycolmap

    return pycolmap


def _quiet(pycolmap) -> None:
    """COLMAP logs every step, and its recoverable errors ("Failed to create any sparse model" before a retry
    with relaxed thresholds), to stderr; photorecon reports what failed in its own line, so COLMAP's log shows
    only with --verbose (its fatal errors always)."""
    pycolmap.logging.minloglevel = 0 if log.isEnabledFor(logging.DEBUG) else 3


def no_model_message(database: Path, n: int) -> str:
    """Why mapping made no model of ``n`` images, from the matches in ``database``: none verified (the photos
    do not overlap), or pairs matched that no model could start from."""
    pycolmap = _pycolmap()
    try:
        db = pycolmap.Database.open(str(database))
        try:
            pairs, inliers = db.num_verified_image_pairs(), db.num_inlier_matches()
        finally:
            db.close()
    except Exception:  # no database to read: say what is known
        pairs = inliers = 0
    if not pairs:
        return (f"0 of {n} images registered: no two images could be matched (do the photos overlap? are they "
                "all identical?)")
    return (f"0 of {n} images registered: {pairs} image pairs were matched ({inliers:,} inlier matches), but no "
            "model could be started from any of them (too little parallax between the photos, or a wrong focal "
            "length: check --intrinsics / --fx and the photos' EXIF)")
