"""Sub-command definitions (argument parsing only; the work is in the stage modules)."""
from __future__ import annotations

from .cli import command  # noqa: F401
