"""Frames of a video file as the images to use: every k-th decoded frame, written as PNG (``--video-every``)."""
from __future__ import annotations

import logging
import os
from pathlib import Path

import cv2

from ..errors import BadArgumentError, NoImagesError
from ..io.atomic import atomic_path
from ..io.images import image_write_failed
from .photos import MAX_ASPECT, MIN_SIDE, TOO_NARROW, TOO_SMALL, Ingest, IngestedImage

log = logging.getLogger("photorecon")

VIDEO_SUFFIXES = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm")


def video_frames(video: str | Path, work: str | Path, every: int = 10) -> Ingest:
    """Every ``every``-th decoded frame of a video file as PNG images in ``work`` (frame_00000.png, ...). Frames
    that do not decode are passed over, and a warning says how many of the video's frames could be decoded.
    Frames COLMAP's SIFT cannot take (under ``MIN_SIDE`` pixels a side, longer than ``MAX_ASPECT``:1) raise
    ``NoImagesError``."""
    video, work = Path(video), Path(work)
    if every < 1:
        raise BadArgumentError(f"--video-every: expected a positive frame step, got {every}")
    if video.is_file() and video.stat().st_size == 0:
        raise NoImagesError(f"{video}: the video file is empty (0 bytes)")
    # FFmpeg prints its own line about a file it cannot read (``moov atom not found``): photorecon's one line
    # says it; the level is read when OpenCV first opens a video, and a level the user set is kept
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise NoImagesError(f"{video}: cannot open the video (unsupported codec or not a video)")
    work.mkdir(parents=True, exist_ok=True)
    total = max(0, int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0))  # the container's count (0: not known)
    out, k, failed = [], 0, 0
    try:
        while True:
            ok, frame = cap.read()
            if not ok:  # the end, or a frame that does not decode: read on while the count says more follow
                failed += 1
                if k + failed >= total:
                    break
                continue
            if k == 0 and (min(frame.shape[:2]) < MIN_SIDE or max(frame.shape[:2]) > MAX_ASPECT * min(frame.shape[:2])):
                H, W = frame.shape[:2]
                raise NoImagesError(f"{video}: its frames are {W}x{H}, "
                                    + (TOO_SMALL if min(H, W) < MIN_SIDE else TOO_NARROW))
            if k % every == 0:
                name = f"frame_{k:05d}.png"
                if not (work / name).exists():
                    with atomic_path(work / name) as tmp:
                        if not cv2.imwrite(str(tmp), frame):
                            image_write_failed(work / name, frame.nbytes)
                H, W = frame.shape[:2]
                out.append(IngestedImage(name, video, W, H))
            k += 1
    finally:
        cap.release()
    if not out:
        raise NoImagesError(f"{video}: no frame could be decoded" + (f" (of {total})" if total else ""))
    if k < total:
        log.warning("%s: %d of %d frames could be decoded (a damaged or incomplete video?); %d of them taken "
                    "(every %d-th)", video, k, total, len(out), every)
    else:
        log.info("video: %d of %d frames taken (every %d-th)", len(out), k, every)
    return Ingest(out)
