"""What a full disk looks like and where a file lives, with the standard library only (``errors.py`` builds its
no-space error from these; ``io/space.py`` is where the rest of photorecon takes them from): ``is_no_space``,
``free_bytes``, ``device`` and ``size_text``."""
from __future__ import annotations

import errno
import os
from pathlib import Path

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


def size_text(n: int | None) -> str:
    """``n`` bytes for a message: ``512 bytes``, ``3.2 MB``, ``1.5 GB`` (``unknown`` for None)."""
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
    return f"{mount} ({fstype + ', ' if fstype else ''}{size_text(free_bytes(p))} free)"
