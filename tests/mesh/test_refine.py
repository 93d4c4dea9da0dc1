"""Photometric mesh refinement (photorecon.mesh.refine): synthetic truth meshes rendered by photorecon.render."""
import json

import numpy as np
import pytest
import trimesh

from photorecon.cameras import Intrinsics, View, look_at_views, sphere_positions
from photorecon.cli import main
from photorecon.mesh import raycasting_scene
from photorecon.mesh.refine import RefineConfig, patch_scores, refine_mesh, subdivide_long, tangents, vertex_normals
from photorecon.mesh.refine_views import _level, facing, select_views, visibility
from photorecon.metrics import mesh_metrics
from photorecon.render import Renderer, SolidNoise


def _views(n, width, height, radius=3.0, hemisphere=False, fov=50.0):
    intr = Intrinsics.from_fov(width, height, fov)
    pos = sphere_positions(n, radius, hemisphere=hemisphere)
    return [View(f"v{i}", intr, T) for i, T in enumerate(look_at_views(pos, (0, 0, 0)))]


def _grey(mesh, views, plain=False):
    r = Renderer(mesh, 0, plain=plain)
    return [r.render(v).rgb.mean(2).astype(np.float32) / 255 for v in views]


def _distance(mesh, truth):
    import open3d as o3d

    return raycasting_scene(truth).compute_distance(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32))).numpy()


def _blob(subdivisions):
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    n = SolidNoise(11, base_freq=1.2, octaves=3, channels=1)
    return trimesh.Trimesh(m.vertices * (1 + 0.25 * (n(m.vertices)[:, 0] - 0.5))[:, None], m.faces, process=False)


def test_refinement_pulls_a_perturbed_mesh_back_to_the_truth():
    truth = _blob(5)  # edges about 2.5 pixel footprints long
    views = _views(14, 160, 120)
    grey = _grey(truth, views)
    fp = 2.0 / views[0].intrinsics.fx  # a pixel's footprint on the surface, about 2 units out
    n = vertex_normals(np.asarray(truth.vertices), np.asarray(truth.faces))
    # a smooth offset field of up to ~1.5 footprints (no smoothing alone undoes it) plus a 0.5-footprint inflation
    field = SolidNoise(5, base_freq=2.0, octaves=2, channels=1)(truth.vertices)[:, 0]
    pushed = (2.0 * (2 * field - 1) + 0.5) * fp
    start = trimesh.Trimesh(truth.vertices + pushed[:, None] * n, truth.faces, process=False)
    before = _distance(start, truth).mean()
    assert before > 0.4 * fp
    out, info = refine_mesh(start, views, grey, RefineConfig(refine=True), subdivide=False)
    after = _distance(out, truth).mean()
    assert after < before / 3, (before / fp, after / fp)
    assert len(out.vertices) == len(truth.vertices) and np.array_equal(out.faces, truth.faces)
    assert info["mean_displacement"] == pytest.approx(np.linalg.norm(out.vertices - start.vertices, axis=1).mean())
    assert info["photo_weighted_fraction"] > 0.8


def test_a_flat_textureless_region_does_not_drift():
    # a plane facing a hemisphere of cameras, textured (random vertex colours) except for a plain disc in the
    # middle: the photos say nothing about the disc's depth, and its vertices must stay where they are
    g = np.linspace(-1.5, 1.5, 81)
    x, y = np.meshgrid(g, g)
    verts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    idx = np.arange(x.size).reshape(x.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    disc = np.hypot(verts[:, 0], verts[:, 1]) < 0.5
    grey = np.where(disc, 150, np.random.default_rng(1).integers(20, 235, len(verts)))
    plane = trimesh.Trimesh(verts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]), process=False,
                            vertex_colors=np.stack([grey] * 3 + [np.full(len(grey), 255)], 1).astype(np.uint8))
    views = _views(8, 160, 120, hemisphere=True)
    out, info = refine_mesh(plane, views, _grey(plane, views), RefineConfig(refine=True), subdivide=False)
    fp = 3.0 / views[0].intrinsics.fx
    z = np.asarray(out.vertices)[:, 2]
    # the disc's middle stays put; within a few footprints of its rim the patches reach the texture and the
    # vertices there follow it by up to ~0.7 footprint
    assert np.abs(z[np.hypot(verts[:, 0], verts[:, 1]) < 0.3]).mean() < 0.05 * fp
    assert np.abs(z[disc]).mean() < 0.15 * fp and np.abs(z[disc]).max() < fp, np.abs(z[disc]).max() / fp
    inner = np.abs(verts[:, :2]).max(1) < 1.0  # the textured ring around the disc, away from the plane's edge
    assert np.abs(z[inner & ~disc]).mean() < 0.1 * fp


