"""TSDF fusion (Open3D tensor ``VoxelBlockGrid``): depth frames in, one mesh out.

Each view's z-depth (masked, range-limited) is integrated into a sparse voxel block grid on the CPU,
with each pixel weighted by its confidence map when there is one (MVS, a compiled numba kernel on the grid's
own storage); marching cubes extracts the zero level set. The voxel size defaults to ``voxel_footprints``
pixel footprints (the median ``z / f`` of the depth maps, at their own resolution, over the central part of
each view: the surface the camera looks at), coarsened with a warning only when the grid would not fit in
memory (``fusion.budget``). The legacy ``ScalableTSDFVolume`` is not used: with Open3D 0.20 on the CPU it
extracts an empty mesh.
Where a depth map has normals (PatchMatch) the signed distance is measured to each pixel's tangent plane
(``normal_sdf``), not along its ray, where the depth map shows that plane going on behind the pixel
(``planar_normals``): surfaces seen at grazing angles (the ground in front of a facade) then keep a band
thicker than a voxel and come out whole, and no fin grows behind an object's rim.

Two drivers share the integration, the extraction and the pieces (``fusion.pieces``): ``tsdf_fuse`` here, with
the frames in memory, and ``chunked.tsdf_fuse_chunked``, one task per chunk reading the depth maps from disk.
They stay two: ``tsdf_fuse`` plans its chunks from every frame's exact block coordinates (computed once, with
the frames held) and splits space only when the grid exceeds its budget, into chunks sized to that budget; the
tasks plan from sampled surface points (the frames are not held), in chunks of a fixed size, and each task
chooses and reads the frames that reach its chunk. Making ``tsdf_fuse`` a special case of the tasks would
change its chunks (and so the order of the stitched mesh's vertices before ``fuse``'s canonical order), read
every depth map again per chunk, and need a dataset on disk, which ``tsdf_fuse``'s callers do not have.
"""
from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np
import trimesh

from ..arrays import unique_rows
from ..cameras import backproject_depth
from ..errors import BadArgumentError, EmptyMeshError, NoDepthError
from ..jit import njit, prange
from ..progress import bar
from ..resources import release_memory
from .budget import tsdf_voxel_size
from .config import DepthFrame, FusionConfig, _BLOCK_RES, _BYTES_PER_VOXEL, budget_share
from .frames import FrameStore, full_frame, nonempty, resolution_weights
from .pieces import _chunk_size, _in_box, chunk_core, stitch_pieces

log = logging.getLogger("photorecon")


@njit(cache=True, inline="always")
def _half(h):  # pragma: no cover - compiled
    """The value of IEEE half-precision bits ``h`` (uint16) as a float (numba has no float16)."""
    b = np.int64(h)
    e = (b >> 10) & 31
    m = b & 1023
    if e == 0:
        v = math.ldexp(np.float64(m), -24)
    elif e == 31:
        v = math.inf if m == 0 else math.nan
    else:
        v = math.ldexp(np.float64(m + 1024), e - 25)
    return -v if b >> 15 else v


