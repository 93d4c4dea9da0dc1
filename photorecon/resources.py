"""Peak-memory and time measurement for stage reports and benchmarks (Linux: /proc VmHWM, reset via clear_refs)."""
from __future__ import annotations

import resource
import time
from contextlib import contextmanager
from pathlib import Path


def available_bytes() -> int:
    """Memory this process can still get: the smaller of what the system can give (Linux MemAvailable; 4 GB
    where unknown) and the headroom under the process's address-space limit (``ulimit -v``, RLIMIT_AS: the
    limit less the address space in use)."""
    free = 4 << 30
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    free = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit != resource.RLIM_INFINITY:
        free = min(free, max(0, limit - _address_space()))
    return free


def _address_space() -> int:
    """The process's virtual memory size (VmSize), bytes; 0 where unknown."""
    return _status_bytes("VmSize") or 0


def _status_bytes(key: str) -> int | None:
    """A size line of /proc/self/status (``VmSize``, ``VmHWM``) in bytes; None where unknown."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


# The address space the native libraries take once loaded (pycolmap, Open3D, numba and their dependencies):
# 1.83 GB measured with pycolmap 4.2, Open3D 0.20 and numba 0.61
LIBRARIES_ADDRESS_SPACE = 1.9 * 2**30
_M_ARENA_MAX = -8  # glibc's mallopt parameter


def fit_address_space(preload: bool = True) -> None:
    """Under an address-space limit (``ulimit -v``, RLIMIT_AS; nothing to do without one): cap glibc's malloc
    arenas at 2 (each thread's arena reserves 64 MB of address space, a native library's threads would take
    their share of the limit), and with ``preload`` load the native libraries now, before any work, so that a
    limit too small for them fails here with ``OutOfMemoryError`` instead of halfway through a stage."""
    import importlib

    from .errors import is_out_of_memory, out_of_memory

    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit == resource.RLIM_INFINITY:
        return
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").mallopt(_M_ARENA_MAX, 2)
    except (OSError, AttributeError):
        pass
    for name in ("cv2", "pycolmap", "open3d", "numba") if preload else ():  # cv2 first: see poses._colmap._pycolmap
        try:
            importlib.import_module(name)
        except (ImportError, OSError, RuntimeError) as exc:  # pycolmap: RuntimeError from the ImportError
            if not is_out_of_memory(exc):
                raise
            raise out_of_memory("start-up", LIBRARIES_ADDRESS_SPACE, limit,
                                hint="the libraries alone need that much address space; raise the limit "
                                     "(ulimit -v)") from None


def check_memory(stage: str, need: float) -> None:
    """Raise ``OutOfMemoryError`` (``out of memory in STAGE: needs about N GB ...``) when a stage's estimated
    ``need`` (bytes) exceeds ``available_bytes()``: before the stage starts, so no native library runs out of
    memory halfway (which aborts or crashes the process, leaving its temporary files)."""
    from .errors import out_of_memory

    avail = available_bytes()
    if need > avail:
        raise out_of_memory(stage, need, avail)


def reset_peak() -> bool:
    """Reset the process's peak resident set (Linux >= 4.0); False where unsupported."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def peak_bytes() -> int:
    """Peak resident set since the last ``reset_peak`` (or process start)."""
    peak = _status_bytes("VmHWM")
    return peak if peak is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


_open_peaks: list[list[int]] = []  # one [peak bytes seen so far] per enclosing measure() block


@contextmanager
def measure(record: dict, key: str):
    """``with measure(stats, "fusion"):`` adds ``stats[key] = {"seconds": s, "peak_mb": m, "cpu_seconds": c}``:
    wall seconds, peak resident memory, and CPU seconds of this process (user + system, all its threads; work
    done in other processes, such as Dask workers, is not counted).

    Blocks nest: an inner block resets the process peak, so it first hands the peak seen so far to the
    blocks around it, and its own peak when it ends; an outer block reports the largest of them all.
    """
    now = peak_bytes()
    for seen in _open_peaks:
        seen[0] = max(seen[0], now)
    reset_peak()
    mine = [0]
    _open_peaks.append(mine)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        _open_peaks.pop()
        peak = max(peak_bytes(), mine[0])
        for seen in _open_peaks:
            seen[0] = max(seen[0], peak)
        record[key] = {"seconds": round(time.perf_counter() - t0, 3), "peak_mb": round(peak / 2**20, 1),
                       "cpu_seconds": round(time.process_time() - c0, 2)}


def release_memory(collect: bool = True) -> None:
    """Hand freed memory back to the system: a garbage collection (``collect``; about 0.1 s with many Python
    objects alive), then glibc's ``malloc_trim`` (where there is glibc). Large meshes and grids are freed into
    malloc's pools, which otherwise keep the pages resident, so the peak of the next step would stack on them."""
    import gc

    if collect:
        gc.collect()
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
