"""Multi-view stereo on the CPU against rendered ground-truth depth."""
import json

import numpy as np
import pytest
import trimesh

from photorecon.cli import main
from photorecon.depth.mvs import MVSConfig, run_mvs
from photorecon.errors import NoDepthError
from photorecon.fusion import FusionConfig, fuse, load_frames
from photorecon.io.colmap_text import SparseModel
from photorecon.io.dataset import Dataset
from photorecon.mesh import clean
from photorecon.metrics import depth_metrics, mesh_metrics

# the plane sweep (--method sweep); PatchMatch has its own tests in tests/depth/test_patchmatch.py
CFG = MVSConfig(method="sweep", n_sources=4, n_depths=96, min_consistent=1, min_confidence=0.5)
SWEEP = dict(method="sweep", n_sources=4, min_confidence=0.5)


@pytest.fixture(scope="module")
def mvs_depth(blob_fusion, tmp_path_factory):
    out = tmp_path_factory.mktemp("mvs_depth")
    ds = Dataset.open(blob_fusion)
    rep = run_mvs(ds, out, CFG)
    return ds, out, rep


@pytest.mark.slow
def test_mvs_depth_accuracy_and_coverage(mvs_depth, blob_fusion):
    ds, out, rep = mvs_depth
    assert rep.views == len(ds.views) == rep["views"]
    # the typed result is what mvs_report.json holds
    assert json.loads((out / "mvs_report.json").read_text()) == json.loads(json.dumps(rep.to_dict()))
    assert set(rep.per_view) == {v.name for v in ds.views} and rep.method == "sweep"
    within, cover = [], []
    for v in ds.views:
        d = np.load(out / f"{v.name}.npy")
        conf = np.load(out / f"{v.name}.conf.npy")
        assert d.shape == (v.intrinsics.height, v.intrinsics.width)
        assert ((conf > 0) == (d > 0)).all() and conf.max() <= 1
        assert (out / f"{v.name}.png").is_file()
        m = depth_metrics(d, np.load(blob_fusion / "depth" / f"{v.name}.npy"))
        within.append(m["within"])
        cover.append(m["coverage"])
    # at 320x240 and 24 views (the benchmark measures 640x480, 40 views)
    assert np.mean(within) >= 0.9, np.mean(within)
    assert np.mean(cover) >= 0.5, np.mean(cover)


@pytest.mark.slow
def test_mvs_depth_fuses_to_the_surface(mvs_depth, blob_fusion):
    ds, out, _ = mvs_depth
    ds2 = Dataset.open(blob_fusion, depth_dir=out)
    mesh = clean(fuse(load_frames(ds2, FusionConfig()), FusionConfig(trunc_voxels=4), ds2.model.points))
    gt = trimesh.load(blob_fusion / "gt_mesh.ply", process=False)
    m = mesh_metrics(mesh, gt, n_samples=30_000)
    assert m.fscore >= 0.9, m


def test_mvs_skips_views_without_points(blob_small, tmp_path, caplog):
    ds = Dataset.open(blob_small)
    # drop every observation of one view: it has no sparse points
    name = ds.views[0].name
    uv, ids = ds.model.observations[name]
    ds.model.observations[name] = (uv[:0], ids[:0])
    rep = run_mvs(ds, tmp_path / "d", MVSConfig(**SWEEP, n_depths=32, min_consistent=1))
    assert name in rep["skipped"] and "no sparse points" in rep["skipped"][name]
    assert not (tmp_path / "d" / f"{name}.npy").exists()
    assert any(name in r.getMessage() for r in caplog.records)
    # no view sees a point -> one clear failure
    m = ds.model
    unseen = Dataset(ds.root, SparseModel(ds.views, m.points, m.colors, m.point_ids, m.errors, {}), ds.depth_dir)
    with pytest.raises(NoDepthError, match="no view yielded depth"):
        run_mvs(unseen, tmp_path / "e", MVSConfig(**SWEEP, n_depths=16))
    # a model without any sparse point (transforms.json), not triangulated: depth ranges come from the cameras
    bare = Dataset(ds.root, SparseModel(ds.views), ds.depth_dir)
    rep = run_mvs(bare, tmp_path / "f", MVSConfig(**SWEEP, n_depths=32, min_consistent=1, triangulate=False))
    assert rep["views"] >= len(ds.views) // 2


@pytest.mark.slow
def test_cli_mvs(blob_small, tmp_path):
    assert main(["-q", "mvs", str(blob_small), "-o", str(tmp_path / "d"), "--n-sources", "3", "--pm-levels", "1",
                 "--pm-iterations", "2", "--min-consistent", "1"]) == 0
    assert len(list((tmp_path / "d").glob("*.normal.npy"))) >= 6
    assert main(["-q", "mvs", str(blob_small), "-o", str(tmp_path / "s"), "--mvs", "sweep", "--n-depths", "32",
                 "--min-consistent", "1"]) == 0
    assert len(list((tmp_path / "s").glob("*.conf.npy"))) >= 6 and not list((tmp_path / "s").glob("*.normal.npy"))


@pytest.mark.parametrize("plane_px", [0.0, 10.0])
def test_compiled_consistency_filter_matches_numpy(blob_fusion, plane_px):
    """The multi-view filter's compiled count (pinhole cameras) equals the numpy one (any camera model) on true depth
    maps with 0.5% noise and holes: the same agreeing views per pixel and the same reprojection errors; with the
    plane test too (normals from the true depth's neighbours), where it confirms more pixels than the point test."""
    from photorecon.depth.config import DepthResult
    from photorecon.depth.filter import _consistency_count_any, _consistency_count_pinhole

    ds = Dataset.open(blob_fusion)
    rng = np.random.default_rng(1)
    res = {}
    for v in ds.views[:6]:
        d = np.load(blob_fusion / "depth" / f"{v.name}.npy").astype(np.float32)
        X = v.intrinsics.pixel_rays(v.intrinsics.pixel_grid().reshape(-1, 2)).reshape(d.shape + (3,)) * d[..., None]
        n = np.cross(np.gradient(X, axis=1), np.gradient(X, axis=0))
        n /= np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-12)
        n *= -np.sign(n[..., 2:3])  # towards the camera
        d *= (1 + 0.005 * rng.standard_normal(d.shape)).astype(np.float32)
        d[rng.random(d.shape) < 0.1] = 0
        res[v.name] = DepthResult(d, np.ones_like(d), v, [], n.astype(np.float32))
    for name, r in res.items():
        r.sources = [s for s in res if s != name]
    cfg = MVSConfig(reproj_px=1.0, rel_depth=0.004, plane_reproj_px=plane_px)
    for r in res.values():
        c1, e1, n1 = _consistency_count_any(r, res, cfg)
        c2, e2, n2 = _consistency_count_pinhole(r, res, cfg)
        assert c1.max() >= 3 and 0.1 < (c1 > 0).mean()  # the test means something: views agree, not everywhere
        assert (c1 != c2).mean() < 1e-4 and abs(n1 - n2) <= 1e-4 * n1, ((c1 != c2).sum(), n1, n2)
        assert abs(e1 / n1 - e2 / n2) < 1e-4
        if plane_px:
            c0 = _consistency_count_pinhole(r, res, MVSConfig(reproj_px=1.0, rel_depth=0.004, plane_reproj_px=0.0))[0]
            assert c2.sum() > 1.05 * c0.sum(), (c2.sum(), c0.sum())
