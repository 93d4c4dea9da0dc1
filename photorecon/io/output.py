"""Output folders: never inside an input, never a stranger's non-empty folder (unless overwrite)."""
from __future__ import annotations

from pathlib import Path

from ..errors import OutputError

MARKER = ".photorecon"


def prepare_output(out: str | Path, overwrite: bool = False, inputs: tuple = ()) -> Path:
    """Create ``out`` (or accept it if empty or a photorecon output); mark it as ours.

    Raises ``OutputError`` if ``out`` lies inside one of ``inputs`` (photorecon never writes into an input
    folder) or is a non-empty folder that photorecon did not write, unless ``overwrite``.
    """
    out = Path(out)
    res = out.resolve()
    for inp in inputs:
        if inp is None:
            continue
        ip = Path(inp).resolve()
        if not ip.is_dir():  # an input file: only refuse writing over it
            if res == ip:
                raise OutputError(f"output {out} is the input file {inp}; choose an output folder")
            continue
        if res == ip or res.is_relative_to(ip):
            raise OutputError(f"output {out} is inside the input folder {inp}; choose an output folder elsewhere")
    if out.exists() and not out.is_dir():
        raise OutputError(f"output {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / MARKER).exists() and not overwrite:
        raise OutputError(f"output folder {out} is not empty and was not written by photorecon; "
                          "pass --overwrite or choose another folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / MARKER).write_text("written by photorecon\n")
    except OSError as exc:
        raise OutputError(f"output folder {out}: cannot write there ({exc.strerror or exc}); "
                          "choose a writable folder") from None
    return out
