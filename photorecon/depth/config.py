"""Multi-view stereo settings (``MVSConfig``, its presets) and the per-view depth result (``DepthResult``): what the
stage's modules (``filter``, ``select``, ``mvs``, the methods) share, in a module that imports none of them but the
method registry (``methods``: ``MVSConfig.method``'s choices).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..cameras import View
from ..fields import check_config
from .methods import names as method_names, view_help

# pixels: a projection this far beyond an image's first or last pixel centre is on it (a rectified pair's border row
# lands on the other view's last one give or take rounding); PatchMatch's NCC, its slow oracle and the gap fill's
# photometric test
EDGE_TOL = 1e-3


@dataclass
class MVSConfig:
    """Settings of the multi-view stereo stage (``photorecon mvs``)."""

    # "tuning": a setting only benchmarks change (left out of --help-all; docs/cli.md's "Tuning settings")
    # the registry's per-view methods (depth/methods/__init__.py), read when the hints are evaluated
    method: Literal[method_names("view")] = field(default="patchmatch", metadata={"help": view_help()})
    n_sources: int = field(default=8, metadata={"help": "source views matched per reference view", "range": (1, 256)})
    max_size: int = field(default=1600, metadata={"help": "working resolution: longest image side in pixels (0 = full resolution)", "range": (64, 65536), "also": (0,)})
    min_confidence: float = field(default=0.2, metadata={"help": "drop depths whose confidence (1 - matching cost, 0..1) is below this before the geometric filter (0 = the filter alone decides)", "range": (0.0, 1.0)})
    min_texture: float = field(default=0.0, metadata={"help": "patchmatch: no depth where the window's grey standard deviation (grey 0..1) is below this (0 = off)", "range": (0.0, 1.0)})
    texture_rel: float = field(default=0.0, metadata={"help": "patchmatch: no depth where the window's grey std. deviation is below this fraction of the image's median (0 = off)", "range": (0.0, 100.0)})
    textured_min_confidence: float = field(default=0.0, metadata={"tuning": True, "help": "with --texture-rel: the confidence threshold (in place of --min-confidence) of the pixels it keeps", "range": (0.0, 1.0)})
    min_consistent: int = field(default=2, metadata={"help": "geometric filter: other views that must agree with a depth, at most the views checked (0 = off)", "range": (0, 256)})
    pair_reproj_px: float = field(default=1.0, metadata={"help": "geometric filter of a view checked against one other view (a stereo pair): left-right check, max forward-backward reprojection error, pixels (0 = as --reproj-px)", "range": (0.0, 1000.0)})
    filter_sources: int = field(default=16, metadata={"help": "geometric filter: views each depth is checked against (the matching sources, then the next best ranked; 0 = the matching sources only)", "range": (0, 256)})
    consistency_confidence: bool = field(default=True, metadata={"tuning": True, "help": "geometric filter: a depth that k views confirm gets at least confidence 1 - 1/k (its fusion weight)"})
    reproj_px: float = field(default=2.0, metadata={"help": "geometric filter: max reprojection error, pixels", "range": (0.0, 1000.0), "exclusive_min": True})
    rel_depth: float = field(default=0.01, metadata={"help": "geometric filter: max relative depth difference (fraction of the depth)", "range": (0.0, 1.0), "exclusive_min": True})
    plane_reproj_px: float = field(default=10.0, metadata={"help": "geometric filter: a view also confirms a depth within this many pixels when planes and normals agree (0 = off)", "range": (0.0, 1000.0)})
    depth_near: float | None = field(default=None, metadata={"help": "depth range: the sparse points' 1st percentile times this (default: 0.6 for patchmatch, 1/1.1 for the sweep)", "range": (0.0, 100.0), "exclusive_min": True})
    depth_far: float | None = field(default=None, metadata={"help": "depth range: the sparse points' 99th percentile times this (default: 1.25 for patchmatch, 1.1 for the sweep)", "range": (0.0, 1000.0), "exclusive_min": True})
    min_angle_deg: float = field(default=2.0, metadata={"help": "view selection: minimum triangulation angle, degrees", "range": (0.0, 90.0)})
    pm_levels: int = field(default=3, metadata={"help": "patchmatch: pyramid levels (each halves the image)", "range": (1, 8)})
    pm_iterations: int = field(default=5, metadata={"help": "patchmatch: iterations at the coarsest level", "range": (1, 100)})
    pm_fine_iterations: int = field(default=1, metadata={"help": "patchmatch: iterations at each finer level", "range": (0, 100)})
    pm_final_iterations: int = field(default=1, metadata={"help": "patchmatch: extra geometric-consistency iterations (0 = none)", "range": (0, 100)})
    pm_final_own_round: bool = field(default=True, metadata={"tuning": True, "help": "patchmatch: the level of the extra geometric-consistency round also gets a round of its own (--pm-fine-iterations) before it; off: the geometric round is that level's one pass (at full resolution about half the NCC evaluations, and less of the surface confirmed: see docs/benchmarks.md)"})
    pm_prune_cost: float = field(default=0.8, metadata={"help": "patchmatch: after the coarsest level, pixels whose previous round's cost exceeds this, and every neighbour's within 2 of that round's pixels too, are not computed (no depth there: no surface matched around them); 0 = off", "range": (0.0, 4.0)})
    pm_final_level: int = field(default=0, metadata={"help": "patchmatch: pyramid level of the extra geometric-consistency round (0 = full resolution; 1 = half: faster)", "range": (0, 7)})
    pm_skip_consistent: int = field(default=2, metadata={"tuning": True, "help": "patchmatch: the extra geometric round skips pixels that this many sources confirm within 1 pixel (0 = off)", "range": (0, 256)})
    pm_radius: int = field(default=5, metadata={"help": "patchmatch: NCC window radius, pixels (with --pm-stride 2, radius 5 = 6x6 samples over 11x11 pixels)", "range": (1, 32)})
    pm_stride: int = field(default=2, metadata={"help": "patchmatch: the NCC window is sampled every this many pixels", "range": (1, 16)})
    pm_sparse_min_size: int = field(default=1024, metadata={"help": "patchmatch: levels with a long side of at least this many pixels sample the window as a checkerboard (0 = off)", "range": (0, 65536)})
    pm_sigma_color: float = field(default=0.1, metadata={"tuning": True, "help": "patchmatch: grey-level sigma of the bilateral NCC weight (grey 0..1)", "range": (0.0, 10.0), "exclusive_min": True})
    pm_fine_sources: int = field(default=0, metadata={"help": "patchmatch: after the coarsest level, match only the best this many source views (0 = all)", "range": (0, 256)})
    pm_fine_refine: int = field(default=2, metadata={"tuning": True, "help": "patchmatch: refinement hypotheses per pixel after the coarsest level (2, 3 or 6: also random ones)", "range": (0, 6)})
    pm_fine_views: Literal["joint", "current"] = field(default="joint", metadata={"tuning": True, "help": "patchmatch: view weights after the coarsest level: joint (ACMH: every candidate in every source) or current (from each pixel's own hypothesis; the other candidates evaluated in the weighted sources only, until they cannot win: fewer evaluations)"})
    pm_carry_views: bool = field(default=True, metadata={"tuning": True, "help": "patchmatch: after the coarsest level, each pixel matches only the sources that the view selection of the round before used there or at the neighbours it takes candidates from (the sources no view selection around it used cost no evaluations); off = every source at every pixel"})
    pm_reuse_cost: bool = field(default=True, metadata={"tuning": True, "help": "patchmatch: finer levels start from the coarser level's costs (upsampled) instead of recomputing them"})
    pm_same_depth: float = field(default=1e-3, metadata={"tuning": True, "help": "patchmatch: candidates this close in relative depth (and --pm-same-normal-deg in normal) share one cost evaluation", "range": (0.0, 1.0)})
    pm_same_normal_deg: float = field(default=1.5, metadata={"tuning": True, "help": "patchmatch: normal tolerance of --pm-same-depth, degrees", "range": (0.0, 90.0)})
    geom_consistency: bool = field(default=True, metadata={"help": "patchmatch: geometric-consistency term between views (ACMM)"})
    geom_weight: float = field(default=0.2, metadata={"tuning": True, "help": "patchmatch: weight of the geometric term (per pixel of reprojection error)", "range": (0.0, 100.0)})
    fill_gaps: Literal["auto", "on", "off"] = field(default="auto", metadata={"help": "geometric filter: fill small gaps between kept depths, and the edges of larger ones, with a neighbouring pixel's plane where the other views' depth maps confirm it as they confirm any depth and the images agree, or where the images alone match it clearly (a pixel distinct along its epipolar line); auto = on for a view checked against one other view (a stereo pair)"})
    fill_max_gap: int = field(default=400, metadata={"help": "--fill-gaps: largest gap filled, pixels at the working resolution", "range": (1, 1 << 24)})
    planar_prior: bool = field(default=False, metadata={"help": "patchmatch: planar prior (ACMP): planes through confident pixels tried where the depth is not confident"})
    triangulate: bool = field(default=True, metadata={"help": "cameras without sparse points: triangulate SIFT matches with the cameras held fixed (view selection, depth ranges)"})
    pm_seed: int = field(default=0, metadata={"help": "patchmatch: random seed (results are deterministic for a seed)", "range": (0, 2**31 - 1)})
    n_depths: int = field(default=128, metadata={"help": "sweep: depth hypotheses (planes, uniform in inverse depth)", "range": (2, 16384)})
    window: int = field(default=7, metadata={"help": "sweep: ZNCC window size in pixels (odd)", "range": (1, 63), "odd": True})
    best_k: int = field(default=2, metadata={"help": "sweep: aggregate the best k source scores per pixel", "range": (1, 256)})
    depth_views: Literal["auto", "coarse", "all"] = field(default="auto", metadata={"help": "views that get a depth map: auto = enough views to see every sparse point well from --depth-view-coverage directions (a redundant capture computes fewer depth maps; a small one keeps all), and from 40 views kept on, also enough of those to see the coarse surface well (as coarse); coarse = PatchMatch's coarsest round for every view, then enough views to see that dense surface well (for captures whose sparse tracks are short); all = every view"})
    depth_resolution: Literal["auto", "full"] = field(default="auto", metadata={"help": "depth map resolution: auto = where the coarse surface chose the views (a large capture), half (or a quarter of) the working resolution for a view whose map at that resolution still resolves the fused mesh's voxel (planned from the coarse maps; it grows with the surface under --memory-gb), half for a view whose surface full-resolution views see as finely from a similar direction; full = every map at the working resolution"})
    depth_view_coverage: int = field(default=3, metadata={"help": "--depth-views auto/coarse: chosen views that must see each sparse point (coarse: each coarse surface sample) at a good angle and resolution", "range": (1, 64)})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.fields)


# Named settings for a caller that needs other values than the defaults (which are for 1600-px photos):
# "fast" is PatchMatch for small images and previews (the demo): 4 sources, 2 pyramid levels, fewer iterations.
MVS_PRESETS: dict[str, dict] = {
    "fast": dict(n_sources=4, pm_levels=2, pm_iterations=4, pm_fine_iterations=1, pm_final_iterations=1,
                 min_consistent=1, min_confidence=0.2, filter_sources=0),  # one view confirms: keep the cost threshold
}



@dataclass
class DepthResult:
    depth: np.ndarray  # (h, w) float32 at working resolution
    confidence: np.ndarray | None  # (h, w) float32 in [0, 1]; None for a filter's source view (not read)
    view: View  # the reference view at working resolution
    sources: list[str]
    normal: np.ndarray | None = None  # (h, w, 3) float16 unit normals, reference camera frame (patchmatch)
