"""Typed results of the pipeline's entry points (``reconstruct``, ``run_mvs``, ``run_mono``; SfM's is
``sfm.SfMResult``): dataclasses whose fields are what the stage's JSON report holds.

``to_dict()`` gives the JSON form (what report.json / mvs_report.json contain). Reading a field by its report key
(``result["views"]``) also works, so code written against the former dict results keeps running; new code uses
attributes."""
from __future__ import annotations

import dataclasses
from pathlib import Path


class Result:
    """Mixin for result dataclasses: ``to_dict()`` and read-only key access by field name."""

    def to_dict(self) -> dict:
        return {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)}

    def __getitem__(self, key: str):
        if key not in self:
            raise KeyError(key)
        return getattr(self, key)

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and key in {f.name for f in dataclasses.fields(self)}

    def get(self, key: str, default=None):
        return self[key] if key in self else default

    def keys(self):
        return [f.name for f in dataclasses.fields(self)]


def _plain(v):
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return v.to_dict() if isinstance(v, Result) else dataclasses.asdict(v)
    if isinstance(v, Path):
        return str(v)
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v