def _scores_numpy(pos, nrm, t1, t2, spacing, step, offsets, sel, P, imgs, sizes, half, min_std):
    """patch_scores, one sample at a time in plain numpy."""
    def sample(i, X):
        x = P[i] @ np.append(X, 1.0)
        if x[2] <= 0:
            return np.nan
        u, v = x[0] / x[2], x[1] / x[2]
        w, h = sizes[i]
        if not (0 <= u <= w - 1 and 0 <= v <= h - 1):
            return np.nan
        u0, v0 = min(int(u), w - 2), min(int(v), h - 2)
        a, b = u - u0, v - v0
        im = imgs[i]
        return ((1 - a) * (1 - b) * im[v0, u0] + a * (1 - b) * im[v0, u0 + 1] + (1 - a) * b * im[v0 + 1, u0]
                + a * b * im[v0 + 1, u0 + 1])

    out = np.full((len(pos), len(offsets)), np.nan)
    grid = [(a, b) for a in range(-half, half + 1) for b in range(-half, half + 1)]
    for vi in range(len(pos)):
        if sel[vi, 0] < 0 or sel[vi, 1] < 0:
            continue
        for ci, o in enumerate(offsets):
            X = [pos[vi] + o * step[vi] * nrm[vi] + (a * t1[vi] + b * t2[vi]) * spacing[vi] for a, b in grid]
            ref = np.array([sample(sel[vi, 0], p) for p in X])
            if not np.isfinite(ref).all() or ref.std() < min_std:
                continue
            zs = []
            for j in sel[vi, 1:]:
                if j < 0:
                    break
                other = np.array([sample(j, p) for p in X])
                if not np.isfinite(other).all():
                    continue
                r, q = ref - ref.mean(), other - other.mean()
                den = np.sqrt((r * r).sum() * (q * q).sum())
                zs.append(max((r * q).sum() / den, 0.0) if (q * q).sum() > 1e-12 else 0.0)
            if zs:
                out[vi, ci] = np.mean(zs)
    return out