@njit(parallel=True, cache=True, fastmath=True)
def _tsdf_weighted_kernel(block_keys, buf_idx, R, t, fx, fy, cx, cy, voxel, trunc, depth_max,
                          depth, weight_map, color_img, normal_map, normal_half, keep_bits, min_cos, tsdf, weight,
                          color):  # pragma: no cover - compiled
    """One pass over the voxels of the given blocks: project each voxel centre, look up its pixel (nearest,
    pixel (0, 0) = centre of the top-left pixel) and fold ``weight_map[pixel]`` x the truncated SDF into the
    running weighted mean (Open3D's update rule with a per-pixel weight instead of 1). Blocks are distinct,
    so the parallel loop over blocks writes disjoint voxels. Storage layout as Open3D's: voxel (x, y, z) of
    block ``b`` at ``(b * res + z) * res + y) * res + x``; voxel world position = integer index * voxel.

    ``normal_map`` (H, W, 3) camera-frame unit normals, or a (1, 1, 3) array for none: the SDF is then the
    distance to the pixel's tangent plane, (depth - z) x |n . (x/z, y/z, 1)| (at least ``min_cos`` x the
    distance along the ray), not along the ray: on a surface seen at a grazing angle the distance along the
    ray is many times the true one, so the truncation band below the surface gets thinner than a voxel and
    marching cubes finds the surface only in stripes. ``normal_half`` (H, W, 3) uint16: the normals as IEEE
    half-precision bits instead (a depth map's float16 normals, read without a float32 copy of the frame).
    ``keep_bits``: the pixels whose normal counts, one bit per pixel (``np.packbits`` of the (H, W) mask), or
    empty for all. ``weight_map`` (1, 1) for none: weight 1 at every pixel with a depth."""
    H, W = depth.shape
    use_normal = normal_map.shape[0] == H and normal_map.shape[1] == W
    use_half = normal_half.shape[0] == H and normal_half.shape[1] == W
    use_keep = keep_bits.shape[0] > 0
    use_weight = weight_map.shape[0] == H and weight_map.shape[1] == W
    res = 16
    inv_trunc = 1.0 / trunc
    for i in prange(block_keys.shape[0]):
        base = np.int64(buf_idx[i]) * res * res * res
        x0 = np.float64(block_keys[i, 0]) * res
        y0 = np.float64(block_keys[i, 1]) * res
        z0 = np.float64(block_keys[i, 2]) * res
        for zv in range(res):
            Z = (z0 + zv) * voxel
            for yv in range(res):
                Y = (y0 + yv) * voxel
                # camera coordinates at x = 0 of this row, then a step along x per voxel
                px = R[0, 1] * Y + R[0, 2] * Z + t[0]
                py = R[1, 1] * Y + R[1, 2] * Z + t[1]
                pz = R[2, 1] * Y + R[2, 2] * Z + t[2]
                row = base + (zv * res + yv) * res
                for xv in range(res):
                    X = (x0 + xv) * voxel
                    zc = R[2, 0] * X + pz
                    if zc <= 0.0:
                        continue
                    xc = R[0, 0] * X + px
                    yc = R[1, 0] * X + py
                    u = np.floor(fx * xc / zc + cx + 0.5)
                    v = np.floor(fy * yc / zc + cy + 0.5)
                    if u < 0.0 or v < 0.0 or u >= W or v >= H:
                        continue
                    ui = np.int64(u)
                    vi = np.int64(v)
                    d = depth[vi, ui]
                    if d <= 0.0 or d >= depth_max:
                        continue
                    sdf = d - zc
                    if use_normal or use_half:
                        n0 = n1 = n2 = 0.0
                        kept = True
                        if use_keep:
                            k = vi * W + ui
                            kept = ((keep_bits[k >> 3] >> (7 - (k & 7))) & 1) == 1
                        if kept and use_half:
                            n0 = _half(normal_half[vi, ui, 0])
                            n1 = _half(normal_half[vi, ui, 1])
                            n2 = _half(normal_half[vi, ui, 2])
                        elif kept:
                            n0 = normal_map[vi, ui, 0]
                            n1 = normal_map[vi, ui, 1]
                            n2 = normal_map[vi, ui, 2]
                        if n0 * n0 + n1 * n1 + n2 * n2 > 0.25:
                            rx = (u - cx) / fx
                            ry = (v - cy) / fy
                            c = abs(n0 * rx + n1 * ry + n2)
                            lim = min_cos * np.sqrt(rx * rx + ry * ry + 1.0)
                            sdf *= max(c, lim)
                    if sdf < -trunc:
                        continue
                    w_new = weight_map[vi, ui] if use_weight else np.float32(1.0)
                    if w_new <= 0.0:
                        continue
                    if sdf > trunc:
                        sdf = trunc
                    li = row + xv
                    w_old = weight[li]
                    w_sum = w_old + w_new
                    inv = 1.0 / w_sum
                    tsdf[li] = (tsdf[li] * w_old + sdf * inv_trunc * w_new) * inv
                    for c in range(3):
                        color[li, c] = (color[li, c] * w_old + color_img[vi, ui, c] * w_new) * inv
                    weight[li] = w_sum


