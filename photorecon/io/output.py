"""Output folders: never an input, never holding an input, never a stranger's files; one run at a time.

``output_folder`` is what every command that writes a folder goes through::

    with output_folder(out, overwrite, inputs=(images, masks)) as out:
        ...  # write into out

It refuses (``OutputError``, before anything is written) an output that is an input, lies inside an input
folder or holds an input; a non-empty folder that photorecon did not write (no ``.photorecon`` marker) unless
``overwrite``, and even then one that already holds a path photorecon's layout writes or deletes (``images/``,
``sparse/``, ``mesh.ply`` ...): ``--overwrite`` adds photorecon's files next to a user's, it never replaces
one. Then it takes the folder's lock (``output_lock``) for the duration of the run.

The lock is ``OUT/.photorecon.lock``: created with ``O_EXCL`` and held with ``flock`` while the run goes on; it
records the process id, host, start time and command. A second run on the same folder stops with an
``OutputError`` naming that process. A lock left by a run that died (SIGKILL, a crash, power loss: the ``flock``
went with the process; without ``flock``, a dead process id on this host) is taken over with a warning. The
lock is removed when the run ends, also on an error or Ctrl-C.
"""
from __future__ import annotations

import json
import logging
import os
import socket
import sys
import time
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError
from ..layout import WRITTEN_NAMES

try:
    import fcntl
except ImportError:  # pragma: no cover  (not POSIX: the process-id check alone)
    fcntl = None

log = logging.getLogger("photorecon")

MARKER = ".photorecon"
LOCK = ".photorecon.lock"


def _resolve(p: str | Path) -> Path:
    return Path(p).expanduser().resolve()


def check_output(out: str | Path, overwrite: bool = False, inputs: tuple = (),
                 writes: tuple[str, ...] = WRITTEN_NAMES) -> Path:
    """Check ``out`` against ``inputs`` (files or folders, None ignored) and its content, writing nothing.

    Raises ``OutputError`` when ``out`` is an input, lies inside an input folder, or holds an input; when it
    exists and is not a folder; when it is a non-empty folder without photorecon's marker and not ``overwrite``;
    and, with ``overwrite``, when such a folder already holds one of ``writes`` (names photorecon writes or
    deletes there), naming it."""
    out = Path(out)
    check_apart(out, inputs)
    if out.exists() and not out.is_dir():
        raise OutputError(f"output {out} exists and is not a folder")
    if not out.is_dir() or (out / MARKER).exists():
        return out
    content = [p for p in out.iterdir() if p.name != LOCK]
    if not content:
        return out
    if not overwrite:
        raise OutputError(f"output folder {out} is not empty and was not written by photorecon; "
                          "pass --overwrite or choose another folder")
    taken = [n for n in writes if (out / n).exists() or (out / n).is_symlink()]
    if taken:
        raise OutputError(f"output folder {out} was not written by photorecon and already holds {out / taken[0]}"
                          + (f" (and {len(taken) - 1} more of photorecon's names)" if len(taken) > 1 else "")
                          + ", which photorecon would replace; --overwrite never replaces a file photorecon did not "
                            "write: choose another folder or move it away")
    return out


def check_apart(out: str | Path, inputs: tuple = (), may_hold: tuple = ()) -> None:
    """``OutputError`` when ``out`` is one of ``inputs`` (files or folders; None ignored), lies inside an input
    folder, or holds an input, except that ``out`` may lie inside the folders ``may_hold`` (a dataset whose
    depth/ or textured/ a command writes)."""
    out = Path(out)
    res = _resolve(out)
    inside_ok = [_resolve(p) for p in may_hold if p is not None]
    for inp in inputs:
        if inp is None or str(inp) == "":
            continue
        ip = _resolve(inp)
        if res == ip:
            raise OutputError(f"output {out} is the input {inp}; choose an output folder outside the inputs")
        if ip.is_dir() and res.is_relative_to(ip) and ip not in inside_ok:
            raise OutputError(f"output {out} is inside the input folder {inp}; choose an output folder outside it")
        if ip.is_relative_to(res):
            raise OutputError(f"output {out} holds the input {inp}, which writing there could replace or delete; "
                              "choose an output folder outside the inputs")


def is_photorecon_folder(folder: str | Path) -> bool:
    """Whether ``folder`` was written by photorecon: it, or the folder it is in, carries the marker."""
    folder = Path(folder)
    return (folder / MARKER).exists() or (folder.parent / MARKER).exists()


def check_foreign_files(folder: str | Path, names) -> None:
    """``OutputError`` when ``folder`` exists, was not written by photorecon (``is_photorecon_folder``) and holds
    one of ``names`` (the files a command is about to write or replace there), naming it."""
    folder = Path(folder)
    if not folder.is_dir() or is_photorecon_folder(folder):
        return
    taken = [n for n in names if (folder / n).exists()]
    if taken:
        raise OutputError(f"{folder} was not written by photorecon and already holds {folder / taken[0]}"
                          + (f" (and {len(taken) - 1} more)" if len(taken) > 1 else "")
                          + ", which would be replaced; choose another output folder (-o)")


def _mark(out: Path) -> None:
    if not (out / MARKER).exists():
        (out / MARKER).write_text("written by photorecon\n")


