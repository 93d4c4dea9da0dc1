"""Fusion: depth maps with their cameras in, one triangle mesh out.

``load_frames`` turns a dataset's depth maps into ``DepthFrame``s; ``fuse`` meshes them with the mesher that
``FusionConfig.mesher`` names: ``tsdf`` (TSDF fusion; ``chunked`` when the grid exceeds its budget or runs on a
cluster), ``grid`` (per-view grids merged by voxel ownership), ``poisson`` (screened Poisson, optionally
watertight). ``fuse_dataset`` and ``fuse_to_files`` add cleaning, export, previews and ``surface_report``
(how much of the surface no depth map observed). ``legacy_article_fuse`` is the original article's mesher.
"""
from __future__ import annotations

import logging

import numpy as np
import trimesh

from ..arrays import position_order
from ..cameras import View
from ..errors import BadArgumentError, EmptyMeshError
from ..config_checks import expect_config
from ..mesh import (CleanConfig, boundary_length, clean_open3d, closed_companion, export, filled_area,
                    to_open3d)
from ..resources import release_memory
from .budget import estimate_blocks, estimate_faces, tsdf_voxel_size
from .chunked import plan_chunks, tsdf_fuse_chunked
from .config import DepthFrame, FusionConfig, budget_share, frames_hold_bytes
from .frames import (FrameStore, depth_view, full_frame, load_frame, load_frames, nonempty, pixel_footprint,
                     prepare_depth, scene_diagonal)
from .grid import grid_fuse, grid_mesh_view
from .legacy import legacy_article_fuse
from .pieces import stitch_pieces
from .points import observed_distance, observed_points, oriented_points, surface_report
from .poisson import poisson_fuse
from .tsdf import planar_normals, tsdf_fuse

log = logging.getLogger("photorecon")


def fuse(frames: list[DepthFrame], cfg: FusionConfig, sparse_points: np.ndarray | None = None, executor=None,
         dataset=None, work_dir=None) -> trimesh.Trimesh:
    """Fuse depth frames into one mesh with ``cfg.mesher``, in ``canonical_order`` (the same frames give the same
    mesh). TSDF runs in chunks (``tsdf_fuse_chunked``, which reads the depth maps from ``dataset``) when
    ``cfg.chunk_voxels`` is set or ``executor`` is a distributed one."""
    cfg = expect_config(cfg, FusionConfig, "cfg")
    if cfg.watertight and cfg.mesher != "poisson":
        raise BadArgumentError(f"--watertight needs --mesher poisson (got --mesher {cfg.mesher})")
    if cfg.mesher == "tsdf" and not cfg.watertight:
        if dataset is not None and (cfg.chunk_voxels or getattr(executor, "distributed", False)):
            mesh = tsdf_fuse_chunked(dataset, frames, cfg, sparse_points, executor, work_dir)
        else:
            mesh = tsdf_fuse(frames, cfg, sparse_points)
    elif cfg.mesher == "grid":
        mesh = grid_fuse(frames, cfg)
    elif cfg.mesher == "poisson":
        mesh = poisson_fuse(frames, cfg)
    else:
        raise BadArgumentError(f"mesher: expected 'tsdf', 'grid' or 'poisson', got {cfg.mesher!r}")
    return canonical_order(mesh) if len(mesh.faces) else mesh


def fuse_dataset(root, out, cfg: FusionConfig | None = None, clean_cfg=None, depth_dir=None,
                 overwrite: bool = False, formats: tuple[str, ...] = ("ply",), masks_dir=None, cluster=None):
    """``photorecon fuse``: dataset folder (synth layout) -> ``out/mesh.ply`` (+ other formats, preview.png).
    ``masks_dir``: masks (NAME.png or NAME.EXT.png, 0 = ignore) instead of DATASET/masks. ``cluster``: a
    ``distributed.ClusterConfig`` (TSDF then in chunks, one task each; pieces under OUT/.work). Returns the mesh path."""

    from ..io.dataset import Dataset
    from ..io.output import output_folder
    from ..layout import Layout
    from ..report.preview import render_preview

    cfg = expect_config(cfg, FusionConfig, "cfg")
    clean_cfg = expect_config(clean_cfg, CleanConfig, "clean_cfg")
    ds = Dataset.open(root, depth_dir, masks_dir)
    frames = load_frames(ds, cfg, hold_bytes=frames_hold_bytes(cfg))
    from ..distributed import executor

    with output_folder(out, overwrite, inputs=(root, depth_dir, masks_dir), command="fuse", resumable=False) as out:
        layout = Layout(out)
        cameras = list(frames.views) if isinstance(frames, FrameStore) else [f.view for f in frames]
        with executor(cluster) as ex:
            mesh, _ = fuse_to_files(frames, cfg, clean_cfg or CleanConfig(), layout, formats, cameras,
                                    ds.model.points, ex, ds, layout.work)
        from ..report import decimate_for_viewer

        render_preview(decimate_for_viewer(mesh), layout.preview, cameras=cameras)  # a few hundred pixels a side
        return layout.mesh("ply")


