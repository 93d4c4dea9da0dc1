"""Disk space: what a full disk looks like (``is_no_space``), the one-line error naming the file and its device
(``no_space_error``), and a check before a step that writes a lot (``check_space``). The first two live below
``io`` (``photorecon._disk``, ``photorecon.errors``), so that ``errors.py`` needs nothing from here."""
from __future__ import annotations

from pathlib import Path

from .._disk import free_bytes, is_no_space  # noqa: F401 (is_no_space: io.atomic and stages take it from here)
from ..errors import no_space_error  # noqa: F401


def check_space(path: str | Path, need: int) -> None:
    """``no_space_error`` when the file system of ``path`` has less than ``need`` bytes available: checked
    before a step whose writer would abort the process on a full disk (COLMAP's SQLite database)."""
    free = free_bytes(path)
    if free is not None and free < need:
        raise no_space_error(path, need)
