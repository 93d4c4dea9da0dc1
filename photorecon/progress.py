"""Progress bars per stage (tqdm, on stderr), switched off by ``--quiet`` or when not wanted."""
from __future__ import annotations

from collections.abc import Iterable

from tqdm import tqdm

_enabled = True


def set_enabled(flag: bool) -> None:
    global _enabled
    _enabled = flag


def bar(iterable: Iterable | None = None, desc: str = "", total: int | None = None, unit: str = "view"):
    """A tqdm bar with counts and ETA; silent when progress is disabled."""
    return tqdm(iterable, desc=desc, total=total, unit=unit, disable=not _enabled, leave=False,
                dynamic_ncols=True)
