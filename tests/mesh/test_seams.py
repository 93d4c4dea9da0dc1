"""Seam levelling of the texture (photorecon/mesh/seams.py): the least-squares offsets on hand-made cases, their
rasterisation into the atlas, and texturing photos with per-view exposure differences (seam steps, colours
against the rendered truth)."""
import numpy as np
import pytest
import trimesh

from photorecon.io.dataset import Dataset
from photorecon.mesh.seams import apply_offsets, seam_steps, solve_offsets
from photorecon.mesh.texture import TextureConfig, texture_mesh
from photorecon.render import Renderer
from photorecon.synthetic import SynthConfig, make_views


def _path_edges(ids):
    return np.stack([ids[:-1], ids[1:]], 1)


def test_solver_recovers_a_known_offset_between_two_charts():
    """Two charts of 20 vertices each (paths), their first 5 vertices on a seam where chart B is 30 (red), -12
    (green), 0 (blue) brighter than chart A: the offsets close the step exactly, are constant over each chart
    (nothing else pulls them) and split it evenly (the smallest offsets)."""
    A, B = np.arange(20), np.arange(20, 40)
    seam_a, seam_b = A[:5], B[:5]
    diff = np.tile([30.0, -12.0, 0.0], (5, 1))  # f_b - f_a
    g = solve_offsets(40, seam_a, seam_b, diff, np.concatenate([_path_edges(A), _path_edges(B)]), rtol=1e-8)
    assert np.allclose(g[A], [15.0, -6.0, 0.0], atol=0.01), g[A]
    assert np.allclose(g[B], [-15.0, 6.0, 0.0], atol=0.01), g[B]
    # an isolated third chart with no seam stays at 0
    g3 = solve_offsets(45, seam_a, seam_b, diff, np.concatenate([_path_edges(A), _path_edges(B),
                                                                 _path_edges(np.arange(40, 45))]), rtol=1e-8)
    assert np.allclose(g3[:40], g, atol=0.01) and not g3[40:].any()


def test_solver_spreads_a_varying_step_smoothly():
    """A step that grows along the seam (0 to 40): the offsets follow it at the seam (within 1 unit) and fall off
    smoothly into a 10 x 10 grid chart, no neighbour differing by more than the seam's own change per vertex."""
    n = 10
    grid = np.arange(n * n).reshape(n, n)
    edges = np.concatenate([np.stack([grid[:, :-1].ravel(), grid[:, 1:].ravel()], 1),
                            np.stack([grid[:-1].ravel(), grid[1:].ravel()], 1)])
    other = n * n + np.arange(n)  # chart B: one column of 10 vertices along grid column 0
    edges = np.concatenate([edges, _path_edges(other)])
    step = np.linspace(0, 40, n)
    diff = np.stack([step, step, step], 1)
    g = solve_offsets(n * n + n, grid[:, 0], other, diff, edges, rtol=1e-8)
    closed = g[grid[:, 0]] - g[other] - diff
    assert np.abs(closed).max() < 1.0, closed
    d = np.abs(np.diff(g[grid.ravel()].reshape(n, n, 3), axis=1)).max()
    assert d <= 40 / (n - 1) + 1e-6, d


def test_offsets_are_interpolated_over_triangles_and_extended_into_the_padding():
    """One triangle in a 12 x 12 rectangle at (3, 2) of a grey atlas, offsets +30 / -30 / 0 at its corners: texels
    inside take the barycentric blend, texels outside the nearest covered texel's value, texels outside the
    rectangle are left as they were."""
    atlas = np.full((20, 20, 3), 128, np.uint8)
    tex = np.array([[[4.0, 3.0], [13.0, 3.0], [4.0, 12.0]]])  # atlas texel coordinates
    offsets = np.array([[30.0] * 3, [-30.0] * 3, [0.0] * 3])
    changed = apply_offsets(atlas, offsets, np.array([[0, 1, 2]]), tex, np.array([0]), np.array([[3, 2]]),
                            np.array([[12, 12]]))
    assert changed == 1
    a = atlas[..., 0].astype(float) - 128
    assert a[3, 4] == 30 and a[3, 13] == -30 and a[12, 4] == 0  # the corners
    assert abs(a[6, 7] - (30 * (1 - 3 / 9 - 3 / 9) - 30 * 3 / 9)) <= 0.5  # inside: barycentric
    assert a[2, 3] == a[3, 4]  # the rectangle's corner texel: nearest covered texel (the triangle's corner)
    assert (a[:2] == 0).all() and (a[:, :3] == 0).all() and (a[14:] == 0).all() and (a[:, 15:] == 0).all()


@pytest.fixture(scope="module")
def gain_scene(blob_small):
    """blob_small's true surface and photos scaled by random per-view, per-channel gains (0.8-1.2)."""
    ds = Dataset.open(blob_small)
    mesh = trimesh.load(blob_small / "gt_mesh.ply", process=False)
    views = ds.views
    rng = np.random.default_rng(0)
    gain = rng.uniform(0.8, 1.2, (len(views), 1)) * rng.uniform(0.95, 1.05, (len(views), 3))

    def images(k):
        return np.clip(ds.image(views[k]).astype(np.float32) * gain[k] + 0.5, 0, 255).astype(np.uint8)

    return ds, mesh, images