def _integrate_weighted(vbg, block_coords, f: "DepthFrame", voxel: float, trunc: float, depth_max: float,
                        normal_sdf: float = 0.0, keep: np.ndarray | None = None, ones: bool = False,
                        factor: float = 1.0) -> None:
    """TSDF integration with a per-pixel weight (the confidence map; weight 1 per pixel with a depth when
    ``ones``), on the grid's own voxel storage: Open3D's ``integrate`` gives every pixel weight 1. Same update
    rule: running weighted mean of the truncated SDF (and of the colour, 0..255, mid-grey where the frame has
    none). ``keep``: the pixels whose normal counts, packed bits (``np.packbits``), None for all."""
    import open3d.core as o3c

    hm = vbg.hashmap()
    _, found = hm.find(block_coords)
    fresh = ~found.numpy().astype(bool)
    if fresh.any():
        # only the blocks not in the grid yet: the hash map counts every key it is given against its capacity
        # and, when they exceed it, doubles its storage (a copy of every block: seconds, and twice the memory)
        hm.activate(o3c.Tensor(np.ascontiguousarray(block_coords.numpy()[fresh])))
    buf, _ = hm.find(block_coords)  # after activate: the storage may have been reallocated
    T = np.ascontiguousarray(f.view.cam_from_world, np.float64)
    intr = f.view.intrinsics
    color = f.color if f.color is not None else np.full(f.depth.shape + (3,), 180, np.uint8)
    tsdf = vbg.attribute("tsdf").numpy().reshape(-1)
    weight = vbg.attribute("weight").numpy().reshape(-1)
    grid_color = vbg.attribute("color").numpy().reshape(-1, 3)
    normals = np.zeros((1, 1, 3), np.float32)
    half = np.zeros((1, 1, 3), np.uint16)
    if normal_sdf > 0 and f.normal is not None:
        if f.normal.dtype == np.float16:
            half = np.ascontiguousarray(f.normal).view(np.uint16)
        else:
            normals = np.ascontiguousarray(f.normal, np.float32)
    keep = np.zeros(0, np.uint8) if keep is None else np.ascontiguousarray(keep, np.uint8)
    if factor != 1.0:  # a coarser frame (``frames.resolution_weights``)
        base = (f.depth > 0).astype(np.float32) if ones else np.asarray(f.confidence, np.float32)
        weights = np.ascontiguousarray(base * np.float32(factor))
    else:
        weights = np.zeros((1, 1), np.float32) if ones else np.ascontiguousarray(f.confidence, np.float32)
    _tsdf_weighted_kernel(np.ascontiguousarray(block_coords.numpy(), np.int32),
                          np.ascontiguousarray(buf.numpy().ravel(), np.int64), T[:3, :3].copy(), T[:3, 3].copy(),
                          float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy), float(voxel),
                          float(trunc), float(depth_max), np.ascontiguousarray(f.depth, np.float32),
                          weights, np.ascontiguousarray(color, np.uint8), normals, half, keep,
                          float(normal_sdf), tsdf, weight, grid_color)


def _new_grid(voxel: float, n_blocks: int):
    import open3d as o3d
    import open3d.core as o3c

    return o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=voxel, block_resolution=_BLOCK_RES, block_count=max(64, n_blocks),
        device=o3c.Device("CPU:0"))


def _depth_max(frames: list[DepthFrame], trunc: float) -> float:
    return float(max(f.depth.max() for f in frames)) * 1.01 + trunc


