"""A TSDF fused in chunks: each chunk's mesh trimmed to its core box, the pieces stitched into one mesh, and the
size of the chunks that fit a budget. ``tsdf.tsdf_fuse`` (the frames in memory) and ``chunked.tsdf_fuse_chunked``
(one task per chunk, the depth maps read from disk) both use them."""
from __future__ import annotations

import numpy as np
import trimesh

from ..arrays import unique_rows, unique_sorted
from ..errors import EmptyMeshError


def _in_box(coords: np.ndarray, lo, hi) -> np.ndarray:
    return np.all((coords >= lo) & (coords < hi), axis=1)

def chunk_core(V: np.ndarray, F: np.ndarray, C: np.ndarray | None, lo: np.ndarray, hi: np.ndarray):
    """A chunk's mesh trimmed to its core: the triangles whose centroid lies in [lo, hi) (scene units), and
    only the vertices they use (colours ``C`` with them). Chunks that share a boundary keep each triangle once."""
    cen = V[F].mean(axis=1)
    F = F[np.all((cen >= lo) & (cen < hi), axis=1)]
    used = unique_sorted(F)
    remap = np.full(len(V), -1, np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F], (C[used] if C is not None else None)

def _chunk_size(blocks: np.ndarray, max_blocks: int) -> int:
    """The largest cubic chunk size (in blocks, a power of two) whose fullest chunk, with the one block layer
    around it, holds at most ``max_blocks`` of ``blocks`` (at least 2)."""
    span = int((blocks.max(0) - blocks.min(0)).max()) + 1
    size = 1 << max(1, int(np.ceil(np.log2(max(span, 2)))))
    while size > 2:
        ids, counts = unique_rows(np.floor_divide(blocks, size), return_counts=True)
        worst = ids[np.argmax(counts)]
        if counts.max() * ((size + 2) / size) ** 2 <= max_blocks and \
                _in_box(blocks, worst * size - 1, (worst + 1) * size + 1).sum() <= max_blocks:
            break
        size //= 2
    return size

def stitch_pieces(pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]]) -> trimesh.Trimesh:
    """One mesh from chunk pieces: faces concatenated, vertices at the same position (a chunk border: the
    same marching-cubes vertex computed on both sides) merged into one."""
    pieces = [p for p in pieces if len(p[1])]
    if not pieces:
        raise EmptyMeshError("TSDF fusion produced no triangle: check that the depth maps and poses agree "
                             "(lower --weight-threshold or use a larger --voxel-size)")
    offsets = np.cumsum([0] + [len(p[0]) for p in pieces])
    V = np.concatenate([p[0] for p in pieces])
    F = np.concatenate([p[1].astype(np.int64) + o for p, o in zip(pieces, offsets)])
    has_color = all(p[2] is not None and len(p[2]) == len(p[0]) for p in pieces)
    uniq, first, inv = np.unique(V, axis=0, return_index=True, return_inverse=True)
    F = inv.ravel()[F]
    C = np.concatenate([p[2] for p in pieces])[first] if has_color else None
    return trimesh.Trimesh(uniq.astype(np.float64), F, vertex_colors=C, process=False)
