"""The one output guard: every command that writes goes through it, with the same rules.

**A command replaces only what that same command wrote.** An output folder carries the marker ``.photorecon``
(JSON: the commands that wrote there); a command writes into

* a new or empty folder, or one whose marker names this command: its own files there are replaced, nothing else;
* any other folder holding files (a user's folder, another command's result, a folder inside a result): refused
  unless ``--overwrite``; with it the command adds its files next to what is there and still refuses when one of
  the names it writes (``layout.COMMAND_WRITES``) is taken: what it did not write is never replaced or deleted;
* never an input, a folder holding an input or a folder inside an input folder (``check_apart``), and never a path
  that is part of another command's result (``RESULT/depth`` of ``synth``'s dataset, ``RESULT/report.json``):
  refused even with ``--overwrite``, so a result is never half-replaced.

An output that is one file (``eval --json``, ``--error-mesh``, ``view --html``, ``convert DST.json``;
``check_file_output``) is never an input nor part of a photorecon result, and an existing file there is replaced
only with ``--overwrite``.

A run that fails leaves no half-written result that looks complete: ``output_folder`` removes what a command
without resumable stages wrote (``resumable=False``); the stage runner removes the unmarked outputs of a stage
that failed (``stages.Stages``); working folders of complete pieces (``layout.RESUMABLE_NAMES``) are kept.

``output_folder`` is what every command that writes a folder goes through::

    with output_folder(out, overwrite, inputs=(images, masks), command="fuse") as out:
        ...  # write into out

It refuses (``OutputError``, exit 8, before anything is written), creates the folder, marks it as the command's and
takes its lock (``output_lock``) for the duration of the run.

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
import shutil
import socket
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError
from ..layout import COMMAND_WRITES, RESUMABLE_NAMES, WRITTEN_NAMES

try:
    import fcntl
except ImportError:  # pragma: no cover  (not POSIX: the process-id check alone)
    fcntl = None

log = logging.getLogger("photorecon")

MARKER = ".photorecon"
LOCK = ".photorecon.lock"
ANY = "*"  # the commands of a marker written before markers named them: any command counts as its own


def _resolve(p: str | Path) -> Path:
    return Path(p).expanduser().resolve()


def _cannot_write(out: Path, exc: OSError) -> OutputError:
    return OutputError(f"output folder {out}: cannot write there ({exc.strerror or exc}); choose a writable folder")


# --- the marker -------------------------------------------------------------------------------------------------
def marker_commands(folder: str | Path) -> list[str]:
    """The commands that wrote ``folder`` (its ``.photorecon`` marker); ``[]`` without a marker, ``["*"]`` for
    a marker that does not name them (written by an earlier photorecon)."""
    path = Path(folder) / MARKER
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError):
        return [ANY] if path.exists() else []
    try:
        data = json.loads(text)
        cmds = data.get("commands") if isinstance(data, dict) else None
        if isinstance(cmds, list) and cmds and all(isinstance(c, str) for c in cmds):
            return cmds
    except ValueError:
        pass
    return [ANY]


def mark(folder: str | Path, command: str) -> None:
    """Add ``command`` to ``folder``'s marker (creating it)."""
    folder = Path(folder)
    cmds = [c for c in marker_commands(folder) if c != ANY]
    if command in cmds and (folder / MARKER).is_file():
        return
    (folder / MARKER).write_text(json.dumps({"written_by": "photorecon", "commands": [*cmds, command]}) + "\n")


def _owns(folder: Path, command: str | None) -> bool:
    cmds = marker_commands(folder)
    return bool(cmds) and (ANY in cmds or command is None or command in cmds)


def _names(command: str) -> tuple[str, ...] | None:
    return COMMAND_WRITES.get(command, WRITTEN_NAMES) if command != ANY else WRITTEN_NAMES


def _cmd_list(cmds: list[str]) -> str:
    known = [c for c in cmds if c != ANY]
    return " and ".join(f"photorecon {c}" for c in known) or "photorecon"


def part_of_result(path: str | Path) -> tuple[Path, list[str]] | None:
    """``(result folder, its commands)`` when ``path`` is, or lies in, something a command wrote in a result
    folder above it (a name of ``layout.COMMAND_WRITES``, or anything in a folder of per-view files such as
    ``mvs``'s): what writing ``path`` would half-replace. ``None`` otherwise."""
    res = _resolve(path)
    for parent in res.parents:
        cmds = marker_commands(parent)
        if not cmds:
            continue
        first = res.relative_to(parent).parts[0]
        for c in cmds:
            names = _names(c)
            if names is None or first in names:
                return parent, cmds
    return None


def _content(out: Path) -> list[Path]:
    return sorted(p for p in out.iterdir() if p.name not in (LOCK, MARKER))


def _listing(paths: list[Path]) -> str:
    return paths[0].name + (f" and {len(paths) - 1} more" if len(paths) > 1 else "")


