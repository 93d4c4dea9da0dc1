"""photorecon: photos -> camera poses, per-image depth and one fused triangle mesh, on a plain CPU."""
from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("photorecon")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

from .cameras import Intrinsics, View, backproject_depth, look_at, project  # noqa: E402
from .errors import PhotoreconError  # noqa: E402

__all__ = ["Intrinsics", "View", "backproject_depth", "look_at", "project", "PhotoreconError", "__version__"]
