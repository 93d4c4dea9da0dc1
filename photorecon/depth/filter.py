"""The multi-view geometric filter: each depth map checked against the depth maps of its source views (and the
next best ranked ones), by reprojection and relative depth, or on the surface with PatchMatch's normals; a
view with one partner gets a left-right check. Depth maps in, the count of agreeing views per pixel out.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..cameras import backproject_depth, invert_rigid, project, transform_points
from .config import DepthResult, MVSConfig
from .select import select_sources


def _nearest_pixel(uv: np.ndarray, z: np.ndarray, intr) -> np.ndarray:
    """(N, 2) integer pixel (column, row) nearest to each projection; -1 where behind or outside the image."""
    with np.errstate(invalid="ignore"):
        ij = np.round(np.nan_to_num(uv, nan=-1.0)).astype(np.int64)
        ok = (z > 0) & (ij[:, 0] >= 0) & (ij[:, 0] < intr.width) & (ij[:, 1] >= 0) & (ij[:, 1] < intr.height)
    ij[~ok] = -1
    return ij


PLANE_MAX_ANGLE_DEG = 20.0  # the plane test's largest angle between the two views' normals


def consistency_count(r: DepthResult, sources: dict[str, DepthResult], cfg: MVSConfig) -> tuple[np.ndarray, float, int]:
    """For each depth of ``r``: how many of its ``sources`` (name -> result) confirm it. The depth's world point
    P goes into the source, whose depth at the nearest pixel gives its point Q. A source confirms P when

    * Q re-projects into ``r`` within ``reproj_px`` pixels of P and within ``rel_depth`` of its depth (ACMM,
      COLMAP), or
    * (plane test, both views with normals, ``plane_reproj_px`` > 0) Q re-projects within ``plane_reproj_px``
      pixels, P and Q each lie within ``reproj_px`` pixel footprints (z / f of ``r``) of the other's tangent
      plane, and their normals agree within ``PLANE_MAX_ANGLE_DEG``. On a surface seen at a grazing angle two
      views agree on the surface but not on the point: an error along a source's ray moves Q along the surface,
      many pixels in ``r``, while it stays within a footprint of it (entry-P10's ground: a median 10 px
      reprojection error, 0.9 footprints off the plane, normals 6 degrees apart).

    Returns (counts (h, w) int32, sum and number of the point-agreeing pairs' forward-backward reprojection
    errors in pixels). Pinhole cameras take the compiled path (``_consistency_count_pinhole``), cameras with
    distortion the numpy one (``_consistency_count_any``)."""
    views = [r.view] + [sources[s].view for s in r.sources if s in sources]
    if not any(v.intrinsics.has_distortion for v in views):
        return _consistency_count_pinhole(r, sources, cfg)
    return _consistency_count_any(r, sources, cfg)


def _consistency_count_any(r: DepthResult, sources: dict[str, DepthResult], cfg: MVSConfig) -> tuple[np.ndarray, float, int]:
    """``consistency_count`` for any camera model and the plane test (numpy; distortion through
    ``cameras.project``)."""
    d = r.depth
    valid = d > 0
    cnt = np.zeros(d.shape, np.int32)
    err_sum, err_n = 0.0, 0
    pts, uv = backproject_depth(np.where(valid, d, 0), r.view.intrinsics, r.view.cam_from_world, return_pixels=True)
    T = r.view.cam_from_world
    d_ref = d[valid]
    plane = cfg.plane_reproj_px > 0 and r.normal is not None
    if plane:
        tol = cfg.reproj_px * d_ref / r.view.intrinsics.fx  # reproj_px pixel footprints
        n_ref = r.normal[valid].astype(np.float64) @ T[:3, :3]  # camera -> world
        cos_max = np.cos(np.radians(PLANE_MAX_ANGLE_DEG))
    for sname in r.sources:
        s = sources.get(sname)
        if s is None or not len(pts):
            continue
        # into the source: its depth at the nearest pixel ...
        intr = s.view.intrinsics
        uv_s, z = project(pts, intr, s.view.cam_from_world)
        ij = _nearest_pixel(uv_s, z, intr)
        ok = ij[:, 0] >= 0
        ds = np.zeros(len(pts), np.float32)
        ds[ok] = s.depth[ij[ok, 1], ij[ok, 0]]
        ok &= ds > 0
        # ... and back: that depth -> world -> reference pixel and depth
        pw = transform_points(invert_rigid(s.view.cam_from_world), intr.pixel_rays(ij[ok]) * ds[ok, None])
        uv_r, zr = project(pw, r.view.intrinsics, T)
        err = np.linalg.norm(uv_r - uv[ok], axis=1)
        dr = d_ref[ok]
        good = (err < cfg.reproj_px) & (np.abs(zr - dr) / dr < cfg.rel_depth)
        err_sum += float(err[good].sum())
        err_n += int(good.sum())
        if plane and s.normal is not None:
            near = np.flatnonzero(~good & (err < cfg.plane_reproj_px))
            k = np.flatnonzero(ok)[near]
            n_s = s.normal[ij[k, 1], ij[k, 0]].astype(np.float64) @ s.view.cam_from_world[:3, :3]
            D = pw[near] - pts[k]
            good[near] = ((np.abs(np.einsum("ij,ij->i", D, n_ref[k])) < tol[k])
                          & (np.abs(np.einsum("ij,ij->i", D, n_s)) < tol[k])
                          & (np.einsum("ij,ij->i", n_ref[k], n_s) > cos_max))
        agree = np.zeros(len(pts), bool)
        agree[np.flatnonzero(ok)] = good
        cnt[valid] += agree
    return cnt, err_sum, err_n


def _consistency_count_pinhole(r: DepthResult, sources: dict[str, DepthResult], cfg: MVSConfig) -> tuple[np.ndarray, float, int]:
    """``consistency_count`` for cameras without distortion, compiled (``_filter_kernel.consistency_source``)."""
    from . import _filter_kernel as k

    d = np.ascontiguousarray(r.depth, np.float32)
    cnt = np.zeros(d.shape, np.int32)
    err_rows = np.zeros(d.shape[0], np.float64)
    n_rows = np.zeros(d.shape[0], np.int64)
    Kr = np.asarray(r.view.intrinsics.K, np.float64)
    Kr_inv = np.linalg.inv(Kr)
    world_from_ref = invert_rigid(r.view.cam_from_world)
    none = np.zeros((1, 1, 3), np.float32)
    plane = cfg.plane_reproj_px > 0 and r.normal is not None
    normal = np.ascontiguousarray(r.normal, np.float32) if plane else none
    cos_max = float(np.cos(np.radians(PLANE_MAX_ANGLE_DEG)))
    for sname in r.sources:
        s = sources.get(sname)
        if s is None:
            continue
        rel = s.view.cam_from_world @ world_from_ref
        Ks = np.asarray(s.view.intrinsics.K, np.float64)
        snormal = np.ascontiguousarray(s.normal, np.float32) if plane and s.normal is not None else none
        k.consistency_source(d, Kr, Kr_inv, np.ascontiguousarray(rel[:3, :3]), np.ascontiguousarray(rel[:3, 3]),
                             Ks, np.linalg.inv(Ks), np.ascontiguousarray(s.depth, np.float32), float(cfg.reproj_px),
                             float(cfg.rel_depth), cnt, err_rows, n_rows, normal, snormal,
                             float(cfg.plane_reproj_px) if plane else 0.0, cos_max)
    return cnt, float(err_rows.sum()), int(n_rows.sum())


def _filter_config(cfg: MVSConfig, n_views: int) -> MVSConfig:
    """The consistency filter's settings for a view checked against ``n_views`` others: against one (a stereo
    pair) it is a left-right check, each depth re-projected into the other view and back within
    ``pair_reproj_px`` pixels and ``rel_depth``, without the plane test (which admits ``plane_reproj_px``): what
    fails it is occluded in the other view, or a wrong match."""
    if n_views != 1 or cfg.pair_reproj_px <= 0:
        return cfg
    return dataclasses.replace(cfg, reproj_px=cfg.pair_reproj_px, plane_reproj_px=0.0)


def _filter_plan(model, views: dict[str, tuple], cfg: MVSConfig) -> dict[str, list[str]]:
    """Per planned view, the views its consistency filter checks: its matching sources, then the next best ranked
    (``select_sources``) up to ``filter_sources`` in all, among the planned views."""
    if cfg.filter_sources <= 0 or cfg.min_consistent <= 0:
        return {}
    wide = dataclasses.replace(cfg, n_sources=max(cfg.filter_sources, cfg.n_sources))
    by_name = {v.name: v for v in model.views}
    out = {}
    for name, (_, srcs, _, _) in views.items():
        ranked = [s.name for s in select_sources(model, by_name[name], wide) if s.name in views]
        out[name] = list(dict.fromkeys(srcs + ranked))[: max(cfg.filter_sources, len(srcs))]
    return out
