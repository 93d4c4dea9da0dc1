"""Given depth maps as a depth method of the whole stage (``reconstruct --depth FOLDER``): a folder of NAME.npy
z-depth maps (a synth dataset's ``depth/``, rendered or measured depth), checked and copied for the dataset's
views, scaled with the given cameras."""
from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np

from ...errors import BadArgumentError, NoDepthError

log = logging.getLogger("photorecon")

SOURCE = "folder"


def selected(run) -> bool:
    return run.depth != "mvs"


def check(run) -> None:
    """The folder, before anything is written."""
    if run.depth != "mvs" and not Path(run.depth).is_dir():
        raise BadArgumentError(f"--depth: expected 'mvs' or a folder of depth maps, got {run.depth!r}")


def inputs(run, fingerprint) -> list:
    """What the stage's key hashes: ``fingerprint`` (``stages.fingerprint``) of the folder."""
    return fingerprint(run.depth)


def run_stage(dataset, run, out_dir, executor, work, factor: float = 1.0) -> dict:
    """The folder's depth maps of the dataset's views, times ``factor`` (depth maps in the given cameras' units
    scale with them: --marker-size, GPS)."""
    n = copy_depth(Path(run.depth), dataset, Path(out_dir), factor)
    return {"source": str(run.depth), "views": n}


def copy_depth(src: Path, ds, dst: Path, factor: float = 1.0) -> int:
    """Copy NAME.npy depth maps (and confidences, previews) for the dataset's views; validate each.
    ``factor``: multiplies the depths (the metric scale applied to the given cameras)."""
    from ...io.images import read_depth

    dst.mkdir(parents=True, exist_ok=True)
    n = 0
    for v in ds.views:
        p = src / f"{v.name}.npy"
        if not p.is_file():
            log.warning("view %s: no depth map %s; skipped", v.name, p)
            continue
        d = read_depth(p, (v.intrinsics.height, v.intrinsics.width), v.name)
        if factor != 1.0:
            np.save(dst / p.name, (d * factor).astype(np.float32))
        else:
            shutil.copyfile(p, dst / p.name)
        for extra in (f"{v.name}.conf.npy", f"{v.name}.normal.npy", f"{v.name}.png"):
            if (src / extra).is_file():
                shutil.copyfile(src / extra, dst / extra)
        n += 1
    if not n:
        raise NoDepthError(f"{src}: no depth map matches the cameras' image names")
    return n
