"""What the sub-commands share: the ``--quality`` option (its presets: ``photorecon.presets``), the output
options, the options ``-h`` shows (the others are in ``--help-all``) and their short help texts.
"""
from __future__ import annotations

import argparse

from .settings import apply_preset


OVERWRITE_HELP = ("write into a non-empty folder this command did not write: its files are added next to what is "
                  "there, which is kept (never replaced)")
OVERWRITE_FILE_HELP = "replace an existing output file (never an input, never part of a photorecon result)"


def _out_args(p: argparse.ArgumentParser, required: bool = True) -> None:
    p.add_argument("-o", "--out", required=required, help="output folder")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


# The quality presets of ``reconstruct --quality`` (and of ``mvs`` / ``sfm`` for their own stages) are
# photorecon.presets' table, the one the Python API reads (StageConfigs.from_preset): settings by ``dest``; a flag
# the user gives (or a --config file sets) wins over the preset.
from ..presets import QUALITY_PRESETS  # noqa: E402


# What -h shows of the commands with many options (the others: --help-all). An option a command lacks is skipped.
_BASIC = ["-h", "--help-all", "-o", "--overwrite", "-q", "-v", "--config", "--quality", "--force"]


COMMON_OPTIONS: dict[str, list[str]] = {
    "reconstruct": _BASIC + ["--scene", "--poses", "--masks", "--texture", "--formats", "--depth-model",
                             "--model-faces", "--intrinsics", "--max-image-size", "--max-size", "--voxel-size",
                             "--target-faces", "--cluster", "--marker-size"],
    "sfm": _BASIC + ["--masks", "--intrinsics", "--camera-model", "--max-image-size", "--max-features",
                     "--matching", "--mapper", "--marker-size", "--video-every"],
    "mvs": _BASIC + ["--masks", "--method", "--max-size", "--n-sources", "--min-consistent", "--min-confidence",
                     "--cluster"],
    "fuse": _BASIC + ["--depth-dir", "--masks", "--formats", "--mesher", "--voxel-size", "--trunc-voxels",
                      "--scene", "--target-faces", "--crop", "--cluster"],
}


# -h texts of common options whose full help (in --help-all) is longer than two lines
SHORT_HELP: dict[str, str] = {
    "--quality": "preview: fast and coarse; default; high: finer and slower (--help-all: what each sets)",
    "--overwrite": "allow a non-empty output folder not made by photorecon",
    "--config": "settings file (TOML); flags on the command line win",
    "--masks": "mask folder (NAME.png, 0 = ignore the pixel; default: alpha channel)",
    "--intrinsics": "3x3 K text file (pixels): known intrinsics, kept fixed",
    "--max-image-size": "SfM: longest image side for features, pixels (default: 1600)",
    "--max-size": "depth: working resolution, longest side in pixels (default: 1600; 0 = full)",
    "--voxel-size": "TSDF voxel size, scene units (default: from the depth maps' resolution)",
    "--scene": "object: remove the table or turntable under it; open: keep the ground; auto (default): from the cameras",
    "--target-faces": "simplify the mesh to this many faces (default: 0 = keep)",
    "--cluster": "run the depth and fusion tasks on Dask: local:N or tcp://HOST:PORT",
    "--marker-size": "ArUco marker edge length, metres: scale the model to metres",
    "--depth-model": "monocular depth from this ONNX model (MiDaS-style) instead of MVS",
    "--poses": "known cameras (COLMAP folder or transforms.json) instead of SfM",
    "--texture": "on (default): also write OUT/model.glb, the mesh simplified and textured from the photos; off: skip it",
    "--model-faces": "faces of OUT/model.glb, the textured model (default: 150000; 0 = all of the mesh's)",
    "--camera-model": "camera model to self-calibrate (default: SIMPLE_RADIAL)",
    "--matching": "image pairs to match: auto, exhaustive, retrieval, sequential, spatial (default: auto)",
    "--mapper": "incremental or global (GLOMAP) mapping (default: auto)",
    "--method": "patchmatch (default) or sweep (a plane sweep: a rough preview, far less accurate)",
    "--min-confidence": "drop depths below this confidence, 0..1 (default: 0.2)",
    "--mesher": "tsdf (default), grid or poisson",
    "--crop": "crop box xmin,ymin,zmin,xmax,ymax,zmax, scene units",
}


def _quality_arg(p: argparse.ArgumentParser, what: str) -> None:
    def show(name):
        return ", ".join(f"{d.split('.', 1)[1].replace('_', '-')} {v}" for d, v in QUALITY_PRESETS[name].items()
                         if d.split(".", 1)[0] in what)

    p.add_argument("--quality", choices=list(QUALITY_PRESETS), default="default",
                   help=f"preset: preview = fast and coarse ({show('preview')}); high = slower and finer "
                        f"({show('high')}); flags given override it (default: default)")


def _apply_quality(args) -> None:
    apply_preset(args, QUALITY_PRESETS[getattr(args, "quality", "default") or "default"])
