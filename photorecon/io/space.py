"""Disk space: what a full disk looks like (``is_no_space``), the one-line error naming the file and its device
(``no_space_error``), and a check before a step that writes a lot (``check_space``)."""
from __future__ import annotations

import errno
import os
from pathlib import Path

from ..errors import OutputError

# a full file system, a full quota, a file-size limit (RLIMIT_FSIZE with SIGXFSZ ignored)
NO_SPACE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def is_no_space(exc: BaseException) -> bool:
    """Whether ``exc`` is a write that failed for lack of space: ENOSPC/EDQUOT/EFBIG, or numpy's short write
    (``OSError: N requested and M written``, no errno)."""
    if not isinstance(exc, OSError):
        return False
    if exc.errno in NO_SPACE_ERRNOS:
        return True
    text = str(exc)
    return exc.errno is None and "requested and" in text and "written" in text


def _existing(path: Path) -> Path:
    p = Path(os.path.abspath(path))
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def free_bytes(path: str | Path) -> int | None:
    """Bytes available to this user on the file system of ``path`` (or of its nearest existing parent)."""
    try:
        st = os.statvfs(_existing(Path(path)))
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def _size(n: int | None) -> str:
    if n is None:
        return "unknown"
    for unit in ("bytes", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TB"  # pragma: no cover


def device(path: str | Path) -> str:
    """The file system holding ``path``: its mount point, type and free space, e.g. ``/data (ext4, 1.2 GB
    free)``."""
    p = _existing(Path(path)).resolve()
    mount = p
    while not os.path.ismount(mount) and mount != mount.parent:
        mount = mount.parent
    fstype = None
    try:
        for line in Path("/proc/mounts").read_text().splitlines():
            parts = line.split()
            if len(parts) >= 3 and parts[1].replace("\\040", " ") == str(mount):
                fstype = parts[2]
    except OSError:
        pass
    return f"{mount} ({fstype + ', ' if fstype else ''}{_size(free_bytes(p))} free)"


def no_space_error(path: str | Path, need: int | None = None) -> OutputError:
    """The one-line error for a write to ``path`` that the disk could not hold (``need``: bytes it needed)."""
    needed = f"; about {_size(need)} needed" if need else ""
    return OutputError(f"{path}: no space left on device {device(path)}{needed}; free some space or choose an "
                       "output folder on another device")


def check_space(path: str | Path, need: int) -> None:
    """``no_space_error`` when the file system of ``path`` has less than ``need`` bytes available: checked
    before a step whose writer would abort the process on a full disk (COLMAP's SQLite database)."""
    free = free_bytes(path)
    if free is not None and free < need:
        raise no_space_error(path, need)
