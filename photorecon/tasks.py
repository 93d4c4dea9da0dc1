"""Small task graphs: the per-view depth and per-chunk fusion work, run in-process by default.

A stage describes its work as a list of ``Task``s (a key, the arguments of one module-level function, the keys
of the tasks it needs first) and hands it to an ``Executor``. The plain ``Executor`` here runs them one after
the other in the order given (dependencies come first), with the usual progress bar; ``photorecon.distributed``
gives a Dask one with the same ``run`` that submits the whole graph to a cluster. Tasks exchange arrays
through files (each written atomically), so a task that runs twice (a retry, a duplicate) is harmless.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence

from .progress import bar


@dataclass(frozen=True)
class Task:
    """``fn(shared, *args)``, after the tasks named in ``deps`` (keys of earlier tasks of the same run)."""

    key: str
    args: tuple = ()
    deps: tuple[str, ...] = ()


class Executor:
    """Runs a task graph in this process, in the order given. ``workers``: how many tasks may run at once
    (1 here); ``distributed``: whether tasks run in other processes (then they must not rely on this one's
    memory)."""

    workers = 1
    distributed = False

    def run(self, fn: Callable[..., Any], tasks: Sequence[Task], shared: Any = None, desc: str = "",
            unit: str = "view") -> dict[str, Any]:
        """Run ``fn(shared, *task.args)`` for every task; returns key -> result. ``shared`` is what every task
        needs (sent once to each worker by a distributed executor)."""
        done: dict[str, Any] = {}
        for t in bar(tasks, desc=desc, unit=unit):
            missing = [d for d in t.deps if d not in done]
            if missing:
                raise ValueError(f"task {t.key}: its dependencies {missing[:3]} must come earlier in the list")
            done[t.key] = fn(shared, *t.args)
        return done

    def close(self) -> None:
        pass


IN_PROCESS = Executor()
