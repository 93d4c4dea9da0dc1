"""Depth at the resolution the mesh keeps (``--depth-resolution auto`` on a capture whose views the coarse depth
maps choose): the voxel the fusion will use is planned from the coarse maps (``fusion.budget.planned_footprint``
on ``depth.views.confirmed_surface``), a view whose half-resolution map resolves it gets half resolution
(``depth.views.mesh_levels``); and the spread views whose coarse maps make the first look (``first_look_views``).
Synthetic cameras, rendered depth; no image is matched."""
import numpy as np
import pytest

from conftest import coarse_maps
from photorecon.depth.views import (MESH_LEVEL_MAX, confirmed_surface, first_look_views, map_footprint, mesh_levels,
                                    spread_views, ViewChoice)
from photorecon.fusion import FusionConfig
from photorecon.fusion.budget import MESH_BYTES_PER_FACE, estimate_faces, planned_footprint, tsdf_voxel_size
from photorecon.fusion.config import DepthFrame
from photorecon.render import Renderer
from photorecon.synthetic import SynthConfig, make_scene, make_views, normalize_mesh


@pytest.fixture(scope="module")
def scene():
    renderer = Renderer(normalize_mesh(make_scene("blob"))[0])
    views = make_views(SynthConfig(views=48, rig="sphere", width=320, height=240))
    return renderer, views


def _sources(views, k: int = 6) -> dict:
    C = np.array([v.center for v in views])
    out = {}
    for i, v in enumerate(views):
        order = np.argsort(np.linalg.norm(C - C[i], axis=1))[1:k + 1]
        out[v.name] = [views[j].name for j in order]
    return out


def _true_frames(renderer, views) -> list:
    return [DepthFrame(view=v, depth=renderer.render(v).depth.astype(np.float32)) for v in views]


def test_the_planned_voxel_is_the_one_the_fusion_chooses(scene):
    """With a memory budget that makes the fusion coarsen its voxel (to about twice 1.5 footprints), the voxel
    planned from the coarse maps, their unconfirmed background left out, is within 15% of the one the fusion
    chooses from the full-resolution depth maps; planned from the raw coarse maps, the background swells it."""
    renderer, views = scene
    frames = _true_frames(renderer, views)
    base = FusionConfig(memory_gb=0)
    v0, _ = tsdf_voxel_size(frames, base)
    faces = estimate_faces(frames, v0)
    cfg = FusionConfig(memory_gb=faces * MESH_BYTES_PER_FACE / 4 / 0.5 / 2 ** 30)  # the mesh share holds 1/4
    voxel, _ = tsdf_voxel_size(frames, cfg)
    assert voxel > 1.6 * v0, (voxel, v0)
    maps = coarse_maps(renderer, views, background=(1.5, 6.0), relative=True, background_cost=0.3)
    working = {v.name: v for v in views}
    need = planned_footprint(confirmed_surface(maps, _sources(views), 2), working, cfg)
    assert abs(need * cfg.voxel_footprints / voxel - 1) <= 0.15, (need * cfg.voxel_footprints, voxel)
    raw = planned_footprint(maps, working, cfg)
    assert raw * cfg.voxel_footprints > 1.3 * voxel, (raw * cfg.voxel_footprints, voxel)
    # another mesher plans nothing
    assert planned_footprint(maps, working, FusionConfig(mesher="poisson")) is None


def test_views_get_half_resolution_only_where_the_mesh_keeps_no_finer_detail(scene):
    """No memory budget: the voxel is 1.5 footprints of the full maps, so every view keeps full resolution. A
    budget that doubles the voxel: every view (all at one distance) gets half resolution, and says why."""
    renderer, views = scene
    maps = coarse_maps(renderer, views, background=(1.5, 6.0), relative=True, background_cost=0.3)
    working = {v.name: v for v in views}
    surface = confirmed_surface(maps, _sources(views), 2)
    choice = ViewChoice([v.name for v in views], len(views), "coarse depth coverage")
    frames = _true_frames(renderer, views)
    v0, _ = tsdf_voxel_size(frames, FusionConfig(memory_gb=0))
    need = planned_footprint(surface, working, FusionConfig(memory_gb=0))
    assert abs(need * 1.5 / v0 - 1) <= 0.1
    assert not mesh_levels(choice, working, maps, need).mesh_coarser
    faces = estimate_faces(frames, v0)
    cfg = FusionConfig(memory_gb=faces * MESH_BYTES_PER_FACE / 6 / 0.5 / 2 ** 30)  # voxel about 2.4x
    need = planned_footprint(surface, working, cfg)
    got = mesh_levels(choice, working, maps, need)
    assert set(got.mesh_coarser) == set(choice.chosen) and all(got.level(n) == 1 for n in choice.chosen)
    name = choice.chosen[0]
    assert 2 * map_footprint(maps[name][1], maps[name][3], working[name]) <= need
    assert got.resolution_reason(name).startswith("half: the fused mesh's voxel")
    assert got.to_dict()["half_resolution"] == len(views) and got.to_dict()["mesh_footprint"] == pytest.approx(need)