def _normal_band_blocks(f: DepthFrame, coords: np.ndarray, voxel: float, trunc: float, min_cos: float) -> np.ndarray:
    """``coords`` (N, 3) int32 block coordinates (Open3D's: the truncation band, +-trunc along each pixel's ray)
    and the blocks of the band that ``normal_sdf`` writes: with the SDF measured along the normal, a pixel whose
    surface makes the cosine c with its ray writes voxels up to trunc / max(c, ``min_cos``) along the ray
    (every other pixel, sampled every half block). On a surface seen at a grazing angle that band reaches the
    voxels just below the surface and the surface between rows of pixels, which lie in blocks that the band
    along the rays never reaches."""
    sub = np.zeros_like(f.depth)
    sub[::2, ::2] = f.depth[::2, ::2]
    nc = f.normal.astype(np.float32)
    valid = (sub > 0) & (np.einsum("hwc,hwc->hw", nc, nc) > 0.25)
    pts, uv = backproject_depth(np.where(valid, sub, 0), f.view.intrinsics, f.view.cam_from_world, return_pixels=True)
    if not len(pts):
        return coords
    ij = np.round(uv).astype(np.int64)
    rays = f.view.intrinsics.pixel_rays(uv)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    n = nc[ij[:, 1], ij[:, 0]].astype(np.float64)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    half = trunc / np.maximum(np.abs(np.einsum("ij,ij->i", rays, n)), min_cos)  # along the ray
    far = half > 1.5 * trunc
    if not far.any():
        return coords
    block = voxel * _BLOCK_RES
    step = 0.5 * block
    k = np.ceil(half[far] / step).astype(np.int64)  # samples each side
    idx = np.repeat(np.arange(int(far.sum())), 2 * k + 1)
    start = np.repeat(np.cumsum(2 * k + 1) - (2 * k + 1), 2 * k + 1)
    t = (np.arange(len(idx)) - start - np.repeat(k, 2 * k + 1)) * step
    t = np.clip(t, -half[far][idx], half[far][idx])
    u = rays[far] @ f.view.cam_from_world[:3, :3]  # camera -> world directions
    P = pts[far][idx] + t[:, None] * u[idx]
    extra = np.floor(P / block).astype(np.int32)
    return np.ascontiguousarray(unique_rows(np.concatenate([coords.astype(np.int32), extra])))


def planar_normals(f: DepthFrame, trunc: float, min_cos: float, tol: float, min_px: float = 2.0,
                   max_px: float = 8.0) -> np.ndarray:
    """``f.normal`` (H, W, 3) with the normals zeroed where the tangent-plane SDF is not justified.

    With ``normal_sdf`` a pixel writes its tangent plane into the voxels along its ray up to s = trunc /
    max(cos, ``min_cos``) behind its depth X, as lying under the plane. That claim holds where the plane goes
    on behind X: under the ground it does, but behind an object's rim (a limb, where the ray grazes a curved
    surface) the ray runs on into empty space and the plane would grow a fin there. The voxel X + s ray lies
    under the plane's point Q = X + s ray + s cos n (n towards the camera), which the camera sees a few
    pixels from X in the image direction of n. So a pixel keeps its normal only where its own depth map shows
    the plane there: the pixels at Q's image offset and half of it (at least ``min_px`` and half of it, at
    most ``max_px``; ``min_px`` for a limb, whose Q falls on the pixel itself) have a depth within ``tol``
    (scene units) of the pixel's tangent plane. A pixel whose normal faces its ray (cos near 1) is kept: its
    plane's distance is the distance along the ray. Camera frame, OpenCV axes; pinhole intrinsics."""
    intr = f.view.intrinsics
    n_all = np.ascontiguousarray(f.normal, np.float32)
    out = np.zeros_like(n_all)
    _planar_normals_kernel(np.ascontiguousarray(f.depth), n_all, float(intr.fx), float(intr.fy), float(intr.cx),
                           float(intr.cy), float(trunc), float(min_cos), float(tol), float(min_px), float(max_px), out)
    return out