# --- the checks -------------------------------------------------------------------------------------------------
def check_output(out: str | Path, overwrite: bool = False, inputs: tuple = (),
                 writes: tuple[str, ...] | None = None, command: str | None = None, may_hold: tuple = ()) -> Path:
    """Check the output folder ``out`` of ``command`` (the module docstring's rules), writing nothing.

    ``inputs``: files or folders (None ignored) that ``out`` must keep apart from (``check_apart``; it may lie in
    ``may_hold``). ``writes``: the names the command writes, replaces or deletes in ``out`` (default: its
    ``layout.COMMAND_WRITES``). Raises ``OutputError`` naming what would be replaced."""
    out = Path(out)
    if writes is None:
        writes = COMMAND_WRITES.get(command, WRITTEN_NAMES) or ()
    check_apart(out, inputs, may_hold)
    if out.exists() and not out.is_dir():
        raise OutputError(f"output {out} exists and is not a folder; choose a folder")
    _check_not_busy(out)  # a folder another run is writing: said first, whatever it holds
    if not out.is_dir() or _owns(out, command):
        if not out.is_dir():
            _check_not_part(out, command)
        return out
    content = _content(out)
    if not content:
        return out
    _check_not_part(out, command)
    cmds = marker_commands(out)
    what = (f"is the result of {_cmd_list(cmds)}, which {_cmd_list([command]) if command else 'this command'} does "
            "not replace" if cmds else f"holds files photorecon did not write ({_listing(content)})")
    if not overwrite:
        raise OutputError(f"output folder {out} {what}; choose another folder, or pass --overwrite to add "
                          "photorecon's files next to them (they are kept)")
    taken = [out / n for n in writes if (out / n).exists() or (out / n).is_symlink()]
    if taken:
        raise OutputError(f"output folder {out} {what} and already holds {taken[0]}"
                          + (f" (and {len(taken) - 1} more of the names photorecon writes)" if len(taken) > 1 else "")
                          + "; --overwrite never replaces a file the command did not write: choose another folder")
    return out


def _part(out: Path, command: str | None) -> tuple[Path, list[str]] | None:
    """``part_of_result(out)`` unless the result is ``command``'s own, or ``out`` is a new name directly in the
    result folder (adding it replaces nothing)."""
    part = part_of_result(out)
    if part is None or (command is not None and command in part[1]):
        return None
    if not (out.exists() or out.is_symlink()) and _resolve(out).parent == part[0]:
        return None
    return part


def _check_not_part(out: Path, command: str | None) -> None:
    part = _part(out, command)
    if part is not None:
        raise OutputError(f"output {out} is part of the result of {_cmd_list(part[1])} in {part[0]}; a result is "
                          "never half-replaced: choose a folder outside it (-o), or a new folder in it")


def check_file_output(path: str | Path | None, overwrite: bool = False, inputs: tuple = (), flag: str = "",
                      may_hold: tuple = ()) -> None:
    """Check an output that is one file: ``OutputError`` when it is an input or lies inside an input folder
    (a new file in the folders ``may_hold`` excepted), is a folder, is part of a photorecon result
    (``part_of_result``), or exists and not ``overwrite``."""
    if path is None or str(path) in ("", "-"):
        return
    path = Path(path)
    name = f"{flag} {path}" if flag else f"output {path}"
    for inp in inputs:
        if inp is not None and str(inp) != "" and _resolve(inp) == _resolve(path):
            raise OutputError(f"{name}: would replace an input ({inp}); choose another file")
    held = [p for p in may_hold if p is not None and _resolve(path).is_relative_to(_resolve(p))]
    if held and (path.exists() or path.is_symlink()):
        raise OutputError(f"{name}: would replace a file in the input folder {held[0]}; choose another file")
    check_apart(path, inputs, may_hold)
    if path.is_dir():
        raise OutputError(f"{name} is a folder; give a file name")
    part = _part(path, None)
    if part is not None:
        raise OutputError(f"{name} is part of the result of {_cmd_list(part[1])} in {part[0]}; a result is never "
                          "half-replaced: choose a file outside it")
    if path.exists() and not overwrite:
        raise OutputError(f"{name} exists; choose another file, or pass --overwrite to replace it")


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
            raise OutputError(f"output {out} is the input {inp}; choose an output outside the inputs")
        if ip.is_dir() and res.is_relative_to(ip) and ip not in inside_ok:
            raise OutputError(f"output {out} is inside the input folder {inp}; choose an output folder outside it")
        if ip.is_relative_to(res):
            raise OutputError(f"output {out} holds the input {inp}, which writing there could replace or delete; "
                              "choose an output folder outside the inputs")


# --- the output folder ------------------------------------------------------------------------------------------
def prepare_output(out: str | Path, overwrite: bool = False, inputs: tuple = (),
                   writes: tuple[str, ...] | None = None, command: str | None = None) -> Path:
    """``check_output``, then create ``out`` and mark it as ``command``'s. Takes no lock: a run uses
    ``output_folder``."""
    out = check_output(out, overwrite, inputs, writes, command)
    try:
        out.mkdir(parents=True, exist_ok=True)
        mark(out, command or ANY)
    except OSError as exc:
        raise _cannot_write(out, exc) from None
    return out


