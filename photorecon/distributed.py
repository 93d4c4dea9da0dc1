"""The Dask side: a cluster from ``--cluster``, the task graphs of ``photorecon.tasks`` submitted to it with
retries, and progress over their futures.

``--cluster`` (``ClusterConfig.cluster``):

* absent: everything runs in this process (``tasks.Executor``), as without Dask;
* ``local`` or ``local:N``: a ``distributed.LocalCluster`` of N worker processes (default 2) on this machine,
  each with ``cores // N`` threads, and numba (and OpenCV, OpenMP) limited to as many threads, so workers x
  threads = cores;
* ``tcp://HOST:PORT``: an existing scheduler (``dask scheduler``) and its workers (``dask worker``), which must
  see the input and output folders at the same paths (a shared file system).

Tasks read their inputs from and write their outputs to the output folder, each file atomically
(``io.atomic``), so a task that a dead worker leaves half done, or that Dask runs twice, is harmless; Dask
retries a failed task ``retries`` times and reschedules the tasks of a worker that dies.
"""
from __future__ import annotations

import logging
import os
import uuid
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

from .errors import BadArgumentError
from .progress import bar
from .tasks import IN_PROCESS, Executor, Task
from .config_checks import check_config

log = logging.getLogger("photorecon")


def _cluster_arg(text: str) -> str:
    """``--cluster`` checked when the arguments are parsed (before SfM runs): the text, or argparse's error."""
    import argparse

    try:
        parse_cluster(text)
    except BadArgumentError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--cluster: ")) from None
    return text


@dataclass
class ClusterConfig:
    """Where the per-view and per-chunk tasks run (``--cluster``)."""

    cluster: str | None = field(default=None, metadata={"help": "run the depth and fusion tasks on Dask: local:N (N local workers) or tcp://HOST:PORT (a scheduler; default: in this process)", "metavar": "ADDRESS", "parse": _cluster_arg})
    retries: int = field(default=3, metadata={"help": "with --cluster: times Dask retries a task that failed or whose worker died", "range": (0, 100)})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.config_checks)


def parse_cluster(spec: str) -> tuple[str, int | str]:
    """``'local'`` / ``'local:N'`` -> ('local', N); ``'tcp://HOST:PORT'`` (any ``scheme://``) -> ('remote', spec)."""
    spec = spec.strip()
    if spec == "local" or spec.startswith("local:"):
        n = spec.partition(":")[2] or "2"
        if not n.isdigit() or int(n) < 1:
            raise BadArgumentError(f"--cluster: expected local:N with N >= 1 worker processes, got {spec!r}")
        return "local", int(n)
    if "://" in spec and spec.partition("://")[2]:
        return "remote", spec
    raise BadArgumentError(f"--cluster: expected 'local', 'local:N' or a scheduler address such as "
                           f"tcp://HOST:8786, got {spec!r}")


def _set_threads(n: int) -> None:
    """Limit numba's and OpenCV's threads in this worker thread (numba's setting is per thread)."""
    import numba

    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))
    try:
        import cv2

        cv2.setNumThreads(n)
    except ImportError:  # pragma: no cover - OpenCV is a dependency
        pass


