"""``photorecon convert``: cameras from any format ``read_model`` reads to any format of the registry
(``io.cameras``) that can be written: COLMAP text/binary, transforms.json (nerfstudio / instant-ngp and NeRF
Blender-synthetic), IDR / NeuS ``cameras_sphere.npz``, LLFF ``poses_bounds.npy`` and PyTorch3D (write only)."""
from __future__ import annotations

from pathlib import Path

from ..errors import BadArgumentError
from . import cameras as camera_formats
from .cameras import SparseModel
from .cameras.pytorch3d import write_pytorch3d  # noqa: F401  (its old place)
from .cameras.transforms import read_transforms
from .dataset import read_model

FORMATS = ("auto", *camera_formats.writable())  # as at import; ``formats()`` also lists formats registered later


def formats() -> tuple[str, ...]:
    """``--to``'s choices: "auto" and every format that can be written."""
    return ("auto", *camera_formats.writable())


def load_cameras(src: str | Path, src_world: str | None = None, neus_world: str = "normalized") -> SparseModel:
    """``src_world``: the NeRF world orientation of a transforms.json (default: as the file records it);
    ``neus_world``: "normalized" or "original" world of a NeuS ``cameras_sphere.npz``."""
    src = Path(src)
    if src.is_file() and src.suffix == ".json":
        return SparseModel(read_transforms(src, src_world))
    return read_model(src, neus_world=neus_world)


def output_format(dst: Path) -> str:
    """The format ``auto`` picks from DST's name."""
    return camera_formats.output_format(dst)


def writes_folder(to: str, dst: Path) -> bool:
    """Whether ``convert --to TO`` writes DST as a folder (COLMAP) rather than one file."""
    fmt = next((f for f in camera_formats.FORMATS if f.NAME == (output_format(Path(dst)) if to == "auto" else to)), None)
    return fmt is not None and getattr(fmt, "SUFFIX", None) is None


def convert_cameras(src, dst, to: str = "auto", world: str = "none", src_world: str | None = None,
                    neus_world: str = "normalized", bounds: tuple[float, float] | None = None) -> Path:
    """Read cameras from ``src`` (anything ``read_model`` reads) and write them to ``dst`` as ``to``.
    ``world``: NeRF world orientation written to a transforms.json; ``bounds``: LLFF near / far for every
    image (default: from the sparse points)."""
    model = load_cameras(src, src_world, neus_world)
    dst = Path(dst)
    if to == "auto":
        to = output_format(dst)
    fmt = next((f for f in camera_formats.FORMATS if f.NAME == to and hasattr(f, "write")), None)
    if fmt is None:
        raise BadArgumentError(f"convert: unknown output format {to!r}; expected one of {formats()}")
    suffix = getattr(fmt, "SUFFIX", None)
    if suffix is not None and dst.suffix != suffix:
        raise BadArgumentError(f"convert: {to} output must be a {suffix} file, got {dst}")
    return fmt.write(model, dst, world=world, bounds=bounds)
