"""Progress of long work, switched off by ``--quiet`` or when not wanted.

On a terminal, a tqdm bar per loop (counts, ETA) on stderr. When stderr is not a terminal (``2> log``, a job
scheduler, a pipe), a bar's redrawn line would be one line of carriage returns, so the loop logs a plain line
instead, at most one every ``INTERVAL`` seconds and only once it has run that long:
``mvs depth (patchmatch, 16 views): 12/64 tasks, 2m30s elapsed, about 10m left``, and a last line when it ends.
Work inside a native library with no count to report (COLMAP's extraction, matching, mapping) logs that it is
still running, at the same pace (``running``), on a terminal too."""
from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Callable, Iterable
from contextlib import contextmanager

from tqdm import tqdm

log = logging.getLogger("photorecon")

# seconds between two progress lines of one loop (when stderr is not a terminal) or of one native step
# (read when a bar starts)
INTERVAL = 30.0

_enabled = True


def set_enabled(flag: bool) -> None:
    global _enabled
    _enabled = flag


def enabled() -> bool:
    return _enabled


def _stderr_is_terminal() -> bool:
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError, OSError):  # None, closed or replaced by an object without isatty
        return False


def duration(seconds: float) -> str:
    """``seconds`` as people read a duration: 45s, 2m05s, 1h02m."""
    s = int(round(max(0.0, seconds)))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


class _Ticker:
    """Calls ``fn`` every ``period`` seconds on a daemon thread until stopped."""

    def __init__(self, fn: Callable[[], None], period: float):
        self._fn, self._period = fn, period
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="photorecon-progress", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(self._period):
            try:
                self._fn()
            except Exception:  # pragma: no cover  (a progress line must never break the work)
                pass

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=5)


class LogBar:
    """A progress bar for a log file: the part of tqdm's interface photorecon uses (iteration, ``update``,
    ``close``, ``with``), logging ``DESC: N/TOTAL UNITs, ELAPSED elapsed, about ETA left`` at most once per
    ``interval`` seconds (the first after ``interval`` seconds), from ``update`` and, with ``tick``, from a
    background thread while one item takes long; on ``close``, ``DESC: N/TOTAL UNITs in ELAPSED`` if any line
    was logged. ``clock``: seconds (``time.monotonic``; tests pass a fake one)."""

    def __init__(self, iterable: Iterable | None = None, desc: str = "", total: int | None = None, unit: str = "view",
                 interval: float | None = None, clock: Callable[[], float] = time.monotonic, tick: bool = True,
                 logger: logging.Logger | None = None):
        interval = INTERVAL if interval is None else interval
        if total is None and iterable is not None:
            try:
                total = len(iterable)  # type: ignore[arg-type]
            except TypeError:
                total = None
        self.iterable, self.desc, self.total, self.unit = iterable, desc, total, unit
        self.interval, self.clock, self.log, self.tick = interval, clock, logger or log, tick
        self.n = 0
        self.lines = 0
        self.start = self._last = clock()
        self._lock = threading.Lock()
        self._closed = False
        self._ticker: _Ticker | None = None

    def _start_ticker(self) -> None:
        """The background thread that logs while one item takes long: started when the work starts (iteration
        or ``with``), stopped by ``close``."""
        if self.tick and self._ticker is None and not self._closed:
            self._ticker = _Ticker(self.poll, min(self.interval, 5.0))

    def _count(self) -> str:
        unit = self.unit if self.n == 1 and self.total in (None, 1) else self.unit + "s"
        return f"{self.n}/{self.total} {unit}" if self.total is not None else f"{self.n} {unit}"

    def _line(self, elapsed: float) -> str:
        eta = ""
        if self.total and 0 < self.n < self.total:
            eta = f", about {duration(elapsed / self.n * (self.total - self.n))} left"
        return f"{self.desc}: {self._count()}, {duration(elapsed)} elapsed{eta}"

    def _last_line(self, elapsed: float) -> str:
        return f"{self.desc}: {self._count()} in {duration(elapsed)}"

    def poll(self) -> bool:
        """Log the progress line if ``interval`` seconds passed since the last (or the start); True if it did."""
        with self._lock:
            now = self.clock()
            if self._closed or now - self._last < self.interval:
                return False
            self._last = now
            self.lines += 1
            line = self._line(now - self.start)
        self.log.info("%s", line)
        return True

    def update(self, n: int = 1) -> None:
        self.n += n
        if self.total is None or self.n < self.total:  # the last one: close's line says it
            self.poll()

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self._ticker is not None:
            self._ticker.stop()
        if self.lines:
            self.log.info("%s", self._last_line(self.clock() - self.start))

    def __iter__(self):
        self._start_ticker()
        try:
            for item in self.iterable:
                yield item
                self.update(1)
        finally:
            self.close()

    def __enter__(self):
        self._start_ticker()
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def bar(iterable: Iterable | None = None, desc: str = "", total: int | None = None, unit: str = "view"):
    """A tqdm bar with counts and ETA on a terminal; a ``LogBar`` (a line every ``INTERVAL`` seconds) when stderr
    is not one; silent when progress is disabled."""
    if _enabled and not _stderr_is_terminal():
        return LogBar(iterable, desc=desc, total=total, unit=unit)
    return tqdm(iterable, desc=desc, total=total, unit=unit, disable=not _enabled, leave=False,
                dynamic_ncols=True)


class _Running(LogBar):
    def _line(self, elapsed: float) -> str:
        return f"{self.desc}: running, {duration(elapsed)} elapsed"

    def _last_line(self, elapsed: float) -> str:
        return f"{self.desc}: done in {duration(elapsed)}"


@contextmanager
def running(desc: str, interval: float | None = None, clock: Callable[[], float] = time.monotonic,
            logger: logging.Logger | None = None, tick: bool = True):
    """For one long call with nothing to count (a native library's): ``DESC: running, ELAPSED elapsed`` every
    ``interval`` seconds while it runs (on a terminal too), and ``DESC: done in ELAPSED`` after it if a line was
    logged. Yields the object that does it (``poll()`` for a test's fake clock; None when progress is off)."""
    if not _enabled:
        yield None
        return
    with _Running(desc=desc, interval=interval, clock=clock, tick=tick, logger=logger) as b:
        yield b