def _call(fn: Callable[..., Any], shared: Any, args: tuple, *_deps) -> Any:
    """A task on a worker: numba threads = cores / the worker's threads, then ``fn(shared, *args)``
    (``_deps`` only order the task after the ones it needs)."""
    try:
        from distributed import get_worker

        nthreads = get_worker().state.nthreads
    except (ImportError, ValueError, AttributeError):
        nthreads = 1
    _set_threads(max(1, (os.cpu_count() or 1) // max(1, nthreads)))
    return fn(shared, *args)


def _identity(x):
    return x


class DaskExecutor(Executor):
    """Submits a task graph to a Dask ``Client``: every task at once, each after its dependencies' futures,
    with ``retries``; a progress bar over the futures as they complete. The first task that fails for good
    cancels the rest and its exception (a typed ``PhotoreconError`` as raised on the worker) is raised here."""

    distributed = True

    def __init__(self, client, retries: int = 3):
        self.client = client
        self.retries = int(retries)

    @property
    def workers(self) -> int:
        return max(1, sum(self.client.nthreads().values()))

    def run(self, fn: Callable[..., Any], tasks: Sequence[Task], shared: Any = None, desc: str = "",
            unit: str = "view") -> dict[str, Any]:
        from distributed import as_completed

        run_id = uuid.uuid4().hex[:8]
        prefix = (desc or fn.__name__).replace(" ", "_")
        with warnings.catch_warnings():  # "large object in the task graph": it is sent once, as a task
            warnings.simplefilter("ignore")
            # a task (not a scatter): if the worker holding it dies, the scheduler makes it again
            ctx = self.client.submit(_identity, shared, key=f"{prefix}-shared-{run_id}", pure=False)
        futures: dict[str, Any] = {}
        for t in tasks:
            missing = [d for d in t.deps if d not in futures]
            if missing:
                raise ValueError(f"task {t.key}: its dependencies {missing[:3]} must come earlier in the list")
            futures[t.key] = self.client.submit(_call, fn, ctx, t.args, *[futures[d] for d in t.deps],
                                                key=f"{prefix}-{t.key}-{run_id}", retries=self.retries, pure=False)
        try:
            with bar(total=len(futures), desc=desc, unit=unit) as progress:
                for fut in as_completed(list(futures.values())):
                    if fut.status == "error":
                        fut.result()  # raises the task's exception
                    progress.update(1)
            return {k: f.result() for k, f in futures.items()}
        except BaseException:  # a failed task or Ctrl-C: nothing else of this graph keeps running
            self.client.cancel(list(futures.values()) + [ctx])
            raise

    def close(self) -> None:
        cluster = getattr(self, "_cluster", None)
        self.client.close()
        if cluster is not None:
            cluster.close()


def local_cluster(n_workers: int, cores: int | None = None):
    """A ``LocalCluster`` of ``n_workers`` processes with ``cores // n_workers`` threads each (at least 1), and
    numba / OpenMP / OpenCV limited to that many threads per worker; its dashboard on a free port (``None``
    still takes 8787 in distributed 2026.8, and two runs would collide)."""
    from distributed import LocalCluster

    cores = cores or os.cpu_count() or 1
    threads = max(1, cores // n_workers)
    env = {"NUMBA_NUM_THREADS": str(threads), "OMP_NUM_THREADS": str(threads)}
    return LocalCluster(n_workers=n_workers, threads_per_worker=threads, processes=True, dashboard_address=":0",
                        host="127.0.0.1", env=env, silence_logs=logging.ERROR)


def make_executor(cfg: ClusterConfig | None) -> Executor:
    """The executor for ``cfg.cluster``: in-process without one; else a ``DaskExecutor`` on a new local cluster
    or connected to the given scheduler (call ``close()`` when done; ``executor()`` does)."""
    if cfg is None or not cfg.cluster:
        return IN_PROCESS
    kind, arg = parse_cluster(cfg.cluster)
    if not log.isEnabledFor(logging.DEBUG):  # Dask's own INFO lines (workers starting, keys released) only with -v
        for name in ("distributed", "distributed.scheduler", "distributed.nanny", "distributed.worker",
                     "distributed.core", "distributed.http.proxy"):
            logging.getLogger(name).setLevel(logging.WARNING)
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - a dependency
        raise BadArgumentError("--cluster needs Dask: pip install 'dask[distributed]'") from None
    if kind == "local":
        cluster = local_cluster(int(arg))
        client = Client(cluster)
        ex = DaskExecutor(client, cfg.retries)
        ex._cluster = cluster
        log.info("cluster: %d local worker processes x %d threads", int(arg), max(1, (os.cpu_count() or 1) // int(arg)))
        return ex
    try:
        client = Client(str(arg), timeout="20s")
    except (OSError, TimeoutError) as exc:
        raise BadArgumentError(f"--cluster: no Dask scheduler answers at {arg} ({exc.__class__.__name__}); start one "
                               "with 'dask scheduler' and workers with 'dask worker " + str(arg) + "'") from None
    n = len(client.nthreads())
    if not n:
        log.warning("cluster: the scheduler at %s has no worker yet; tasks wait for one", arg)
    log.info("cluster: %s, %d workers", arg, n)
    return DaskExecutor(client, cfg.retries)


@contextmanager
def executor(cfg: ClusterConfig | None) -> Iterator[Executor]:
    """``with executor(ClusterConfig("local:2")) as ex:`` ... the cluster (when one was made) is closed after."""
    ex = make_executor(cfg)
    try:
        yield ex
    finally:
        ex.close()
