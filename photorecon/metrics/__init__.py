"""Accuracy metrics against ground truth: meshes (Chamfer, F-score, normal consistency), reference point
clouds (DTU / ETH3D / Tanks-and-Temples style, absolute thresholds), camera poses and depth.

- ``surfaces``: ``mesh_metrics``, ``cloud_metrics``, their distances and samples, error colours.
- ``poses``: ``align_cameras``, ``pose_metrics``, a result moved into the truth's frame through its cameras.
- ``depth``: ``depth_metrics``, co-visible pixels, two-view depth and disparity errors.

``umeyama`` (the Sim3 of two point sets) lives in ``photorecon.transform``; it is re-exported here.

Mesh metrics sample ``n_samples`` points area-uniformly on each mesh with a fixed seed (default 200,000,
seed 0) and measure exact point-to-triangle distances to the other mesh (Open3D ``RaycastingScene``):
accuracy = result -> truth, completeness = truth -> result, Chamfer = their mean;
precision / recall = fraction of those distances below tau; F = 2PR / (P + R).

Point-cloud metrics (``cloud_metrics``) do the same against a reference point cloud (e.g. a laser scan):
result surface samples -> nearest reference point (KD-tree) and reference point -> result surface (exact,
or nearest result point when the result is itself a point cloud). Result samples far outside the
reference's bounding box (background the reference does not cover) can be left out with ``crop_margin``.
"""
from ..transform import umeyama
from .depth import covisible, depth_metrics, disparity_scores, two_view_depth_scores
from .poses import (align_by_cameras, align_cameras, cameras_beside, evaluate_reconstruction, frames_differ,
                    pose_metrics)
from .surfaces import (CloudMetrics, MeshMetrics, ThresholdScore, _Distance, check_taus, cloud_metrics,
                       distance_to, doubled_shell_fraction, error_colors, icp_refine, load_reference, mesh_metrics,
                       sample_surface, seen_split_metrics)

__all__ = ["CloudMetrics", "MeshMetrics", "ThresholdScore", "align_by_cameras", "align_cameras", "cameras_beside",
           "check_taus", "cloud_metrics", "covisible", "depth_metrics", "disparity_scores", "distance_to",
           "doubled_shell_fraction", "error_colors", "evaluate_reconstruction", "frames_differ", "icp_refine",
           "load_reference", "mesh_metrics", "pose_metrics", "sample_surface", "seen_split_metrics",
           "two_view_depth_scores", "umeyama"]