def prepare_output(out: str | Path, overwrite: bool = False, inputs: tuple = (),
                   writes: tuple[str, ...] = WRITTEN_NAMES) -> Path:
    """``check_output``, then create ``out`` and mark it as photorecon's. Takes no lock: a run uses
    ``output_folder``."""
    out = check_output(out, overwrite, inputs, writes)
    try:
        out.mkdir(parents=True, exist_ok=True)
        _mark(out)
    except OSError as exc:
        raise OutputError(f"output folder {out}: cannot write there ({exc.strerror or exc}); "
                          "choose a writable folder") from None
    return out


@contextmanager
def output_folder(out: str | Path, overwrite: bool = False, inputs: tuple = (),
                  writes: tuple[str, ...] = WRITTEN_NAMES):
    """Check ``out`` (``check_output``), create it, lock it (``output_lock``), mark it as photorecon's and
    yield it as a ``Path``; the lock is released when the block ends. A folder this call created is removed
    again when the block fails before writing anything into it."""
    out = check_output(out, overwrite, inputs, writes)
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"output folder {out}: cannot write there ({exc.strerror or exc}); "
                          "choose a writable folder") from None
    try:
        with output_lock(out):
            try:
                _mark(out)
            except OSError as exc:
                raise OutputError(f"output folder {out}: cannot write there ({exc.strerror or exc}); "
                                  "choose a writable folder") from None
            yield out
    except BaseException:
        if created:
            _remove_if_unused(out)
        raise


def _remove_if_unused(out: Path) -> None:
    """Remove ``out`` when it holds no file but photorecon's marker (empty folders aside)."""
    import shutil

    try:
        if all(p.is_dir() or p == out / MARKER for p in out.rglob("*")):
            shutil.rmtree(out)
    except OSError:
        pass


# --- the lock ---------------------------------------------------------------------------------------------------
_HELD: dict[str, list] = {}  # resolved folder -> [fd, depth]: a run locking a folder it already holds nests


def _describe(info: dict) -> str:
    return (f"process {info.get('pid', '?')} on {info.get('host', '?')}, started {info.get('started', '?')}"
            + (f": {info['command']}" if info.get("command") else ""))


def _read_info(fd: int) -> dict:
    try:
        data = os.pread(fd, 4096, 0)
        info = json.loads(data.decode("utf-8", "replace") or "{}")
        return info if isinstance(info, dict) else {}
    except (OSError, ValueError):
        return {}


def _alive(info: dict) -> bool:
    """Whether the process that wrote ``info`` may still run: False for a process id that is not running on
    this host, and for a lock file without one (a run that died as it created it)."""
    try:
        pid = int(info.get("pid"))
    except (TypeError, ValueError):
        return False
    if info.get("host") != socket.gethostname():
        return True
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _in_use(folder: Path, info: dict, path: Path) -> OutputError:
    return OutputError(f"output folder {folder} is in use by another photorecon run ({_describe(info)}); wait for "
                       f"it to finish or choose another output folder (if no such run is going on, remove {path})")


def _acquire(folder: Path, path: Path) -> int:
    me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%d %H:%M:%S %z"),
          "command": " ".join(["photorecon", *sys.argv[1:]])[:300] if sys.argv and sys.argv[0] else ""}
    for _ in range(20):
        created = True
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            created = False
            try:
                fd = os.open(path, os.O_RDWR)
            except FileNotFoundError:  # released meanwhile
                continue
        except OSError as exc:
            raise OutputError(f"output folder {folder}: cannot write there ({exc.strerror or exc}); "
                              "choose a writable folder") from None
        flocked = False
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                flocked = True
            except BlockingIOError:
                info = _read_info(fd)
                os.close(fd)
                raise _in_use(folder, info, path) from None
            except OSError:  # no flock on this file system: the process-id check decides
                pass
        try:  # still the file at ``path``? (its holder may have removed it after we opened it)
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if not same:
            os.close(fd)
            continue
        if not created:
            info = _read_info(fd)
            if not flocked and _alive(info):
                os.close(fd)
                raise _in_use(folder, info, path)
            if info:
                log.warning("output folder %s: the run that locked it (%s) is no longer running; taking it over",
                            folder, _describe(info))
        data = json.dumps(me).encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, data, 0)
        return fd
    raise OutputError(f"output folder {folder}: could not take its lock {path}; is another run starting there?")


def _release(path: Path, fd: int) -> None:
    try:
        if os.fstat(fd).st_ino == os.stat(path).st_ino:
            path.unlink()
    except OSError:
        pass
    finally:
        os.close(fd)  # releases the flock


@contextmanager
def output_lock(folder: str | Path, path: str | Path | None = None):
    """Hold ``folder``'s lock (see the module docstring) for the block, creating the folder if needed;
    ``OutputError`` when another live run holds it. Nested use on a folder this process already holds is
    allowed. ``path``: the lock file, when not ``folder``/.photorecon.lock (a folder that is replaced as a
    whole is locked from beside it)."""
    folder = Path(folder)
    path = Path(path) if path else folder / LOCK
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"output folder {folder}: cannot write there ({exc.strerror or exc}); "
                          "choose a writable folder") from None
    key = str(_resolve(path))
    if key in _HELD:
        _HELD[key][1] += 1
        try:
            yield folder
        finally:
            _HELD[key][1] -= 1
        return
    fd = _acquire(folder, path)
    _HELD[key] = [fd, 1]
    try:
        yield folder
    finally:
        del _HELD[key]
        _release(path, fd)