@njit(parallel=True, cache=True)
def _planar_normals_kernel(d, n_all, fx, fy, cx, cy, trunc, min_cos, tol, min_px, max_px, out):  # pragma: no cover - compiled
    """``planar_normals`` per pixel (rows in parallel): ``out`` gets ``n_all`` where the test keeps it."""
    H, W = d.shape
    thresh = 1e-3 * 0.5 * (fx + fy)
    for r in prange(H):
        for c in range(W):
            dv = d[r, c]
            a0, a1, a2 = n_all[r, c, 0], n_all[r, c, 1], n_all[r, c, 2]
            if not (dv > 0 and a0 * a0 + a1 * a1 + a2 * a2 > np.float32(0.25)):
                continue
            x = (c - cx) / fx
            y = (r - cy) / fy
            z = np.float64(dv)
            n0, n1, n2 = np.float64(a0), np.float64(a1), np.float64(a2)
            nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            n0, n1, n2 = n0 / nn, n1 / nn, n2 / nn
            sg = -np.sign(n0 * x + n1 * y + n2)  # towards the camera
            n0, n1, n2 = n0 * sg, n1 * sg, n2 * sg
            norm = math.sqrt(x * x + y * y + 1.0)
            nr = n0 * x + n1 * y + n2
            cos = -nr / norm
            s = trunc / max(cos, min_cos)
            # image direction of n at X (pixels per unit length along n), and Q's offset from the pixel
            g0 = fx * (n0 - x * n2) / z
            g1 = fy * (n1 - y * n2) / z
            g_len = math.sqrt(g0 * g0 + g1 * g1)
            zs = z + s / norm
            sc = s * cos
            q2 = zs + sc * n2
            q0 = (x * zs + sc * n0) / q2
            q1 = (y * zs + sc * n1) / q2
            offset = math.hypot((q0 - x) * fx, (q1 - y) * fy)
            reach = min(max(offset, min_px), max_px)
            plane_d = z * nr  # n . X
            frontal = g_len * z < thresh
            gl = max(g_len, 1e-12)
            dir0, dir1 = g0 / gl, g1 / gl
            keep = True
            for t in (0.5, 1.0):
                uu = np.int64(np.rint(c + t * reach * dir0))
                vv = np.int64(np.rint(r + t * reach * dir1))
                inside = uu >= 0 and uu < W and vv >= 0 and vv < H
                uc = min(max(uu, 0), W - 1)
                vc = min(max(vv, 0), H - 1)
                dq = np.float64(d[vc, uc])
                xq = (uc - cx) / fx
                yq = (vc - cy) / fy
                off = dq * (n0 * xq + n1 * yq + n2) - plane_d
                keep = keep and (frontal or (inside and dq > 0 and abs(off) <= tol))
            if keep:
                out[r, c, 0], out[r, c, 1], out[r, c, 2] = a0, a1, a2


def _frame_blocks(vbg, f: DepthFrame, cfg: FusionConfig, voxel: float, depth_max: float
                  ) -> tuple[DepthFrame, np.ndarray, bool]:
    """What integrating ``f`` takes: the frame as integrated (normals kept only where ``planar_normals``
    justifies them; weight 1 per valid pixel where the tangent-plane SDF needs the compiled kernel and the
    frame has no confidence map), the (M, 3) int32 coordinates of the blocks it writes (Open3D's truncation
    band along the rays, widened by ``_normal_band_blocks``), and whether the compiled weighted kernel
    integrates it (else Open3D's ``integrate``). ``vbg`` serves Open3D's block search only (any grid with
    this voxel)."""
    import open3d as o3d
    import open3d.core as o3c

    intr = f.view.intrinsics
    if intr.has_distortion:
        raise BadArgumentError(f"view {f.view.name}: TSDF fusion needs undistorted (pinhole) depth maps")
    trunc = cfg.trunc_voxels * voxel
    K = o3c.Tensor(intr.K, o3c.float64)
    T = o3c.Tensor(np.ascontiguousarray(f.view.cam_from_world), o3c.float64)
    depth = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(f.depth, np.float32)))
    try:
        coords = vbg.compute_unique_block_coordinates(depth, K, T, 1.0, depth_max, float(cfg.trunc_voxels)).numpy()
    except RuntimeError as exc:  # Open3D refuses a frame whose few valid pixels touch no block: it adds nothing
        if "No block is touched" not in str(exc):
            raise
        coords = np.zeros((0, 3), np.int32)
    weighted = f.confidence is not None and cfg.confidence_weights
    if cfg.normal_sdf > 0 and f.normal is not None:
        if cfg.normal_sdf_plane_tol > 0:
            f = replace(f, normal=planar_normals(f, trunc, cfg.normal_sdf, cfg.normal_sdf_plane_tol * voxel))
        coords = _normal_band_blocks(f, coords, voxel, trunc, cfg.normal_sdf)
        if not weighted:  # the compiled kernel with weight 1: Open3D's integrate measures along the ray
            f = replace(f, confidence=(f.depth > 0).astype(np.float32))
            weighted = True
    return f, np.ascontiguousarray(coords, np.int32), weighted