def test_kernel_matches_a_plain_numpy_version():
    rng = np.random.default_rng(0)
    views = _views(4, 48, 36, radius=2.5)
    imgs = np.zeros((4, 36, 48), np.float32)
    imgs[:] = rng.random((4, 36, 48))
    imgs[2, :30, :40] = rng.random((30, 40))  # view 2 is smaller: its image holds [:30, :40]
    sizes = np.array([(48, 36), (48, 36), (40, 30), (48, 36)], np.int32)
    P = np.array([v.intrinsics.K @ v.cam_from_world[:3, :4] for v in views])
    pos = rng.normal(size=(7, 3)) * 0.3
    nrm = rng.normal(size=(7, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    t1, t2 = tangents(nrm)
    spacing = np.full(7, 0.04)
    step = np.full(7, 0.02)
    offsets = np.linspace(-1, 1, 5)
    sel = np.array([[0, 1, 2, 3], [1, 0, -1, -1], [2, 3, 0, -1], [3, -1, -1, -1], [0, 2, 1, 3], [-1, -1, -1, -1],
                    [1, 2, 3, 0]], np.int32)
    fast = patch_scores(pos, nrm, t1, t2, spacing, step, offsets, sel, P, imgs, sizes, 1, 0.01)
    slow = _scores_numpy(pos, nrm, t1, t2, spacing, step, offsets, sel, P, imgs, sizes, 1, 0.01)
    assert np.isfinite(slow).sum() >= 15  # the case exercises scored and unscored candidates alike
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(slow))
    np.testing.assert_allclose(fast[np.isfinite(slow)], slow[np.isfinite(slow)], atol=1e-5)


def test_views_and_subdivision():
    cos = np.array([[0.9, 0.0, 0.5], [0.3, 0.0, 0.7], [0.0, 0.0, 0.6]], np.float32)  # (views, vertices)
    assert select_views(cos, 2).tolist() == [[0, 1], [-1, -1], [1, 2]]
    tri = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    out = subdivide_long(tri, 0.3)
    e = out.edges_unique_length
    assert e.max() <= 0.3 and len(out.faces) == 4 ** 3 and out.area == pytest.approx(0.5)
    assert len(subdivide_long(tri, 0.3, max_vertices=20).faces) == 16  # 3 -> 6 -> 15 vertices; 63 is over the cap


def test_facing_repeats_visibility_on_the_pairs_it_found_unoccluded():
    """The rounds after a level's first reuse its occlusion test and redo only the facing test: on the pairs
    found seen, the same cosines and depths as ``visibility``; elsewhere 0, as there."""
    mesh = _blob(3)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # area-weighted normals, as numpy sums them
    ref = np.zeros_like(v)
    for c in range(3):
        np.add.at(ref, f[:, c], fn)
    n = vertex_normals(v, f)
    np.testing.assert_allclose(n, ref / np.linalg.norm(ref, axis=1, keepdims=True), atol=1e-12)
    views = _views(6, 80, 60)
    lvl = _level(views, [np.zeros((60, 80), np.float32)] * len(views), 1.0)
    cos, depth = visibility(v, f, n, views, lvl)
    seen = cos > 0
    assert 0.2 < seen.mean() < 0.8  # some pairs facing away or hidden, some seen
    cos2, depth2 = facing(v, n, np.array([w.center for w in views]), lvl.P, seen, 0.2)
    np.testing.assert_allclose(cos2, cos, atol=1e-6)
    np.testing.assert_allclose(depth2, depth, rtol=1e-6)
    # moved normals: a pair whose vertex now faces away from the camera drops out
    cos3, _ = facing(v, -n, np.array([w.center for w in views]), lvl.P, seen, 0.2)
    assert not cos3.any()


@pytest.mark.slow
def test_reconstruct_refine_option(blob_small, tmp_path):
    out = tmp_path / "out"
    assert main(["-q", "reconstruct", str(blob_small / "images"), "-o", str(out), "--poses",
                 str(blob_small / "transforms.json"), "--depth", str(blob_small / "depth"), "--refine",
                 "--refine-levels", "1", "--refine-iterations", "2"]) == 0
    rep = json.loads((out / "report.json").read_text())
    r = rep["mesh"]["refine"]
    assert rep["parameters"]["refine"]["refine"] is True
    fp = 2.0 / (0.5 * 160 / np.tan(np.radians(25)))
    assert 0 < r["mean_displacement"] < 2 * fp and r["seconds"] > 0
    mesh = trimesh.load(out / "mesh.ply", process=False)
    assert len(mesh.vertices) == rep["mesh"]["vertices"] == r["vertices"]
    m = mesh_metrics(mesh, trimesh.load(blob_small / "gt_mesh.ply", process=False), n_samples=30_000)
    assert m.fscore >= 0.97, m


def test_relief_scene_has_bumps_below_a_footprint():
    from photorecon.synthetic import make_scene

    m = make_scene("relief")
    h = np.linalg.norm(m.vertices, axis=1) - 1.0  # height above the unit sphere
    assert h.min() > -1e-9 and h.max() > 0.0018
    assert (h > 0.0029).mean() < 0.02  # under one footprint (0.0029 at the default rig) but where bumps overlap
    assert 0.05 < (h > 0.001).mean() < 0.4  # bumps, not a uniformly inflated sphere
