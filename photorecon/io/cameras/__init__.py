"""Camera formats: one module each, and the one registry (``FORMATS``) that the dataset reader
(``io.dataset.read_model``), ``photorecon convert`` and its ``--to`` choices read.

A format module defines:

* ``NAME``: its name on the command line (``--to NAME``);
* ``detect(path) -> Path | None``: the file or folder ``read`` takes when ``path`` (a file, or a dataset or model
  folder) holds this format, else None;
* ``read(path, **options) -> SparseModel`` (options it does not know are ignored: ``world`` (a transforms.json's
  NeRF world), ``neus_world``);
* optionally ``write(model, path, **options) -> Path`` (options: ``world``, ``bounds``) and ``SUFFIX``, the file
  suffix it writes (None: a folder); a format without ``write`` is read-only, one without ``detect`` and
  ``read`` write-only;
* optionally ``auto_output(path) -> bool``: ``convert --to auto`` picks it for the destination ``path``;
* optionally ``LOOKS_FOR`` and ``FILE_NAME``: how the "no cameras found" message names it.

Adding a format: a module here, and its line in ``FORMATS``. The order of ``FORMATS`` is the order of
detection (the first format that finds cameras in a folder reads them) and of the ``--to`` choices.
"""
from __future__ import annotations

from pathlib import Path

from ...errors import BadArgumentError, InputDataError
from . import blender, colmap_bin, colmap_text, llff, neus, pytorch3d, strecha, transforms
from .model import SparseModel

FORMATS: list = [
    colmap_text,
    colmap_bin,
    transforms,
    blender,
    neus,
    llff,
    strecha,
    pytorch3d,
]
DEFAULT_OUTPUT = "colmap-text"  # what ``convert --to auto`` writes when no format claims the destination

__all__ = ["DEFAULT_OUTPUT", "FORMATS", "SparseModel", "detect", "output_format", "read", "register",
           "writable"]


def register(module):
    """Add a format module (or any object with the same attributes) to ``FORMATS``, after the others."""
    if not isinstance(getattr(module, "NAME", None), str) or not (hasattr(module, "read") or hasattr(module, "write")):
        raise BadArgumentError(f"camera format {module!r}: expected NAME and read or write")
    if any(f.NAME == module.NAME for f in FORMATS):
        raise BadArgumentError(f"camera format {module.NAME!r} is registered already")
    FORMATS.append(module)
    return module


def writable() -> list[str]:
    """The names of the formats that can be written, in registry order."""
    return [f.NAME for f in FORMATS if hasattr(f, "write")]


def detect(path: str | Path):
    """(format module, the path its ``read`` takes) for the first format that finds cameras at ``path``, or
    None."""
    path = Path(path)
    for f in FORMATS:
        found = f.detect(path) if hasattr(f, "detect") else None
        if found is not None:
            return f, found
    return None


def _names(items: list[str]) -> str:
    return items[0] if len(items) < 2 else ", ".join(items[:-1]) + " or " + items[-1]


def read(path: str | Path, **options) -> SparseModel:
    """Cameras (and sparse points, if any) from ``path``, in the first format that detects them; raises
    ``InputDataError`` naming the formats looked for when none does."""
    path = Path(path)
    found = detect(path)
    if found is not None:
        fmt, where = found
        return fmt.read(where, **options)
    if not path.is_dir():
        files = [f.FILE_NAME for f in FORMATS if getattr(f, "FILE_NAME", None)]
        raise InputDataError(f"{path}: no such COLMAP model folder or camera file ({', '.join(files)})")
    looked = [f.LOOKS_FOR for f in FORMATS if getattr(f, "LOOKS_FOR", None)]
    raise InputDataError(f"{path}: no cameras found; expected {_names(looked)}")


def output_format(dst: str | Path) -> str:
    """The format ``convert --to auto`` writes to ``dst``: the first that claims it, else ``DEFAULT_OUTPUT``."""
    dst = Path(dst)
    return next((f.NAME for f in FORMATS if hasattr(f, "auto_output") and f.auto_output(dst)), DEFAULT_OUTPUT)
