"""The stage runner: every cached step of photorecon runs through ``Stages.run`` (the pipeline's poses, depth,
fusion and preview; SfM's ingest, extraction, matching, mapping and undistortion).

A stage is reused when its marker ``FOLDER/NAME.json`` holds the same key and its outputs are still there
with the names and sizes it wrote (not times: COLMAP touches a database it only reads). The key is a hash of
the stage's parameters (settings and ``fingerprint``s of its input files) and of the identity of the outputs
of the stage before it, so a stage that runs again makes every later stage run again too, in this run or,
after an interruption, in the next one. Otherwise the old marker is removed, the stage's function writes its
outputs (each atomically: ``atomic_dir``, ``io.atomic``), and the marker is written last, with the stage's
seconds and peak memory. ``force=True`` runs every stage. A stage that fails (an error, Ctrl-C) has its
outputs removed, except those of stages complete before it: no partial output is left to look like a result.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable

from .errors import OutputError, is_out_of_memory, out_of_memory
from .io.atomic import atomic_write_json
from .io.space import is_no_space, no_space_error
from .resources import measure

log = logging.getLogger("photorecon")


def fingerprint(*paths: str | Path, times: bool = True) -> list:
    """What identifies files without reading them: ``[name, size, mtime_ns]`` for each file (folders
    recursively, hidden files and folders skipped; names relative to the given path's parent);
    ``[name, None, None]`` for a missing path. ``times=False`` leaves the time out (``None``)."""
    rows = []
    for p in map(Path, paths):
        if not p.exists():
            rows.append([p.name, None, None])
            continue
        files = [p] if p.is_file() else sorted(
            f for f in p.rglob("*") if f.is_file() and not any(part.startswith(".") for part in f.relative_to(p).parts))
        for f in files:
            st = f.stat()
            rows.append([f.relative_to(p.parent).as_posix(), st.st_size, st.st_mtime_ns if times else None])
    return rows


def params_key(params) -> str:
    """A short hash of JSON-able ``params`` (dict order does not matter; other objects by ``str``)."""
    return hashlib.sha256(json.dumps(params, sort_keys=True, default=str).encode()).hexdigest()[:16]


def replace_dir(src: str | Path, dst: str | Path) -> Path:
    """Move folder ``src`` onto ``dst``, replacing what was there (two renames on one file system)."""
    src, dst = Path(src), Path(dst)
    old = dst.with_name(f".{dst.name}.old")
    shutil.rmtree(old, ignore_errors=True)
    if dst.exists():
        os.replace(dst, old)
    shutil.move(str(src), str(dst))
    shutil.rmtree(old, ignore_errors=True)
    return dst


@contextmanager
def atomic_dir(path: str | Path):
    """Yield an empty temporary folder next to ``path``; on success it replaces ``path`` (an interrupted
    write leaves ``path`` as it was and removes the temporary folder; a full disk raises ``OutputError``
    naming ``path`` and its device)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        yield tmp
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if is_no_space(exc):
            raise no_space_error(path) from None
        raise
    replace_dir(tmp, path)


class Stages:
    """Runs named stages in order, with their markers in ``folder`` (see the module docstring).

    ``stats[NAME]`` is ``{"seconds", "peak_mb"}`` for a stage that ran, ``{"seconds": 0.0, "cached": True}``
    for one reused; ``info[NAME]`` is the dict its function returned (kept in the marker, so a reused stage
    has it too).
    """

    def __init__(self, folder: str | Path, force: bool = False):
        self.dir = Path(folder)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.force = force
        self.stats: dict[str, dict] = {}
        self.info: dict[str, dict] = {}
        self._previous = ""  # identity of the outputs of the last stage run or reused
        self._complete: set[Path] = set()  # outputs of the stages run or reused so far

    @property
    def cached(self) -> list[str]:
        return [name for name, s in self.stats.items() if s.get("cached")]

    def run(self, name: str, params, fn: Callable[[], dict | None], outputs: Iterable[str | Path] = (),
            optional: Iterable[str | Path] = ()) -> dict:
        """Reuse stage ``name`` or run ``fn()``, which writes ``outputs`` (files or folders); returns its info.

        ``params``: JSON-able settings and input fingerprints; a change runs the stage (and all later ones).
        ``fn`` returns a dict of facts for the report (anything else counts as ``{}``). The stage is marked
        complete only when each of ``outputs`` exists after ``fn`` (a folder with at least one file), except
        those also in ``optional`` (which may be missing or empty); else ``OutputError`` naming the first
        missing one, and no marker.
        """
        marker = self.dir / f"{name}.json"
        outputs = list(outputs)
        optional = {Path(p) for p in optional}
        key = params_key({"params": params, "after": self._previous})
        old = _read_marker(marker)
        if not self.force and old.get("key") == key and old.get("outputs") == fingerprint(*outputs, times=False):
            self.stats[name] = {"seconds": 0.0, "cached": True}
            self.info[name] = old.get("info", {})
            self._previous = old["id"]
            self._complete.update(map(Path, outputs))
            log.debug("%s: unchanged, reused", name)
            return self.info[name]
        marker.unlink(missing_ok=True)
        try:
            with measure(self.stats, name):
                try:
                    result = fn()
                except (MemoryError, RuntimeError, OSError, ImportError) as exc:  # an allocation that failed
                    if not is_out_of_memory(exc):
                        raise
                    from .resources import available_bytes, release_memory

                    release_memory()
                    raise out_of_memory(name, None, available_bytes()) from None
        except BaseException:
            for p in map(Path, outputs):  # partial (its marker is gone): removed, unless an earlier stage's
                if p not in self._complete:
                    _remove(p)
            raise
        self.info[name] = result if isinstance(result, dict) else {}
        for p in map(Path, outputs):
            if p not in optional and not _present(p):
                raise OutputError(f"stage {name}: its output {p} is missing or empty after it ran; was the output "
                                  "folder changed by another program meanwhile? Run again to redo the stage")
        self._previous = uuid.uuid4().hex[:16]
        params = json.loads(json.dumps(params, default=str))  # as hashed, for a reader of the marker
        atomic_write_json(marker, {"key": key, "id": self._previous, "params": params, **self.stats[name],
                                   "outputs": fingerprint(*outputs, times=False), "info": self.info[name]})
        self._complete.update(map(Path, outputs))
        log.debug("%s: %.1f s, peak %.0f MB", name, self.stats[name]["seconds"], self.stats[name]["peak_mb"])
        return self.info[name]


def _remove(p: Path) -> None:
    try:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink(missing_ok=True)
    except OSError:
        pass


def _present(p: Path) -> bool:
    """A file, or a folder holding at least one file that is not hidden."""
    if p.is_file():
        return True
    return p.is_dir() and any(not f.name.startswith(".") for f in p.iterdir())


def _read_marker(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):  # unreadable, not UTF-8, not JSON: as if absent (the stage runs again)
        return {}
    return data if isinstance(data, dict) and "id" in data else {}