def _integrate_blocks(vbg, f: DepthFrame, coords: np.ndarray, weighted: bool, cfg: FusionConfig, voxel: float,
                      depth_max: float, keep: np.ndarray | None = None, ones: bool = False, factor: float = 1.0) -> None:
    """Integrate the frame ``f`` (from ``_frame_blocks``) into the blocks ``coords`` of ``vbg``; ``keep``, ``ones``
    and ``factor`` (the frame's weight factor, ``frames.resolution_weights``) as ``_integrate_weighted``'s."""
    import open3d as o3d
    import open3d.core as o3c

    if not len(coords):
        return
    c = o3c.Tensor(np.ascontiguousarray(coords, np.int32))
    if weighted or factor != 1.0:
        _integrate_weighted(vbg, c, f, voxel, cfg.trunc_voxels * voxel, depth_max, cfg.normal_sdf, keep,
                            ones or not weighted, factor)
        return
    K = o3c.Tensor(f.view.intrinsics.K, o3c.float64)
    T = o3c.Tensor(np.ascontiguousarray(f.view.cam_from_world), o3c.float64)
    depth = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(f.depth, np.float32)))
    color = f.color if f.color is not None else np.full(f.depth.shape + (3,), 180, np.uint8)
    color = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(color, np.float32) / 255.0))
    vbg.integrate(c, depth, color, K, K, T, 1.0, depth_max, float(cfg.trunc_voxels))


def _integrate_frame(vbg, f: DepthFrame, cfg: FusionConfig, voxel: float, depth_max: float,
                     blocks: tuple[np.ndarray, np.ndarray] | None = None, factor: float = 1.0) -> int:
    """Integrate one frame into ``vbg`` (confidence-weighted when it has a confidence map); only the blocks it
    touches, and with ``blocks`` = (lo, hi) block coordinates only those with lo <= key < hi (a chunk).
    Returns the number of blocks integrated."""
    f, coords, weighted = _frame_blocks(vbg, f, cfg, voxel, depth_max)
    if blocks is not None:
        coords = coords[_in_box(coords, blocks[0], blocks[1])]
    _integrate_blocks(vbg, f, coords, weighted, cfg, voxel, depth_max, factor=factor)
    return int(len(coords))


