"""photorecon: photos -> camera poses, per-image depth and one fused triangle mesh, on a plain CPU.

The stages are packages, in pipeline order: ``poses`` (ingest, SfM, given cameras, scale), ``depth`` (MVS,
monocular), ``fusion`` (depth maps -> one mesh), ``mesh`` (clean, texture, export), ``report`` (previews,
report.html); ``pipeline.reconstruct`` composes them and ``cli`` puts them on the command line.

The public API is available here, imported on first use (``photorecon.reconstruct``, the configs, the results
and the converters), so ``import photorecon`` stays light.
"""
import importlib
import importlib.abc
import importlib.util
import sys
from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("photorecon")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

from .cameras import Intrinsics, View, backproject_depth, look_at, project  # noqa: E402
from .errors import PhotoreconError  # noqa: E402

# Module paths of earlier layouts -> the module that holds the code now. ``import photorecon.sfm``,
# ``from photorecon.sfm import x`` and ``monkeypatch.setattr("photorecon.sfm.x", ...)`` all reach the same
# module object as ``photorecon.poses.sfm``.
_ALIASES = {
    "photorecon.ingest": "photorecon.poses.ingest",
    "photorecon.sfm": "photorecon.poses.sfm",
    "photorecon.triangulate": "photorecon.poses.triangulate",
    "photorecon.scale": "photorecon.poses.scale",
    "photorecon.scene": "photorecon.mesh.scene",
    "photorecon.texture": "photorecon.mesh.texture",
    "photorecon.preview": "photorecon.report.preview",
    "photorecon.commands": "photorecon.cli.commands",
    "photorecon.config": "photorecon.cli.config",
}


class _AliasLoader(importlib.abc.Loader):
    def __init__(self, target: str):
        self.target = target

    def create_module(self, spec):
        return importlib.import_module(self.target)

    def exec_module(self, module):  # the target module is already executed
        pass


class _AliasFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        real = _ALIASES.get(fullname)
        if real is None:
            return None
        return importlib.util.spec_from_loader(fullname, _AliasLoader(real))


if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
    sys.meta_path.insert(0, _AliasFinder())

# The public API, by name -> the module that defines it (imported on first access).
_LAZY = {
    "reconstruct": "photorecon.pipeline",
    "ReconstructConfig": "photorecon.pipeline",
    "ReconstructResult": "photorecon.pipeline",
    "StageConfigs": "photorecon.pipeline",
    "SfMConfig": "photorecon.poses.sfm",
    "SfMResult": "photorecon.poses.sfm",
    "run_sfm": "photorecon.poses.sfm",
    "ScaleConfig": "photorecon.poses.scale",
    "MVSConfig": "photorecon.depth.mvs",
    "MVSResult": "photorecon.depth.mvs",
    "run_mvs": "photorecon.depth.mvs",
    "MonoConfig": "photorecon.depth.mono",
    "MonoResult": "photorecon.depth.mono",
    "FusionConfig": "photorecon.fusion",
    "fuse": "photorecon.fusion",
    "fuse_dataset": "photorecon.fusion",
    "CleanConfig": "photorecon.mesh",
    "clean": "photorecon.mesh",
    "export": "photorecon.mesh",
    "load_mesh": "photorecon.mesh",
    "TextureConfig": "photorecon.mesh.texture",
    "ClusterConfig": "photorecon.distributed",
    "SynthConfig": "photorecon.synthetic",
    "synthesize": "photorecon.synthetic",
    "Dataset": "photorecon.io.dataset",
    "read_model": "photorecon.io.dataset",
    "convert_cameras": "photorecon.io.convert",
    "load_cameras": "photorecon.io.convert",
    "conventions": "photorecon.conventions",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'photorecon' has no attribute {name!r}")
    mod = importlib.import_module(module)
    value = mod if module.endswith("." + name) else getattr(mod, name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


__all__ = ["Intrinsics", "View", "backproject_depth", "look_at", "project", "PhotoreconError", "__version__",
           *_LAZY]
