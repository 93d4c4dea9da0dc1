"""The stage runner: every cached step of photorecon runs through ``Stages.run`` (the pipeline's poses, depth,
fusion, preview and texture; SfM's ingest, extraction, matching, mapping and undistortion).

**Complete means: its outputs hold what the stage wrote.** When a stage ends, its marker ``FOLDER/NAME.json``
records the key and a SHA-256 of every output file (``digest``). A stage is reused when the marker holds the same
key and every output still has that content; a file that was damaged or edited since (even to the same size) is
found, and the stage runs again (a warning names the file). Reading every file at every resume would make a resume
of a large project take as long as reading its depth maps, so the marker also records each file's status (device,
inode, mtime, ctime) when it was hashed: a file whose status is still that, and whose ctime was at least
``SETTLED_S`` seconds older than the hashing, is not read again. No program can write a file without the kernel
changing its ctime (``utime`` cannot set it), so an unchanged status means unchanged content; any other file (a
file written just before it was hashed, a copied or restored folder, another file system) is hashed again, and
the marker's statuses are refreshed when its contents still match. Hashing runs on several threads (hashlib
releases the GIL): about 1 GB/s a core. An SQLite database (COLMAP's) is hashed without the change counter in its
header, which a connection that only reads it counts up (``sha256_file``).

**Key and chain.** The key is a hash of the stage's parameters (settings and ``fingerprint``s of its input files)
and of the identity of the stage before it; a stage's identity is a hash of the one before it and of its
outputs' contents. A stage that runs again and writes other outputs so makes every later stage run again (in
this run, or after an interruption, in the next); one that writes the same bytes again (a damaged
``cameras.txt`` rewritten from the SfM model) leaves the later stages reused.

**Failures.** A stage writes its outputs each atomically (``atomic_dir``, ``io.atomic``), and its marker is
written last, so an interrupted run leaves nothing a later run takes for complete. A stage that fails has the
outputs it made removed, except those that were there before it started (kept as they are, without a marker:
the next run redoes the stage) and those of stages complete before it. **The last complete result is never
lost to a failed run:** the outputs of a stage run with ``result=True`` (the mesh, its previews, the textured
mesh) and files passed to ``set_aside`` (the report) are moved, with the stage's marker, into ``FOLDER/last/``
before they are rewritten; inside ``keeping_result()`` a run that fails puts them all back (the new ones of
result stages are removed, those of the intermediate stages stay for a resume, each checked by its hash), and a
run that completes deletes them. A run killed before it could do either (``kill -9``, a power loss) has them put
back when the next run starts (``Stages()``). ``force=True`` runs every stage.

Each stage logs one line when it starts (and why it runs) and one when it ends (time, peak memory, files and
bytes written), or one line when it is reused.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable

from .errors import OutputError, is_out_of_memory, out_of_memory
from .io.atomic import atomic_write_json
from .io.space import is_no_space, no_space_error
from .resources import measure

log = logging.getLogger("photorecon")

# a file's recorded status vouches for its content only if its ctime was this much older than the hashing: a
# write in the same tick of the file system's clock as the hashing would not change the ctime
SETTLED_S = 2.0
HASH_THREADS = max(1, min(8, os.cpu_count() or 1))
KEPT = "last"  # in the markers' folder: the last complete result's files, set aside while a run replaces them


def fingerprint(*paths: str | Path, times: bool = True) -> list:
    """What identifies files without reading them: ``[name, size, mtime_ns]`` for each file (folders
    recursively, hidden files and folders skipped; names relative to the given path's parent);
    ``[name, None, None]`` for a missing path. ``times=False`` leaves the time out (``None``)."""
    rows = []
    for p in map(Path, paths):
        if not p.exists():
            rows.append([p.name, None, None])
            continue
        for f, rel in _files(p):
            st = f.stat()
            rows.append([rel, st.st_size, st.st_mtime_ns if times else None])
    return rows


def _files(p: Path) -> list[tuple[Path, str]]:
    """The files of ``p`` (itself, or a folder's, recursively, hidden ones skipped), with their names relative to
    ``p``'s parent."""
    files = [p] if p.is_file() else sorted(
        f for f in p.rglob("*") if f.is_file() and not any(part.startswith(".") for part in f.relative_to(p).parts))
    return [(f, f.relative_to(p.parent).as_posix()) for f in files]


SQLITE_MAGIC = b"SQLite format 3\x00"


def sha256_file(path: str | Path) -> str:
    """SHA-256 of a file's bytes, read in 1 MB blocks. An SQLite database (COLMAP's) is hashed with its header's
    file change counter and version-valid-for number (bytes 24-27, 92-95) as zeros: every connection that opens
    it (pycolmap's ``Database.open``, also only to read) counts one more change there, the data unchanged."""
    h = hashlib.sha256()
    buf = bytearray(1 << 20)
    view = memoryview(buf)
    with open(path, "rb", buffering=0) as f:
        first = True
        while n := f.readinto(buf):
            if first and n >= 100 and buf[:16] == SQLITE_MAGIC:
                buf[24:28] = buf[92:96] = bytes(4)
            first = False
            h.update(view[:n])
    return h.hexdigest()


def _status(st: os.stat_result) -> list:
    return [st.st_dev, st.st_ino, st.st_mtime_ns, st.st_ctime_ns]


def digest(*paths: str | Path, known: dict | None = None) -> tuple[list, dict]:
    """The content of files: ``[name, size, sha256]`` for each file of ``paths`` (as ``fingerprint`` lists them;
    ``[name, None, None]`` for a missing path), and ``{"hashed_ns", "status": [[dev, ino, mtime_ns, ctime_ns],
    ...], "read": N}`` (a status a row, None for a missing path; N files read). ``known``: ``{name: (status,
    sha256)}`` of files whose status vouches for their content (see the module docstring): not read again while
    their status is the same."""
    known = known or {}
    rows, status, todo = [], [], []
    hashed_ns = time.time_ns()
    for p in map(Path, paths):
        if not p.exists():
            rows.append([p.name, None, None])
            status.append(None)
            continue
        for f, rel in _files(p):
            st = f.stat()
            rows.append([rel, st.st_size, None])
            status.append(_status(st))
            prior = known.get(rel)
            if prior is not None and prior[0] == status[-1]:
                rows[-1][2] = prior[1]
            else:
                todo.append((len(rows) - 1, f))
    if todo:
        with ThreadPoolExecutor(min(HASH_THREADS, len(todo))) as pool:
            for (i, _), h in zip(todo, pool.map(lambda t: sha256_file(t[1]), todo)):
                rows[i][2] = h
    return rows, {"hashed_ns": hashed_ns, "status": status, "read": len(todo)}


def _vouched(marker: dict) -> dict:
    """``{name: (status, sha256)}`` of a marker's files whose recorded status vouches for their content."""
    rows, files = marker.get("outputs") or [], marker.get("files") or {}
    status, hashed_ns = files.get("status") or [], files.get("hashed_ns") or 0
    out = {}
    if len(status) != len(rows):
        return out
    for row, st in zip(rows, status):
        if (isinstance(row, list) and len(row) == 3 and isinstance(row[2], str) and isinstance(st, list)
                and len(st) == 4 and st[3] and st[3] + SETTLED_S * 1e9 <= hashed_ns):
            out[row[0]] = (st, row[2])
    return out


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

    ``stats[NAME]`` is ``{"seconds", "peak_mb", "cpu_seconds"}`` for a stage that ran, ``{"seconds": 0.0,
    "cached": True}`` for one reused; ``info[NAME]`` is the dict its function returned (kept in the marker, so a
    reused stage has it too). ``label`` prefixes the stage names in the log lines (``"SfM "``).
    """

    def __init__(self, folder: str | Path, force: bool = False, label: str = ""):
        self.dir = Path(folder)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.force = force
        self.label = label
        self.stats: dict[str, dict] = {}
        self.info: dict[str, dict] = {}
        self._previous = ""  # identity of the outputs of the last stage run or reused
        self._complete: set[Path] = set()  # outputs of the stages run or reused so far
        self.restore()  # a run killed before it ended: the result it was replacing put back

    @property
    def cached(self) -> list[str]:
        return [name for name, s in self.stats.items() if s.get("cached")]

    # --- the last complete result, set aside while a run replaces it --------------------------------------------
    @property
    def kept_dir(self) -> Path:
        return self.dir / KEPT

    def _kept_index(self) -> list:
        try:
            data = json.loads((self.kept_dir / "index.json").read_text())
        except (OSError, ValueError):
            return []
        return data if isinstance(data, list) else []

    def set_aside(self, paths: Iterable[str | Path], group: str = "result") -> None:
        """Move the files or folders ``paths`` that exist into ``FOLDER/last/`` (renames, nothing copied), for
        ``restore`` to put back if the run fails; ``group``: what ``restore(group)`` puts back."""
        index = self._kept_index()
        for p in map(Path, paths):
            if not (p.exists() or p.is_symlink()):
                continue
            self.kept_dir.mkdir(exist_ok=True)
            kept = f"{len(index)}_{p.name}"
            index.append([group, os.path.relpath(p, self.dir), kept])
            atomic_write_json(self.kept_dir / "index.json", index)  # first: a crash now leaves an entry to skip
            os.replace(p, self.kept_dir / kept)

    def restore(self, group: str | None = None) -> None:
        """Put back what ``set_aside`` moved (only ``group``'s, or all), replacing what is at those paths now."""
        index = self._kept_index()
        if not index:
            shutil.rmtree(self.kept_dir, ignore_errors=True)
            return
        back = [e for e in index if isinstance(e, list) and len(e) == 3 and group in (None, e[0])]
        failed = []
        for entry in reversed(back):
            src, dst = self.kept_dir / entry[2], self.dir / entry[1]
            if src.exists() or src.is_symlink():
                try:
                    _remove(dst)
                    dst.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(src, dst)
                except OSError as exc:  # kept there, and said: the error that made the run fail is the one raised
                    failed.append(entry)
                    log.warning("%s could not be put back from %s (%s); move it back by hand", os.path.normpath(dst),
                                src, exc.strerror or exc)
        back = [e for e in back if e not in failed]
        rest = [e for e in index if e not in back]
        if rest:
            atomic_write_json(self.kept_dir / "index.json", rest)
        else:
            shutil.rmtree(self.kept_dir, ignore_errors=True)
        if back:
            log.info("%sthe last complete result was put back (%d files or folders)", self.label, len(back))

    def discard_kept(self) -> None:
        """The run completed: what it replaced is deleted."""
        shutil.rmtree(self.kept_dir, ignore_errors=True)

    @contextmanager
    def keeping_result(self):
        """``with stages.keeping_result():`` around a whole run: if it fails, the files set aside are put back;
        if it completes, they are deleted."""
        try:
            yield self
        except BaseException:
            self.restore()
            raise
        self.discard_kept()

    # --- running a stage --------------------------------------------------------------------------------------
    def run(self, name: str, params, fn: Callable[[], dict | None], outputs: Iterable[str | Path] = (),
            optional: Iterable[str | Path] = (), result: bool = False) -> dict:
        """Reuse stage ``name`` or run ``fn()``, which writes ``outputs`` (files or folders); returns its info.

        ``params``: JSON-able settings and input fingerprints; a change runs the stage (and all later ones).
        ``fn`` returns a dict of facts for the report (anything else counts as ``{}``). The stage is marked
        complete only when each of ``outputs`` exists after ``fn`` (a folder with at least one file), except
        those also in ``optional`` (which may be missing or empty); else ``OutputError`` naming the first
        missing one, and no marker. ``result``: the outputs are part of the result people look at: the last
        complete run's are set aside while the stage runs (see ``keeping_result``).
        """
        marker = self.dir / f"{name}.json"
        outputs = list(outputs)
        optional = {Path(p) for p in optional}
        key = params_key({"params": params, "after": self._previous})
        old = _read_marker(marker)
        label = f"{self.label}{name}"
        if self.force:
            why = "forced"
        elif not old:
            why = "no complete earlier run"
        elif old.get("key") != key:
            same = old.get("params") == json.loads(json.dumps(params, default=str))
            why = "an earlier stage's outputs changed" if same else "its settings or inputs changed"
        else:
            rows, files = digest(*outputs, known=_vouched(old))
            changed, damaged = _first_change(old.get("outputs"), rows, outputs)
            if changed is None:
                if files.pop("read"):  # files read again and the same: their statuses vouch for them from now on
                    atomic_write_json(marker, {**old, "files": files})
                self.stats[name] = {"seconds": 0.0, "cached": True}
                self.info[name] = old.get("info", {})
                self._previous = old["id"]
                self._complete.update(map(Path, outputs))
                log.info("%s: unchanged, reused (%s)", label, _amount(rows))
                return self.info[name]
            why = changed
            if damaged:
                log.warning("%s: %s; the stage runs again", label, changed)
        existed = {Path(p) for p in outputs if Path(p).exists() or Path(p).is_symlink()}
        if result:
            self.set_aside([marker], group=name)
            self.set_aside([p for p in outputs if Path(p) not in self._complete], group=name)
        marker.unlink(missing_ok=True)
        log.info("%s: started (%s)", label, why)
        try:
            with measure(self.stats, name):
                try:
                    res = fn()
                except (MemoryError, RuntimeError, OSError, ImportError) as exc:  # an allocation that failed
                    if not is_out_of_memory(exc):
                        raise
                    from .resources import available_bytes, release_memory

                    release_memory()
                    raise out_of_memory(name, None, available_bytes()) from None
            for p in map(Path, outputs):
                if p not in optional and not _present(p):
                    raise OutputError(f"stage {name}: its output {p} is missing or empty after it ran; was the "
                                      "output folder changed by another program meanwhile? Run again to redo the stage")
        except BaseException:
            for p in map(Path, outputs):  # partial (its marker is gone): removed, unless an earlier stage's or,
                if p not in self._complete and (result or p not in existed):  # not a result, there before it
                    _remove(p)
            if result:
                self.restore(name)
            log.info("%s: failed after %s", label, _duration(self.stats.get(name, {}).get("seconds", 0.0)))
            raise
        self.info[name] = res if isinstance(res, dict) else {}
        rows, files = digest(*outputs)
        files.pop("read")
        self._previous = params_key({"after": self._previous, "outputs": rows, **({} if outputs else {"key": key})})
        params = json.loads(json.dumps(params, default=str))  # as hashed, for a reader of the marker
        atomic_write_json(marker, {"key": key, "id": self._previous, "params": params, **self.stats[name],
                                   "outputs": rows, "files": files, "info": self.info[name]})
        self._complete.update(map(Path, outputs))
        s = self.stats[name]
        log.info("%s: done in %s, peak %.0f MB (%s)", label, _duration(s["seconds"]), s["peak_mb"], _amount(rows))
        return self.info[name]


def _first_change(recorded, rows: list, outputs: list) -> tuple[str | None, bool]:
    """What differs between a marker's output rows and the current ones: ``(None, False)`` when nothing does,
    else which file changed and whether it was there with another content (damaged or edited), e.g.
    ``("OUT/mesh.ply changed since the stage wrote it (damaged or edited)", True)``."""
    def path(name: str) -> str:  # a row's name (relative to its output's parent) as the file's path
        for p in map(Path, outputs):
            if name == p.name or name.startswith(p.name + "/"):
                return str(p.parent / name)
        return name

    if not isinstance(recorded, list) or any(isinstance(r, list) and len(r) == 3 and r[1] is not None
                                             and not isinstance(r[2], str) for r in recorded):
        return "its record is from an older photorecon, without its outputs' contents", False
    before = {r[0]: r for r in recorded if isinstance(r, list) and len(r) == 3}
    now = {r[0]: r for r in rows}
    for n, r in now.items():
        if n not in before or (before[n][1] is None and r[1] is not None):
            return f"{path(n)} is there and was not written by the stage", False
        if r[1] is None and before[n][1] is not None:
            return f"{path(n)} is missing", False
        if r != before[n]:
            return f"{path(n)} changed since the stage wrote it (damaged or edited)", True
    for n in before:
        if n not in now:
            return f"{path(n)} is missing", False
    return None, False


def _amount(rows: list) -> str:
    files = [r for r in rows if r[1] is not None]
    size = sum(r[1] for r in files)
    return f"{len(files)} file{'s' if len(files) != 1 else ''}, " + (
        f"{size / 2**20:.1f} MB" if size >= 2**20 / 10 else f"{size / 1024:.1f} kB")


def _duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f}s"
    s = int(round(seconds))
    return f"{s // 60}m{s % 60:02d}s" if s < 3600 else f"{s // 3600}h{s % 3600 // 60:02d}m"


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