def _extract(vbg, cfg: FusionConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Marching cubes on the grid: (vertices (V, 3) float64, faces (F, 3) int64, colours (V, 3) uint8 or None)."""
    mesh = vbg.extract_triangle_mesh(weight_threshold=cfg.weight_threshold)
    V = mesh.vertex.positions.numpy().astype(np.float64)
    F = mesh.triangle.indices.numpy().astype(np.int64)
    colors = None
    if "colors" in mesh.vertex:
        colors = (np.clip(mesh.vertex.colors.numpy(), 0, 1) * 255).astype(np.uint8)
    return V, F, colors


def tsdf_fuse(frames: list[DepthFrame], cfg: FusionConfig, sparse_points: np.ndarray | None = None) -> trimesh.Trimesh:
    """Integrate ``frames`` into a VoxelBlockGrid and extract a coloured triangle mesh.

    First every frame's blocks are found (``_frame_blocks``; kept: its block coordinates, and its normals'
    ``planar_normals`` mask as one bit per pixel). When all the blocks fit in ``cfg.grid_budget_gb`` the grid
    holds them all; else space is cut into cubic chunks that each fit, and each chunk (with one block layer
    around it) is integrated from the frames in their order and meshed, keeping the triangles whose centroid
    lies in its core: the same voxels, values and triangles as one grid (``tsdf_fuse_chunked`` does the same
    from disk, one task per chunk). Memory: the frames, one chunk's grid and the mesh, whatever the scene's
    extent."""
    frames = nonempty(frames)
    if not len(frames):
        raise NoDepthError("every depth map is empty (all pixels invalid, masked or out of range): nothing to fuse")
    budget = budget_share(cfg, "grid")
    # chunks bound the grid, so an automatic voxel (bounded by the depth maps' pixel footprint) is not
    # coarsened for the whole grid's size; a given --voxel-size is still refused when the whole grid would not fit
    auto = budget and cfg.voxel_size is None
    voxel, n_blocks = tsdf_voxel_size(frames, replace(cfg, memory_limit_gb=cfg.memory_limit_gb or 1e6)
                                      if auto else cfg, sparse_points)
    trunc = cfg.trunc_voxels * voxel
    depth_max = _depth_max(frames, trunc)
    probe = _new_grid(voxel, 64)
    # per frame: (coords, planar-normal mask or None, weighted, whether its weights are 1 per valid pixel)
    plans = []
    store = isinstance(frames, FrameStore)
    for i in bar(range(len(frames)), desc="tsdf blocks"):
        f = full_frame(frames, i)
        g, coords, weighted = _frame_blocks(probe, f, cfg, voxel, depth_max)
        keep, ones = None, g.confidence is not f.confidence
        if g.normal is not None and g.normal is not f.normal:
            if store:  # the frame on disk as integrated: its normals where planar_normals keeps them
                frames.replace_frame(i, replace(g, confidence=f.confidence))
            else:
                keep = np.packbits(np.any(g.normal != 0, axis=2), axis=None)
        plans.append((coords, keep, weighted, ones))
        del f, g
    del probe
    allb = unique_rows(np.concatenate([p[0] for p in plans]))
    per_block = _BLOCK_RES ** 3 * _BYTES_PER_VOXEL * 2  # storage, and marching cubes' buffers
    chunk = None
    if budget and len(allb) * per_block > budget:
        chunk = _chunk_size(allb, max(1, int(budget // per_block)))
    log.debug("tsdf: voxel %.5g, truncation %.5g, %d blocks, %s", voxel, trunc, len(allb),
              f"chunks of {chunk}^3 blocks" if chunk else "one grid")
    if chunk is None:
        boxes = [(None, None, len(allb))]
    else:
        ids = unique_rows(np.floor_divide(allb, chunk))
        boxes = [(i * chunk, (i + 1) * chunk, None) for i in ids]
    pieces = []
    factors = resolution_weights(frames, voxel / cfg.voxel_footprints)
    for lo, hi, count in bar(boxes, desc="tsdf fusion", unit="chunk") if chunk else boxes:
        if count is None:
            count = int(_in_box(allb, lo - 1, hi + 1).sum())
        vbg = _new_grid(voxel, int(count * 1.05) + 64)
        for i in bar(range(len(frames)), desc="tsdf fusion") if not chunk else range(len(frames)):
            coords, keep, weighted, ones = plans[i]
            if lo is not None:
                coords = coords[_in_box(coords, lo - 1, hi + 1)]
                if not len(coords):
                    continue
            # the frame as it is: the kernel reads its normals through ``keep`` and weighs by ``ones``
            _integrate_blocks(vbg, full_frame(frames, i), coords, weighted, cfg, voxel, depth_max, keep, ones,
                              factors[i])
        V, F, C = _extract(vbg, cfg)
        del vbg
        release_memory(collect=False)  # the grid is freed by reference counting
        if lo is not None and len(F):
            V, F, C = chunk_core(V, F, C, lo * voxel * _BLOCK_RES, hi * voxel * _BLOCK_RES)
        pieces.append((V.astype(np.float32), F.astype(np.int32), C))
    if sum(len(p[1]) for p in pieces) == 0:
        raise EmptyMeshError("TSDF fusion produced no triangle: check that the depth maps and poses agree "
                             "(lower --weight-threshold or use a larger --voxel-size)")
    if chunk is None:
        V, F, C = pieces[0]
        out = trimesh.Trimesh(V.astype(np.float64), F.astype(np.int64), vertex_colors=C, process=False)
    else:
        out = stitch_pieces(pieces)
    out.metadata["voxel_size"] = voxel
    out.metadata["mesher"] = "tsdf"
    out.metadata["chunks"] = len(boxes) if chunk else 1
    return out