def _held_out_errors(tex, mesh):
    """Mean absolute RGB error (0-255) and PSNR over the object's pixels of unlit renders of ``tex`` from
    4 views texturing never used, against blob_small's true renders."""
    truth = Renderer(mesh, seed=3)
    r = Renderer(tex.mesh, unlit=True)
    held = make_views(SynthConfig(rig="ring", views=4, elevation=35, width=160, height=120, seed=11, jitter_deg=3))
    err = []
    for v in held:
        t = truth.render(v)
        err.append(r.render(v).rgb[t.mask].astype(float) - t.rgb[t.mask])
    err = np.concatenate(err)
    return float(np.abs(err).mean()), float(10 * np.log10(255.0 ** 2 / (err ** 2).mean()))


def test_levelling_halves_the_seam_steps_of_photos_with_exposure_differences(gain_scene):
    """Exposure correction off, so every seam between photos of different gains shows: with levelling the
    colour step across chart borders, beyond the texture's own change across edges inside charts, is at most
    half of that without (measured: 10.5 -> 1.1 RGB units), and the held-out renders are closer to the truth."""
    ds, mesh, images = gain_scene
    res = {}
    for lev in (False, True):
        tex = texture_mesh(mesh, ds.views, images, TextureConfig(atlas_size=1024, exposure=False, seam_levelling=lev),
                           ds.mask)
        res[lev] = seam_steps(tex.mesh, tex.atlas, tex.labels), _held_out_errors(tex, mesh)
    (s0, (e0, p0)), (s1, (e1, p1)) = res[False], res[True]
    assert s0["seam_pairs"] > 500 and s0["excess"] > 5.0, s0  # the seams show without levelling
    assert s1["excess"] <= 0.5 * s0["excess"], (s0, s1)
    assert abs(s1["interior"] - s0["interior"]) < 1.0, (s0, s1)  # the texture inside charts keeps its detail
    assert e1 < e0 and p1 > p0 + 3.0, (e0, e1, p0, p1)  # measured 25.6 -> 32.4 dB


def test_levelled_colours_stay_close_to_the_truth(gain_scene):
    """With the defaults (exposure correction and levelling), the held-out renders of the textured true surface
    match the true renders: mean absolute error under 6 RGB units (0-255) and PSNR within 0.5 dB of texturing
    without levelling (measured 36.7 and 36.8 dB)."""
    ds, mesh, images = gain_scene
    tex = texture_mesh(mesh, ds.views, images, TextureConfig(atlas_size=1024), ds.mask)
    assert tex.info["seam_levelling"]["seam_vertices"] > 0
    err, psnr = _held_out_errors(tex, mesh)
    plain = texture_mesh(mesh, ds.views, images, TextureConfig(atlas_size=1024, seam_levelling=False), ds.mask)
    err0, psnr0 = _held_out_errors(plain, mesh)
    assert err < 6.0 and psnr > 30.0, (err, psnr)
    assert psnr > psnr0 - 0.5 and err < err0 + 0.3, (err, err0, psnr, psnr0)


def test_local_blending_meets_at_the_mean_on_the_seam_and_fades_out():
    """Two triangles sharing an edge, each in its own rectangle of a flat colour (100 and 160): after blending
    with a 2-texel strip, texels on the seam take the mean (130) on both sides, a texel 1 texel away moves a
    quarter of the step, texels 2 or more texels away and outside the rectangles keep their colour."""
    from photorecon.mesh.seams import blend_seams

    atlas = np.zeros((20, 45, 3), np.uint8)
    atlas[:, :20] = 100
    atlas[:, 20:40] = 160
    faces = np.array([[0, 1, 2], [1, 0, 3]])
    tex = np.array([[[10.0, 2.0], [10.0, 17.0], [3.0, 10.0]],  # face 0 in rectangle 0, seam at x = 10
                    [[25.0, 17.0], [25.0, 2.0], [32.0, 10.0]]])  # face 1 in rectangle 1, seam at x = 25
    n = blend_seams(atlas, faces, np.array([0, 1]), np.array([[0, 1]]), np.array([[0, 1]]), tex, np.array([0, 1]),
                    np.array([[0, 0], [20, 0]]), np.array([[20, 20], [20, 20]]), width=2.0)
    a = atlas[..., 1].astype(int)
    assert n > 0
    assert a[10, 10] == 130 and a[10, 25] == 130  # on the seam: the mean
    assert a[10, 9] == 115 and a[10, 11] == 115 and a[10, 26] == 145 and a[10, 24] == 145  # 1 texel away
    assert a[10, 7] == 100 and a[10, 28] == 160 and a[19, 10] == 100  # 2+ texels away (beyond the edge's end too)
    assert (a[:, 40:] == 0).all()


def test_a_step_only_a_few_seam_vertices_show_is_not_levelled():
    """Between charts 0 and 1 the step is 30 +- 1 at ten vertices and 90 at one (a silhouette in one photo); between
    charts 0 and 2 it is -20 +- 1 at five: only the 90 is left out."""
    from photorecon.mesh.seams import seam_inliers

    rng = np.random.default_rng(0)
    group = np.r_[np.zeros(11, int), np.ones(5, int)]
    diff = np.r_[30 + rng.uniform(-1, 1, 10), 90.0, -20 + rng.uniform(-1, 1, 5)][:, None] * np.ones(3)
    ok = seam_inliers(group, diff)
    assert ok.tolist() == [True] * 10 + [False] + [True] * 5