def test_views_get_a_quarter_of_the_resolution_where_the_mesh_keeps_no_finer_detail_than_that(scene):
    """A budget that makes the voxel about 5x the full maps' 1.5 footprints: with coarse maps at an eighth of the
    resolution every view gets a quarter (its quarter-resolution footprint within the voxel's need, its eighth
    not), says so and counts as such; with the coarse maps at a quarter, the views stop at half, one level finer
    than the coarse round (every chosen view gets a round with the geometric term)."""
    renderer, views = scene
    working = {v.name: v for v in views}
    choice = ViewChoice([v.name for v in views], len(views), "coarse depth coverage")
    frames = _true_frames(renderer, views)
    v0, _ = tsdf_voxel_size(frames, FusionConfig(memory_gb=0))
    faces = estimate_faces(frames, v0)
    cfg = FusionConfig(memory_gb=faces * MESH_BYTES_PER_FACE / 25 / 0.5 / 2 ** 30)
    eighth = coarse_maps(renderer, views, background=(1.5, 6.0), relative=True, background_cost=0.3, level=3)
    need = planned_footprint(confirmed_surface(eighth, _sources(views), 2), working, cfg)
    got = mesh_levels(choice, working, eighth, need)
    assert MESH_LEVEL_MAX == 2 and all(got.level(n) == 2 for n in choice.chosen), got.mesh_coarser
    name = choice.chosen[0]
    f0 = map_footprint(eighth[name][1], eighth[name][3], working[name])
    assert 4 * f0 <= need < 8 * f0
    assert got.resolution_reason(name).startswith("quarter: the fused mesh's voxel")
    assert got.to_dict()["quarter_resolution"] == len(views) and got.to_dict()["half_resolution"] == 0
    quarter = coarse_maps(renderer, views, background=(1.5, 6.0), relative=True, background_cost=0.3)
    capped = mesh_levels(choice, working, quarter, need)
    assert all(capped.level(n) == 1 for n in choice.chosen)
    assert "quarter_resolution" not in capped.to_dict()


def test_the_first_look_views_are_spread_around_the_capture():
    """A ring of 48 views: the first look's 12 are spread around it (no gap over twice the even spacing), the
    same each time; a capture under 40 views computes every coarse map at once."""
    ring = make_views(SynthConfig(views=48, rig="ring", width=64, height=48))
    picked = first_look_views(ring)
    assert len(picked) == 20 and picked == first_look_views(ring)  # at least FIRST_LOOK_MIN_VIEWS
    few = spread_views(ring, 12)
    ang = np.sort([np.degrees(np.arctan2(ring[k].center[1], ring[k].center[0])) % 360 for k in few])
    gaps = np.diff(np.concatenate([ang, ang[:1] + 360]))
    assert len(few) == 12 and gaps.max() <= 2 * 360 / 12 + 1e-6, gaps
    small = make_views(SynthConfig(views=30, rig="ring", width=64, height=48))
    assert first_look_views(small) == list(range(30))


def test_a_half_resolution_map_that_resolves_the_voxel_weighs_as_a_full_one(scene):
    """Fusion weights: a half-resolution frame weighs 0.25 where full-resolution maps set the voxel (its footprint
    twice the one the voxel asks for), 1 where the voxel asks for no finer footprint than its own (the mesh's budget
    coarsened the voxel), in between as the square of the ratio; a full-resolution frame always 1."""
    from dataclasses import replace

    from photorecon.depth.methods.patchmatch.solver import level_view
    from photorecon.fusion.frames import DEPTH_LEVEL, frame_footprint, resolution_weights

    renderer, views = scene
    full = _true_frames(renderer, views[:1])[0]
    lv = level_view(views[0], 1)
    half = DepthFrame(view=replace(lv, extra={DEPTH_LEVEL: 1}), depth=renderer.render(lv).depth.astype(np.float32))
    own = frame_footprint(half)
    assert own == pytest.approx(2 * frame_footprint(full), rel=0.05)
    assert resolution_weights([full, half]) == [1.0, 0.25]
    assert resolution_weights([full, half], own / 2) == [1.0, 0.25]
    assert resolution_weights([full, half], own) == [1.0, 1.0]
    assert resolution_weights([full, half], 0.75 * own)[1] == pytest.approx(0.5625)


def test_the_fusion_reads_each_depth_maps_level_from_the_depth_report(tmp_path):
    """``fusion.frames.depth_levels`` reads the resolution the depth stage gave each view in mvs_report.json: half
    is level 1, quarter level 2; full and names it does not know are the working resolution."""
    import json
    from types import SimpleNamespace

    from photorecon.fusion.frames import depth_levels

    per_view = {"a": {"resolution": "full"}, "b": {"resolution": "half"}, "c": {"resolution": "quarter"},
                "d": {"resolution": "eighth"}, "e": {}}
    (tmp_path / "mvs_report.json").write_text(json.dumps({"per_view": per_view}))
    assert depth_levels(SimpleNamespace(depth_dir=str(tmp_path))) == {"b": 1, "c": 2}