@contextmanager
def output_folder(out: str | Path, overwrite: bool = False, inputs: tuple = (),
                  writes: tuple[str, ...] | None = None, command: str | None = None, may_hold: tuple = (),
                  resumable: bool = True, warnings: list | None = None):
    """Check ``out`` (``check_output``), create it, lock it (``output_lock``), mark it as ``command``'s and
    yield it as a ``Path``; the lock is released when the block ends.

    When the block fails: a command without resumable stages (``resumable=False``) has what it wrote removed
    (``writes`` but ``layout.RESUMABLE_NAMES``: before the run they were the command's own, or absent); a folder
    this call created is removed when nothing but its marker is left. ``warnings``: a list
    that receives the lock's warning (a stale lock taken over), for the run's report."""
    if writes is None:
        writes = COMMAND_WRITES.get(command, WRITTEN_NAMES) or ()
    out = check_output(out, overwrite, inputs, writes, command, may_hold)
    created = next((p for p in reversed((out, *out.parents)) if not p.exists()), None)  # the top folder made here
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _cannot_write(out, exc) from None
    try:
        with output_lock(out, warnings=warnings):
            try:
                mark(out, command or ANY)
            except OSError as exc:
                raise _cannot_write(out, exc) from None
            try:
                yield out
            except BaseException:
                if not resumable:
                    remove_written(out, writes)
                raise
    except BaseException:
        if created is not None:
            _remove_if_unused(out)
            for p in out.parents:  # the parents this call made, when left empty
                if p == created.parent:
                    break
                try:
                    p.rmdir()
                except OSError:
                    break
        raise


def remove_written(out: Path, names) -> None:
    """Remove ``names`` from ``out`` (a failed run's partial output), working folders of complete pieces
    (``layout.RESUMABLE_NAMES``) kept."""
    for n in names:
        p = out / n
        if n in RESUMABLE_NAMES or not (p.exists() or p.is_symlink()):
            continue
        try:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
        except OSError:
            pass


def _remove_if_unused(out: Path) -> None:
    """Remove ``out`` when it holds no file but photorecon's marker (empty folders aside)."""
    try:
        if all(p.is_dir() or p == out / MARKER for p in out.rglob("*")):
            shutil.rmtree(out)
    except OSError:
        pass


# --- the lock ---------------------------------------------------------------------------------------------------
_HELD: dict[str, list] = {}  # resolved folder -> [fd, depth, thread]: a run locking a folder it already holds nests


def _held_by_other_thread(folder: Path, key: str) -> None:
    """``OutputError`` when a run in another thread of this process holds the lock ``key`` (a folder's lock is
    the process's: only the thread that took it may nest)."""
    held = _HELD.get(key)
    if held is not None and held[2] != threading.get_ident():
        raise OutputError(f"output folder {folder} is in use by another photorecon run in this process (another "
                          "thread); wait for it to finish or choose another output folder")


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


def _check_not_busy(folder: Path) -> None:
    """``OutputError`` naming the run when another live run holds ``folder``'s lock; writes nothing."""
    path = folder / LOCK
    if str(_resolve(path)) in _HELD:
        _held_by_other_thread(folder, str(_resolve(path)))
        return
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        info = _read_info(fd)
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
                return  # nobody holds it: a stale lock, taken over later
            except BlockingIOError:
                raise _in_use(folder, info, path) from None
            except OSError:
                pass
        if _alive(info):
            raise _in_use(folder, info, path)
    finally:
        os.close(fd)


def _acquire(folder: Path, path: Path, warnings: list | None = None) -> int:
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
                msg = (f"output folder {folder}: the run that locked it ({_describe(info)}) is no longer running; "
                       "taking it over")
                log.warning("%s", msg)
                if warnings is not None:
                    warnings.append(msg)
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
def output_lock(folder: str | Path, path: str | Path | None = None, warnings: list | None = None):
    """Hold ``folder``'s lock (see the module docstring) for the block, creating the folder if needed;
    ``OutputError`` when another live run holds it. Nested use on a folder this process already holds is
    allowed. ``path``: the lock file, when not ``folder``/.photorecon.lock (a folder that is replaced as a
    whole is locked from beside it). ``warnings``: a list that receives the warning of a stale lock taken over."""
    folder = Path(folder)
    path = Path(path) if path else folder / LOCK
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"output folder {folder}: cannot write there ({exc.strerror or exc}); "
                          "choose a writable folder") from None
    key = str(_resolve(path))
    if key in _HELD:
        _held_by_other_thread(folder, key)
        _HELD[key][1] += 1
        try:
            yield folder
        finally:
            _HELD[key][1] -= 1
        return
    fd = _acquire(folder, path, warnings)
    _HELD[key] = [fd, 1, threading.get_ident()]
    try:
        yield folder
    finally:
        del _HELD[key]
        _release(path, fd)
