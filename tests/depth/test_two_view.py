"""Two views with known cameras (a stereo pair): depth and a mesh with the defaults; the left-right check."""
import json

import numpy as np
import pytest

from photorecon.cli import main
from photorecon.io.dataset import read_model
from photorecon.metrics import covisible, two_view_depth_scores


@pytest.fixture(scope="module")
def stereo_pair(tmp_path_factory):
    """A rectified pair of the room (one orientation, 0.3 apart along the image x axis) at 320x240."""
    from photorecon.testing import synth_scene

    return synth_scene(tmp_path_factory, "stereo_pair", scene="room", rig="stereo", width=320, height=240,
                       radius=2.6, elevation=35.0, baseline=0.3)


def test_stereo_rig_is_rectified(stereo_pair):
    """synth --rig stereo: one orientation, the second camera along the first's image x axis: a surface point
    has the same row in both images and disparity fx * baseline / depth."""
    a, b = read_model(stereo_pair / "sparse" / "0").views
    assert np.allclose(a.cam_from_world[:3, :3], b.cam_from_world[:3, :3])
    offset = a.cam_from_world[:3, :3] @ (b.center - a.center)
    assert offset == pytest.approx([0.3, 0, 0], abs=1e-9)
    from photorecon.cameras import project

    P = np.array([[0.1, -0.2, 0.3]])
    (ua, va), za = (x[0] for x in project(P, a.intrinsics, a.cam_from_world))
    (ub, vb), _ = (x[0] for x in project(P, b.intrinsics, b.cam_from_world))
    assert va == pytest.approx(vb) and ua - ub == pytest.approx(a.intrinsics.fx * 0.3 / za)


@pytest.mark.slow
def test_two_views_with_given_cameras_give_depth_and_a_mesh(stereo_pair, tmp_path):
    """reconstruct --poses on two views, defaults: the sparse points are triangulated from the pair's matches,
    the consistency filter asks for no more views than there are (exit 0, not 'no depth survived'), and the
    depth is within 1% of the truth on most pixels both views see."""
    out = tmp_path / "out"
    assert main(["-q", "reconstruct", str(stereo_pair / "images"), "-o", str(out),
                 "--poses", str(stereo_pair / "transforms.json")]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["depth"]["views"] == 2 and report["mesh"]["faces"] > 5000
    mvs = json.loads((out / "depth" / "mvs_report.json").read_text())
    assert mvs["triangulated"] and mvs["sparse_points"] >= 50
    views = read_model(stereo_pair / "sparse" / "0").views
    gt = [np.load(stereo_pair / "depth" / f"{v.name}.npy") for v in views]
    for a, b in ((0, 1), (1, 0)):
        d = np.load(out / "depth" / f"{views[a].name}.npy")
        s = two_view_depth_scores(d, gt[a], covisible(gt[a], views[a], gt[b], views[b]))
        assert s["pixels"] > 20000 and s["within"] > 0.8 and s["accuracy"] > 0.9


def test_left_right_check_drops_occluded_and_inconsistent_depths(stereo_pair):
    """The filter of a view checked against one other view is a left-right check: the true depth survives
    where both views see the surface; where the other view sees a nearer surface (occluded) and where the depth
    was made 3% wrong, it does not."""
    import dataclasses

    from photorecon.depth.mvs import DepthResult, MVSConfig, _filter_config, consistency_count

    views = read_model(stereo_pair / "sparse" / "0").views
    gt = [np.load(stereo_pair / "depth" / f"{v.name}.npy") for v in views]
    cov = covisible(gt[0], views[0], gt[1], views[1])
    occluded = (gt[0] > 0) & ~cov
    wrong = np.zeros_like(cov)
    wrong[100:140, 150:220] = True
    wrong &= cov
    assert occluded.sum() > 500 and wrong.sum() > 1000
    d = np.where(wrong, gt[0] * 1.03, gt[0]).astype(np.float32)
    ref = DepthResult(d, np.ones_like(d), views[0], [views[1].name])
    src = {views[1].name: DepthResult(gt[1].astype(np.float32), None, views[1], [views[0].name])}
    cfg = _filter_config(MVSConfig(), 1)
    assert cfg.reproj_px == MVSConfig().pair_reproj_px and cfg.plane_reproj_px == 0
    cnt, _, _ = consistency_count(ref, src, cfg)
    kept = cnt >= 1
    assert kept[cov & ~wrong].mean() > 0.97
    assert kept[wrong].mean() < 0.02
    assert kept[occluded].mean() < 0.1
    # with more views to check against, the filter is as configured
    assert _filter_config(MVSConfig(), 3) == MVSConfig()
    assert dataclasses.replace(MVSConfig(), pair_reproj_px=0) == _filter_config(MVSConfig(pair_reproj_px=0), 1)
