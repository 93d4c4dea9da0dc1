"""A large capture's first look: the coarse depth maps that choose the depth views, fused into a mesh and a
picture in OUT/first_look while the full depth maps are computed, removed once the result is complete."""
import logging

import numpy as np
import pytest
import trimesh

from conftest import coarse_maps
from photorecon.fusion.first_look import first_look_mesh
from photorecon.metrics import mesh_metrics
from photorecon.render import Renderer
from photorecon.synthetic import SynthConfig, make_scene, make_views, normalize_mesh


def test_first_look_of_noisy_coarse_maps_lies_on_the_surface():
    """40 views around the blob at 320x240, coarse maps at 80x60 with 5% of the surface's pixels wrong (at a
    random depth but matched well): the first look covers the surface (F-score at 1% of the diagonal >= 0.8,
    measured 0.997) and 95% of it lies within 1% of the diagonal of the truth; the badly matched background
    never enters it."""
    gt = normalize_mesh(make_scene("blob"))[0]
    renderer = Renderer(gt)
    views = make_views(SynthConfig(views=40, rig="sphere", width=320, height=240))
    mesh = first_look_mesh(coarse_maps(renderer, views, wrong=0.05, background=(0.5, 3.0)))
    m = mesh_metrics(mesh, gt, n_samples=20_000)
    assert m.fscore >= 0.8 and m.precision >= 0.95, m
    # bounded by the truth: nothing from the background's depths
    lo, hi = gt.bounds
    diag = float(np.linalg.norm(hi - lo))
    assert np.all(mesh.vertices >= lo - 0.05 * diag) and np.all(mesh.vertices <= hi + 0.05 * diag)


def test_first_look_needs_two_maps_to_agree():
    """One map alone never makes a first look: a surface seen by a single view has weight 1 < 2 everywhere."""
    from photorecon.errors import EmptyMeshError, NoDepthError

    renderer = Renderer(normalize_mesh(make_scene("blob"))[0])
    views = make_views(SynthConfig(views=12, rig="ring", width=160, height=120))
    maps = coarse_maps(renderer, views[:1], wrong=0.0, background=(0.5, 3.0))
    with pytest.raises((EmptyMeshError, NoDepthError)):
        first_look_mesh(maps)


@pytest.mark.slow
def test_first_look_of_patchmatch_coarse_maps_lies_on_the_surface(tmp_path):
    """The coarse maps PatchMatch's first round gives for 30 views of the blob at 256x192 (64x48 maps), handed to
    ``run_mvs``'s ``on_coarse`` before any full depth map: their first look lies on the surface and covers it
    (precision and recall at 1% of the diagonal 0.970 and 0.982 measured)."""
    from photorecon.depth.mvs import MVSConfig, run_mvs
    from photorecon.io.dataset import Dataset
    from photorecon.synthetic import synthesize

    class Enough(Exception):
        pass

    data = tmp_path / "data"
    synthesize(SynthConfig(scene="blob", rig="sphere", views=30, width=256, height=192, points=1500, seed=3), data)
    got = {}

    def first_look(maps):
        got["maps"] = maps
        got["written"] = list((tmp_path / "depth").glob("*.npy"))
        raise Enough  # the full depth maps are not needed here

    with pytest.raises(Enough):
        run_mvs(Dataset.open(data), tmp_path / "depth", MVSConfig(depth_views="coarse"), on_coarse=first_look)
    assert len(got["maps"]) >= 20 and not got["written"]
    view, depth, normal, cost = next(iter(got["maps"].values()))
    assert depth.shape == cost.shape == (48, 64) and view.intrinsics.size == (64, 48)
    m = mesh_metrics(first_look_mesh(got["maps"]), trimesh.load(data / "gt_mesh.ply", process=False), n_samples=10_000)
    assert m.precision >= 0.9 and m.recall >= 0.9, m


@pytest.mark.slow
def test_reconstruct_shows_a_first_look_while_depth_runs_then_removes_it(tmp_path, monkeypatch, caplog):
    """reconstruct with given cameras on 30 views of the blob at 128x96 (``--depth-views coarse``): the first look
    (mesh.ply and preview.png in OUT/first_look) exists before the first full depth map is written, is said in the
    log, and is gone once the run is complete."""
    from photorecon import pipeline
    from photorecon.depth.mvs import MVSConfig
    from photorecon.pipeline import ReconstructConfig, StageConfigs, reconstruct
    from photorecon.synthetic import synthesize

    data = tmp_path / "data"
    synthesize(SynthConfig(scene="blob", rig="sphere", views=30, width=128, height=96, points=1500, seed=3), data)
    seen = {}
    original = pipeline.first_look_stage

    def spy(maps, ds, layout, fusion_cfg):
        original(maps, ds, layout, fusion_cfg)
        seen["files"] = sorted(p.name for p in layout.first_look.iterdir())
        seen["mesh"] = trimesh.load(layout.first_look / "mesh.ply", process=False)
        seen["depth maps"] = list((layout.root / ".depth.partial").glob("*.npy")) if (layout.root / ".depth.partial").exists() else []
        seen["maps"] = len(maps)

    monkeypatch.setattr(pipeline, "first_look_stage", spy)
    cfgs = StageConfigs(ReconstructConfig(poses=str(data / "transforms.json"), formats="ply"),
                        mvs=MVSConfig(depth_views="coarse"))
    out = tmp_path / "out"
    with caplog.at_level(logging.INFO, logger="photorecon"):
        reconstruct(data / "images", out, cfgs)
    assert seen["files"] == ["mesh.ply", "preview.png"] and seen["maps"] >= 20
    assert not [p for p in seen["depth maps"] if p.name.count(".") == 1], "the first look comes before any depth map"
    assert len(seen["mesh"].faces) > 500
    assert any("first look: " in r.getMessage() for r in caplog.records)
    assert not (out / "first_look").exists() and (out / "mesh.ply").exists()
