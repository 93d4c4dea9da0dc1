"""Per-triangle quantities of a mesh given as arrays (V (N, 3), T (F, 3)): edge cross products, areas, centres,
computed a block of triangles at a time (no (F, 3, 3) corner array of a mesh of millions of faces), one int64
key per edge, and the connected components of its triangles. The cleaning,
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


def edge_keys(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """One int64 key per undirected edge (a, b) of a mesh of ``n`` vertices: min * n + max."""
    a, b = np.asarray(a).astype(np.int64), np.asarray(b).astype(np.int64)
    return np.minimum(a, b) * n + np.maximum(a, b)


def face_edges(T: np.ndarray) -> np.ndarray:
    """Every face's edges as the face runs them (3F, 2): the edges (0, 1) of all faces, then (1, 2), then (2, 0)
    (the order of ``face_edge_keys``)."""
    T = np.asarray(T)
    return np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])


def face_edge_keys(T: np.ndarray, n: int | None = None) -> np.ndarray:
    """``edge_keys`` of every face's edges (3F,): the edges (0, 1) of all faces, then (1, 2), then (2, 0)."""
    T = np.asarray(T)
    n = int(T.max()) + 1 if n is None else n
    F = len(T)
    keys = np.empty(3 * F, np.int64)
    for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        keys[k * F:(k + 1) * F] = edge_keys(T[:, i], T[:, j], n)
    return keys


def triangle_components(V: np.ndarray, T: np.ndarray, block: int = 1 << 20) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of triangles that share an edge (as Open3D's ``cluster_connected_triangles``):
    (per-triangle label (F,), per-component area (C,)). Built from one sorted int64 key per face edge and a
    sparse face graph, a few tens of bytes per face (Open3D's edge map took about 400 per face)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    F = len(T)
    if not F:
        return np.zeros(0, np.int64), np.zeros(0)
    keys = face_edge_keys(T)
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    same = keys[1:] == keys[:-1]
    del keys
    face = np.remainder(order, F, out=order)
    u, v = face[:-1][same].astype(np.int32), face[1:][same].astype(np.int32)  # faces sharing an edge, chained
    del face, order, same
    graph = coo_matrix((np.ones(len(u), np.int8), (u, v)), shape=(F, F)).tocsr()
    del u, v
    _, labels = connected_components(graph, directed=False)
    del graph
    return labels.astype(np.int64), np.bincount(labels, weights=face_areas(V, T, block))
