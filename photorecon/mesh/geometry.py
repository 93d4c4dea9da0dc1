"""Per-triangle quantities of a mesh given as arrays (V (N, 3), T (F, 3)): edge cross products, areas, centres,
computed a block of triangles at a time (no (F, 3, 3) corner array of a mesh of millions of faces). The cleaning,
the support removal, the hole filling and the refinement share them; this module imports nothing of theirs."""
from __future__ import annotations

import numpy as np


def face_cross(V: np.ndarray, T: np.ndarray, block: int = 1 << 20) -> np.ndarray:
    """Per triangle of (V, T): the cross product of its edges (v1 - v0) x (v2 - v0) (F, 3), twice its area times
    its unit normal; computed ``block`` triangles at a time (no (F, 3, 3) corner array)."""
    out = np.empty((len(T), 3), np.result_type(V.dtype, np.float32))
    for s in range(0, len(T), block):
        t = V[T[s:s + block]]
        out[s:s + block] = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    return out


def face_areas(V: np.ndarray, T: np.ndarray, block: int = 1 << 20) -> np.ndarray:
    """Per triangle of (V, T): its area (F,), ``block`` triangles at a time."""
    out = np.empty(len(T), np.result_type(V.dtype, np.float32))
    for s in range(0, len(T), block):
        t = V[T[s:s + block]]
        out[s:s + block] = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    return out


def face_centres(V: np.ndarray, T: np.ndarray, block: int = 1 << 20) -> np.ndarray:
    """Per triangle of (V, T): the mean of its corners (F, 3), ``block`` triangles at a time."""
    out = np.empty((len(T), 3), np.result_type(V.dtype, np.float32))
    for s in range(0, len(T), block):
        out[s:s + block] = V[T[s:s + block]].mean(1)
    return out
