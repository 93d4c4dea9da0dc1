"""Planar prior (photorecon/depth/planar.py) against rendered ground truth: a textured plane with a flat,
textureless square in its middle, where photometric matching has no evidence."""
import numpy as np
import pytest

from photorecon.depth.mvs import MVSConfig, _gray, run_mvs
from photorecon.depth.planar import prior_planes, textureless
from photorecon.io.dataset import Dataset
from photorecon.metrics import depth_metrics
from photorecon.synthetic import SynthConfig, synthesize
from photorecon.testing import multiscale_texture, textured_plane

FAST = dict(n_sources=4, pm_levels=2, pm_iterations=4, pm_fine_iterations=2, pm_final_iterations=1)


def test_prior_planes_recover_a_plane_from_its_support_points():
    """Depths of a slanted plane with a hole of high cost: the prior fills the hole with the plane's depth."""
    H, W = 60, 80
    K = np.array([[70.0, 0, 39.5], [0, 70.0, 29.5], [0, 0, 1]])
    Kinv = np.linalg.inv(K)
    n = np.array([0.3, -0.5, -0.8]) / np.linalg.norm([0.3, -0.5, -0.8])  # facing the camera
    ys, xs = np.mgrid[0:H, 0:W]
    rays = np.stack([(xs - 39.5) / 70, (ys - 29.5) / 70, np.ones((H, W))], -1)
    depth = (-2.0 / (rays @ n)).astype(np.float32)  # n . X = -2
    normal = np.broadcast_to(n, (H, W, 3)).astype(np.float32).copy()
    cost = np.full((H, W), 0.1, np.float32)
    hole = (slice(22, 38), slice(32, 48))
    cost[hole] = 1.0
    truth = depth.copy()
    depth[hole] = 5.0  # wrong
    pd, pn, st = prior_planes(depth, normal, cost, Kinv, want=cost > 0.3, cell=4)
    assert st["pixels"] == 16 * 16
    np.testing.assert_allclose(pd[hole], truth[hole], rtol=1e-5)
    assert np.all(pn[hole] @ n > 0.9999)
    assert not pd[cost <= 0.3].any()  # only the wanted pixels


@pytest.fixture(scope="module")
def flat_square(tmp_path_factory):
    """A 4x4 plane with a rich texture and a flat grey square (1/4 of its side) in the middle."""
    root = tmp_path_factory.mktemp("flat_square")
    n = 256
    img = multiscale_texture(n, (4, 8, 16, 32))
    c = slice(3 * n // 8, 5 * n // 8)
    img[c, c] = 0.55
    textured_plane(root / "plane.glb", (np.clip(img, 0, 1) * 255).astype(np.uint8))
    synthesize(SynthConfig(mesh=str(root / "plane.glb"), rig="hemisphere", views=10, width=200, height=150,
                           radius=2.2, points=1500, seed=2), root / "data", overwrite=True)
    return root / "data"


@pytest.mark.slow
def test_planar_prior_fills_a_textureless_square_at_the_same_accuracy(flat_square, tmp_path):
    ds = Dataset.open(flat_square)
    scores = {}
    for prior in (False, True):
        out = tmp_path / f"prior{int(prior)}"
        run_mvs(ds, out, MVSConfig(planar_prior=prior, **FAST))
        flat_cov, flat_hit, within, cover = [], [], [], []
        for v in ds.views:
            gt = np.load(flat_square / "depth" / f"{v.name}.npy")
            p = out / f"{v.name}.npy"
            d = np.load(p) if p.is_file() else np.zeros_like(gt)
            m = depth_metrics(d, gt)
            within.append(m["within"])
            cover.append(m["coverage"])
            flat = (gt > 0) & textureless(_gray(ds.image(v)), 5, 0.004)
            got = flat & (d > 0)
            flat_cov.append(got.sum() / max(flat.sum(), 1))
            flat_hit.append((np.abs(d[got] - gt[got]) < 0.01 * gt[got]).sum())
        scores[prior] = dict(flat_cov=float(np.mean(flat_cov)), within=float(np.mean(within)),
                             cover=float(np.mean(cover)), flat_hits=int(np.sum(flat_hit)))
    base, prior = scores[False], scores[True]
    # without the prior the flat square is (almost) empty; with it a good part of it is filled ...
    assert base["flat_cov"] < 0.05, scores
    assert prior["flat_cov"] > base["flat_cov"] + 0.1, scores
    assert prior["flat_hits"] > 5 * max(base["flat_hits"], 1), scores  # ... with the right depths
    # ... and the plane as a whole gains coverage at the same accuracy
    assert prior["cover"] > base["cover"], scores
    assert prior["within"] > base["within"] - 0.01, scores