def canonical_order(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The same mesh with its vertices sorted by position and its faces by their vertex numbers (each face
    starting at its lowest vertex, its winding kept): marching cubes on several threads (Open3D's, the chunks'
    stitching) emits the same triangles in an order that changes between runs, and the cleaning and the files
    would follow it (``fuse`` returns its meshes in this order)."""
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    order, rank = position_order(v)
    f = rank.astype(f.dtype)[f]
    first = f.argmin(axis=1)
    f = np.take_along_axis(f, (first[:, None] + np.arange(3)) % 3, axis=1)
    f = f[np.lexsort((f[:, 2], f[:, 1], f[:, 0]))]
    colors = np.asarray(mesh.visual.vertex_colors)[order] if mesh.visual.kind == "vertex" else None
    return trimesh.Trimesh(v[order], f, vertex_colors=colors, process=False, metadata=dict(mesh.metadata))


def fuse_to_files(frames: list[DepthFrame], cfg: FusionConfig, clean_cfg, layout, formats: tuple[str, ...],
                  cameras: list[View], sparse_points: np.ndarray | None = None, executor=None, dataset=None,
                  work_dir=None) -> tuple[trimesh.Trimesh, dict]:
    """The fusion stage of ``reconstruct`` and ``fuse``: ``fuse`` -> ``clean`` (floaters judged against
    ``cameras``) -> ``layout.mesh(fmt)`` for each format. Returns the mesh and its facts (counts and
    ``surface_report``: watertight, boundary edges, invented fraction), which are also logged.

    Once fused, each entry of ``frames`` is replaced by the frame with its depth map only (the surface report
    needs no more): the colour, confidence and normal maps are freed before the cleaning unless the caller
    holds the frames elsewhere."""
    fused = fuse(frames, cfg, sparse_points, executor, dataset, work_dir)
    if isinstance(frames, list):
        frames[:] = [DepthFrame(f.view, f.depth) for f in frames]
    if not len(fused.faces):
        raise EmptyMeshError("the mesh has no triangle")
    m, metadata = to_open3d(fused), dict(fused.metadata)
    del fused  # the cleaning works on the Open3D copy
    release_memory()  # the grid's and the frames' freed pages: the cleaning's peak would stack on them
    mesh = clean_open3d(m, metadata, clean_cfg, cameras=cameras)
    del m
    release_memory()
    for fmt in formats:
        export(mesh, layout.mesh(fmt))
    closed = write_closed(mesh, clean_cfg, layout, formats)
    release_memory()
    surface = surface_report(mesh, frames)
    log.info("mesh: %d views -> %d vertices, %d faces; watertight: %s, %d boundary edges, %.1f%% of its area "
             "invented", len(frames), len(mesh.vertices), len(mesh.faces), surface["watertight"],
             surface["boundary_edges"], 100 * surface["invented_fraction"])
    support = {k: v for k, v in mesh.metadata.items() if k.startswith("support_")}  # the object's support removed
    scene = {"scene": mesh.metadata["scene"]} if "scene" in mesh.metadata else {}  # what --scene detected and did
    fusion = {"streamed": isinstance(frames, FrameStore)}  # depth frames read one at a time (--fusion-memory)
    if metadata.get("voxel_size"):
        fusion["voxel_size"] = float(metadata["voxel_size"])
    fill = {"boundary_length": boundary_length(mesh), "filled_area": filled_area(mesh),
            "fill": mesh.metadata.get("fill"), "closed": closed}
    return mesh, {"vertices": len(mesh.vertices), "faces": len(mesh.faces), "depth_maps_fused": len(frames),
                  "mesher": cfg.mesher, **fusion, **surface, **fill, **support, **scene}


def write_closed(mesh: trimesh.Trimesh, clean_cfg, layout, formats: tuple[str, ...], metadata: dict | None = None):
    """For an object capture (``metadata``, default the mesh's: its ``scene``, what the cleaning detected) unless
    ``clean_cfg.closed`` is "off": the watertight companion of ``mesh`` (``mesh.closed_companion``) written to
    ``layout.mesh_closed(fmt)`` for each format; returns its facts (``file``, ``watertight``, ``filled_area``,
    ``faces``), or None after removing any such file an earlier run left."""
    metadata = mesh.metadata if metadata is None else metadata
    if getattr(clean_cfg, "closed", "off") == "off" or (metadata.get("scene") or {}).get("detected") != "object":
        for fmt in formats:
            layout.mesh_closed(fmt).unlink(missing_ok=True)
        return None
    src = mesh
    if metadata is not mesh.metadata:
        src = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=mesh.visual.vertex_colors
                              if mesh.visual.kind == "vertex" else None, process=False)
        src.metadata.update(metadata)
    closed, info = closed_companion(src)
    for fmt in formats:
        export(closed, layout.mesh_closed(fmt))
    log.info("closed mesh: %s, %s faces, filled area %.3g scene units² (%s)", "watertight" if info["watertight"]
             else "NOT watertight", f"{info['faces']:,}", info["filled_area"], layout.mesh_closed(formats[0]).name)
    return {"file": layout.mesh_closed(formats[0]).name, **info}
