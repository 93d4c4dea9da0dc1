"""``SparseModel``: the cameras and sparse points every camera format reads into and writes from."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...cameras import View


@dataclass
class SparseModel:
    """Cameras and sparse points. ``observations[name] = (uv (M, 2) OpenCV pixels, point3D ids (M,), -1 = none)``."""

    views: list[View]
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    point_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    errors: np.ndarray | None = None
    observations: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    def point_index(self) -> dict[int, int]:
        """point3D id -> row in ``points`` (built once; models are not mutated after loading)."""
        cached = getattr(self, "_point_index", None)
        if cached is None or len(cached) != len(self.point_ids):
            cached = {int(pid): i for i, pid in enumerate(self.point_ids)}
            self._point_index = cached
        return cached

    def points_seen_by(self, name: str) -> np.ndarray:
        """World points (K, 3) observed in view ``name``."""
        if name not in self.observations or len(self.points) == 0:
            return np.zeros((0, 3))
        ids = self.observations[name][1]
        index = self.point_index()
        rows = [index[int(p)] for p in ids if p >= 0 and int(p) in index]
        return self.points[rows]
