"""Hole filling after the geometric filter (photorecon.depth.fill): a rectified pair rendered from planes with
a procedural texture; the reference depth map gets holes, the other view's depth map is the truth."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage as ndi

from photorecon.cameras import Intrinsics, View
from photorecon.depth.config import DepthResult, MVSConfig
from photorecon.depth.fill import FILL_PASSES, fill_holes, fillable_holes, photometric_error

W, H, F, B = 96, 72, 80.0, 0.3  # image size, focal length, baseline (x)
INTR = Intrinsics(W, H, F, F, (W - 1) / 2, (H - 1) / 2)


def _view(name: str, cx: float) -> View:
    T = np.eye(4)
    T[0, 3] = -cx  # camera centre at (cx, 0, 0), looking along +z
    return View(name, INTR, T)


def _texture(X: np.ndarray, Y: np.ndarray, flat: tuple | None) -> np.ndarray:
    g = 0.5 + 0.2 * np.sin(23 * X + 3 * Y) + 0.15 * np.sin(17 * Y - 5 * X) + 0.1 * np.sin(41 * X * Y + 29 * Y)
    if flat is not None:  # a textureless patch: (x0, x1, y0, y1) in world units
        x0, x1, y0, y1 = flat
        g = np.where((X > x0) & (X < x1) & (Y > y0) & (Y < y1), 0.5, g)
    return g.astype(np.float32)


def _render(center_x: float, planes: list[tuple[np.ndarray, float, tuple]], flat=None):
    """Depth, normals (camera frame) and grey image of a camera at (center_x, 0, 0): the nearest of ``planes``
    (normal n, offset c: n . X = c; x-extent (xmin, xmax) of the plane in world units, or None)."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    d = np.stack([(u - INTR.cx) / F, (v - INTR.cy) / F, np.ones_like(u, float)], -1)  # rays, z = 1
    C = np.array([center_x, 0.0, 0.0])
    depth = np.full((H, W), np.inf)
    normal = np.zeros((H, W, 3))
    for n, c, xr in planes:
        t = (c - n @ C) / (d @ n)
        X = C + d * t[..., None]
        ok = t > 0
        if xr is not None:
            ok &= (X[..., 0] >= xr[0]) & (X[..., 0] < xr[1])
        nearer = ok & (t < depth)
        depth[nearer] = t[nearer]
        normal[nearer] = -n / np.linalg.norm(n)
    X = C + d * depth[..., None]
    noise = np.random.default_rng(int(center_x * 100)).normal(0, 0.005, (H, W))  # camera noise
    img = (_texture(X[..., 0], X[..., 1], flat) + noise).astype(np.float32)
    return depth.astype(np.float32), normal.astype(np.float16), img


TILTED = (np.array([0.2, 0.1, 1.0]), 2.0, None)  # one slanted plane, about 2 away


def _fill(planes, hole: np.ndarray, flat=None, max_hole: int = 400, wrong_depth: float | None = None):
    dA, nA, gA = _render(0.0, planes, flat)
    dB, nB, gB = _render(B, planes, flat)
    depth = dA.copy()
    if wrong_depth is not None:  # both depth maps agree on a plane around the hole that the images do not show
        ring = ndi.binary_dilation(hole, iterations=4)
        depth[ring] = wrong_depth
        dB = np.full_like(dB, wrong_depth)
        nA[ring] = (0, 0, -1)
        nB[:] = (0, 0, -1)
    truth = depth.copy()
    depth[hole] = 0
    r = DepthResult(depth, np.ones((H, W), np.float32), _view("a", 0.0), ["b"], nA.copy())
    src = {"b": DepthResult(dB, None, _view("b", B), ["a"], nB)}
    cfg = MVSConfig(fill_max_gap=max_hole, reproj_px=1.0, plane_reproj_px=0.0)
    filled, stats = fill_holes(r, src, cfg, 1, gA, {"b": (gB, src["b"].view)})
    return r, truth, filled, stats


def _box(y0, y1, x0, x1) -> np.ndarray:
    m = np.zeros((H, W), bool)
    m[y0:y1, x0:x1] = True
    return m


def test_textureless_hole_between_confirmed_neighbours_is_filled_to_the_truth():
    hole = _box(30, 42, 44, 56)  # 144 pixels on a flat grey patch of the slanted plane
    flat = (-0.2, 0.3, -0.3, 0.3)  # world x, y around the hole's pixels (about 2 away: 40 px per unit)
    r, truth, filled, stats = _fill([TILTED], hole, flat)
    assert stats["hole_pixels"] == hole.sum()
    assert filled[hole].mean() > 0.95, filled[hole].mean()
    err = np.abs(r.depth[hole & filled] - truth[hole & filled]) / truth[hole & filled]
    assert err.max() < 0.005, err.max()  # the neighbours' planes, extended: the slanted plane itself
    assert not filled[~hole].any()
    assert np.allclose(np.linalg.norm(r.normal[hole & filled].astype(float), axis=1), 1.0, atol=1e-2)
    assert (r.confidence[hole & filled] >= 0.25).all()


def test_hole_larger_than_the_limit_keeps_its_inside_empty():
    hole = _box(24, 48, 36, 60)  # 576 pixels
    assert not fillable_holes(np.where(hole, 0, 1.0), None, 400).any()
    r, truth, filled, stats = _fill([TILTED], hole, max_hole=400)
    rim = hole & ~ndi.binary_erosion(hole, np.ones((3, 3), bool))  # next to a kept depth
    inner = ndi.binary_erosion(hole, np.ones((3, 3), bool), iterations=FILL_PASSES)  # beyond the passes' reach
    assert stats["hole_pixels"] == rim.sum()  # only its rim is looked at, then the next ring
    assert not filled[inner].any() and (r.depth[inner] == 0).all()
    assert filled[rim].mean() > 0.8  # the rim, on a textured plane, takes its neighbours' plane
    err = np.abs(r.depth[filled] - truth[filled]) / truth[filled]
    assert err.max() < 0.005, err.max()
    _, _, filled, _ = _fill([TILTED], hole, max_hole=600)  # the same hole under a larger limit is filled
    assert filled[hole].mean() > 0.95


def test_plain_background_beside_an_edge_does_not_take_the_edges_plane():
    # a textured near plane (z = 1.5) covering world x >= 0.1 before a plain grey wall (z = 3): the wall has no
    # depth in the left view (a gap far over the limit) and the right view's depth map has the near plane
    # "fattened" 6 px onto the wall, as PatchMatch's windows leave it; in the top half the near plane lost its
    # first column
    near = (np.array([0.0, 0.0, 1.0]), 1.5, (0.1, 10.0))
    far = (np.array([0.0, 0.0, 1.0]), 3.0, None)
    dA, nA, gA = _render(0.0, [near, far])
    dB, nB, gB = _render(B, [near, far])
    rng = np.random.default_rng(1)
    gA, gB = (np.where(d > 2.0, 0.5 + rng.normal(0, 0.005, d.shape), g).astype(np.float32)
              for d, g in ((dA, gA), (dB, gB)))  # the wall plain grey, with the camera noise
    near_a = dA < 2.0
    first = near_a & ~np.roll(near_a, 1, axis=1)  # the near plane's first column in the left view
    first[H // 2:] = False
    depth = np.where(near_a & ~first, dA, 0).astype(np.float32)
    fat = ndi.binary_dilation(dB < 2.0, np.ones((1, 3), bool), iterations=6)
    dB = np.where(fat, 1.5, dB).astype(np.float32)
    nB[fat] = (0, 0, -1)
    wall_rim = ~near_a & ndi.binary_dilation(depth > 0, np.ones((3, 3), bool))  # the wall's pixels next to depth
    r = DepthResult(depth, np.ones((H, W), np.float32), _view("a", 0.0), ["b"], nA.copy())
    src = {"b": DepthResult(dB, None, _view("b", B), ["a"], nB)}
    cfg = MVSConfig(fill_max_gap=400, reproj_px=1.0, plane_reproj_px=0.0)
    filled, stats = fill_holes(r, src, cfg, 1, gA, {"b": (gB, src["b"].view)})
    assert wall_rim.sum() > 30 and first.sum() > 30 and stats["hole_pixels"] == (first | wall_rim).sum()
    assert filled[first].mean() > 0.6  # the textured plane's own edge comes back ...
    assert np.abs(r.depth[first & filled] - 1.5).max() < 0.01
    assert filled[wall_rim].mean() < 0.1, filled[wall_rim].mean()  # ... the plain wall beside it does not take it


def test_hole_touching_the_image_border_or_the_mask_is_not_fillable():
    d = np.ones((H, W), np.float32)
    d[0:5, 10:15] = 0  # touches the top border
    d[30:35, 30:35] = 0  # inside, next to masked-out pixels
    d[50:55, 60:65] = 0  # inside, fully in the mask
    mask = np.ones((H, W), bool)
    mask[30:35, 35:40] = False
    d[~mask] = 0
    f = fillable_holes(d, mask, 400)
    assert f[50:55, 60:65].all() and not f[0:5, 10:15].any() and not f[30:35, 30:35].any()


def test_hole_at_a_depth_edge_is_filled_only_where_the_other_view_sees_it():
    # a near plane (z = 1.5, disparity 16 px) covering world x >= 0.1 in front of a far wall (z = 3, 8 px): in the
    # left view the 8 px of wall just left of the near plane's edge are hidden from the right view; the hole
    # spans them and 8 px of wall that the right view sees
    near = (np.array([0.0, 0.0, 1.0]), 1.5, (0.1, 10.0))
    far = (np.array([0.0, 0.0, 1.0]), 3.0, None)
    dA, _, _ = _render(0.0, [near, far])
    edge = int(np.ceil(INTR.cx + F * 0.1 / 1.5))  # first pixel of the near plane in the left view
    hole = _box(25, 45, edge - 16, edge)
    occluded = _box(25, 45, edge - 8, edge)
    assert (dA[hole] > 2.9).all() and (dA[25:45, edge] < 1.6).all()
    r, truth, filled, stats = _fill([near, far], hole)
    assert stats["hole_pixels"] == hole.sum()
    assert not filled[occluded].any()  # neither side's plane is confirmed there (the near one is 2x too near)
    seen = hole & ~occluded & ~_box(0, H, edge - 9, edge - 8)  # the column at the occlusion's edge may go either way
    assert filled[seen].mean() > 0.95
    assert np.abs(r.depth[filled] - truth[filled]).max() < 0.01 * 3  # the wall's depth, never the near plane's


def test_plane_confirmed_by_depth_maps_but_not_by_the_images_is_not_filled():
    # around the hole both depth maps say z = 1.2, the images show the slanted plane at about 2: candidates that
    # the other view's depth confirms and its image contradicts
    hole = _box(30, 40, 40, 52)
    r, _, filled, _ = _fill([TILTED], hole, wrong_depth=1.2)
    assert not filled.any()
    r, _, filled, _ = _fill([TILTED], hole)  # with the right depth maps it is filled
    assert filled[hole].mean() > 0.95


@pytest.mark.slow
def test_stereo_pair_fill_adds_correct_depth_without_more_wrong_depth(tmp_path_factory):
    """run_mvs on a rectified pair of the room, without and with --fill-gaps on: the fill answers more of the
    pixels both views see within 2 px of disparity, and the share of answers off by more than 2 px does not grow."""
    from photorecon.depth.mvs import MVSConfig as Cfg, run_mvs
    from photorecon.io.dataset import Dataset, read_model
    from photorecon.metrics import covisible, disparity_scores
    from photorecon.testing import synth_scene

    root = synth_scene(tmp_path_factory, "fill_pair", scene="room", rig="stereo", width=240, height=180,
                       radius=2.6, elevation=35.0, baseline=0.3)
    ds = Dataset.open(root)
    a, b = read_model(root / "sparse" / "0").views
    gt = [np.load(root / "depth" / f"{v.name}.npy") for v in (a, b)]
    cov = covisible(gt[0], a, gt[1], b)
    fxb = a.intrinsics.fx * np.linalg.norm(a.center - b.center)
    scores = {}
    for fill in (False, True):
        out = tmp_path_factory.mktemp(f"fill_{fill}")
        rep = run_mvs(ds, out, Cfg(fill_gaps="on" if fill else "off", n_sources=1, pm_levels=2))
        assert rep.views == 2
        d = np.load(out / f"{a.name}.npy")
        disp = np.where(d > 0, fxb / np.maximum(d, 1e-12), np.nan)
        scores[fill] = disparity_scores(disp, fxb / np.maximum(gt[0], 1e-12), cov)
    before, after = scores[False], scores[True]
    assert after["within"] > before["within"] + 0.003, (before, after)
    assert after["bad"] <= before["bad"] + 0.001, (before, after)


def test_photometric_error_next_to_a_depth_edge_is_the_noise_of_the_pixels_own_side():
    # a textured strip (z = 1.5) before a textured wall (z = 3): wall pixels right next to the strip, seen by both
    # views at the wall's depth, have a 3x3 neighbourhood that straddles the edge; the best 2x2 block holding the
    # pixel lies on the wall's side, so the error stays at the images' noise level (0.005 each)
    strip = (np.array([0.0, 0.0, 1.0]), 1.5, (-0.2, 0.1))
    wall = (np.array([0.0, 0.0, 1.0]), 3.0, None)
    dA, _, gA = _render(0.0, [strip, wall])
    dB, _, gB = _render(B, [strip, wall])
    va, vb = _view("a", 0.0), _view("b", B)
    r = DepthResult(dA, None, va, ["b"], None)
    on_wall = dA > 2.9
    edge = on_wall & ndi.binary_dilation(~on_wall, np.ones((3, 3), bool))  # wall pixels touching the strip
    py, px = np.nonzero(edge[5:-5, 5:-5])
    py, px = py + 5, px + 5
    # keep those the other view sees: their projection lands on the wall there too
    u = px - F * B / dA[py, px]
    seen = (u > 1) & (dB[py, np.clip(np.round(u).astype(int), 0, W - 1)] > 2.9)
    py, px = py[seen], px[seen]
    assert len(py) > 20
    e = photometric_error(gA, r, {"b": (gB, vb)}, py, px, dA[py, px].astype(np.float64))
    assert np.median(e) < 0.01 and np.quantile(e, 0.9) < 0.015, (np.median(e), np.quantile(e, 0.9))


def test_hole_the_other_depth_map_misses_is_filled_only_where_the_images_are_clear():
    # the other view has no depth at all (no geometric confirmation anywhere): a hole on the textured slanted plane
    # is filled on the images' word alone; the same hole on a plain grey patch is not, when it is not enclosed by
    # one surface (here: the enclosed-hole rule switched off; below, the hole inside one surface)
    hole = _box(30, 40, 40, 52)
    for flat, want in ((None, True), ((-0.6, 0.6, -0.6, 0.6), False)):
        r, truth, filled = _fill_without_other_depth([TILTED], hole, flat, enclosed=False)
        if want:
            assert filled[hole].mean() > 0.6, filled[hole].mean()
            err = np.abs(r.depth[filled] - truth[filled]) / truth[filled]
            assert err.max() < 0.005, err.max()
        else:
            assert filled[hole].mean() < 0.05, filled[hole].mean()


def _fill_without_other_depth(planes, hole: np.ndarray, flat, enclosed: bool = True):
    """``fill_holes`` on the left view of ``planes`` with ``hole`` cut out, the other view without any depth (only
    the images or the surrounding surface can confirm): (result, the true depth, the filled pixels)."""
    dA, nA, gA = _render(0.0, planes, flat)
    _, nB, gB = _render(B, planes, flat)
    depth = dA.copy()
    depth[hole] = 0
    r = DepthResult(depth, np.ones((H, W), np.float32), _view("a", 0.0), ["b"], nA.copy())
    src = {"b": DepthResult(np.zeros((H, W), np.float32), None, _view("b", B), ["a"], nB)}
    cfg = MVSConfig(fill_max_gap=400, reproj_px=1.0, plane_reproj_px=0.0)
    filled, _ = fill_holes(r, src, cfg, 1, gA, {"b": (gB, src["b"].view)}, enclosed=enclosed)
    return r, dA, filled


def test_plain_hole_inside_one_surface_takes_its_plane_and_one_across_a_step_stays_empty():
    # the other view has no depth and the hole lies on a plain grey patch, so neither the depth maps nor the images
    # can confirm anything: a hole whose neighbours in all 8 directions carry one plane takes it (to the truth); a
    # hole across a depth step (neighbours on two planes, 20% apart) stays empty
    flat = (-0.6, 0.6, -0.6, 0.6)
    near = (np.array([0.0, 0.0, 1.0]), 2.0, (-10.0, 0.0))  # world x < 0 at z = 2, the rest at z = 2.4
    far = (np.array([0.0, 0.0, 1.0]), 2.4, None)
    for planes, hole, want in (([TILTED], _box(30, 40, 40, 52), True), ([near, far], _box(30, 40, 42, 54), False)):
        r, dA, filled = _fill_without_other_depth(planes, hole, flat)
        if want:
            assert filled[hole].mean() > 0.95, filled[hole].mean()
            err = np.abs(r.depth[filled] - dA[filled]) / dA[filled]
            assert err.max() < 0.005, err.max()
        else:
            assert (dA[hole] < 2.2).any() and (dA[hole] > 2.2).any()  # the step crosses the hole
            assert filled[hole].mean() < 0.05, filled[hole].mean()


def test_a_plane_that_would_hide_what_the_other_view_saw_is_not_taken_on_the_images_word():
    # _not_seen_through: a point in front of the surface the other view's depth map holds would block that view's
    # ray (False); on the surface, behind it (hidden from that view) or where it has no depth, nothing says no
    from photorecon.depth.fill import _not_seen_through

    dA, nA, _ = _render(0.0, [TILTED])
    dB, nB, _ = _render(B, [TILTED])
    r = DepthResult(dA, None, _view("a", 0.0), ["b"], nA)
    py, px = np.nonzero(_box(20, 50, 30, 60))
    z = dA[py, px].astype(np.float64)
    src = {"b": DepthResult(dB, None, _view("b", B), ["a"], nB)}
    assert _not_seen_through(r, src, py, px, z, 0.01).all()
    assert _not_seen_through(r, src, py, px, z * 1.2, 0.01).all()
    assert not _not_seen_through(r, src, py, px, z * 0.8, 0.01).any()
    empty = {"b": DepthResult(np.zeros_like(dB), None, _view("b", B), ["a"], nB)}
    assert _not_seen_through(r, empty, py, px, z * 0.8, 0.01).all()


def test_photometric_error_through_the_plane_matches_a_surface_the_other_view_sees_foreshortened():
    # a textured wall seen at a grazing angle (x + 0.3 z = 0.6), between 0.8 and 2.5 away: the two views see it
    # foreshortened differently, so a window sampled at the same offsets around the projection compares different
    # surface points; through the wall's plane (its normal given) the error is the images' noise (0.005 each)
    steep = (np.array([1.0, 0.0, 0.3]), 0.6, None)
    with np.errstate(invalid="ignore"):  # the rays that miss the wall
        dA, nA, gA = _render(0.0, [steep])
        dB, _, gB = _render(B, [steep])
    ok = np.isfinite(dA) & (dA > 0.8) & (dA < 2.5)
    ok[:3], ok[-3:], ok[:, :3], ok[:, -3:] = False, False, False, False
    py, px = np.nonzero(ok)
    u = px - F * B / dA[py, px]
    keep = (u > 2) & (u < W - 3)  # the other view sees it, window and all
    py, px = py[keep], px[keep]
    assert len(py) > 1000
    r = DepthResult(dA, None, _view("a", 0.0), ["b"], None)
    images = {"b": (gB, _view("b", B))}
    z = dA[py, px].astype(np.float64)
    plain = photometric_error(gA, r, images, py, px, z)
    warped = photometric_error(gA, r, images, py, px, z, normal=nA[py, px].astype(np.float64))
    assert np.median(warped) < 0.006 and np.median(plain) > 0.008, (np.median(warped), np.median(plain))
    assert np.quantile(warped, 0.9) < 0.5 * np.quantile(plain, 0.9), (np.quantile(warped, 0.9), np.quantile(plain, 0.9))


def test_noisy_plain_background_beside_an_edge_does_not_take_the_edges_plane_on_the_images_word():
    # a textured near plane before a plain wall, as above, but with strong camera noise (0.04) and no depth in
    # the other view: only the images could confirm the near plane on the wall's pixels, and there a depth
    # "matches better" than its neighbours along the epipolar line only by the noise's chance; the pixel must be
    # distinct by a margin that follows the images' noise, not by a fixed grey difference
    near = (np.array([0.0, 0.0, 1.0]), 1.5, (0.1, 10.0))
    far = (np.array([0.0, 0.0, 1.0]), 3.0, None)
    dA, nA, gA = _render(0.0, [near, far])
    dB, nB, gB = _render(B, [near, far])
    near_a = dA < 2.0
    depth = np.where(near_a, dA, 0).astype(np.float32)
    wall_rim = ~near_a & ndi.binary_dilation(near_a, np.ones((3, 3), bool))
    for seed in range(4):
        rng = np.random.default_rng(seed)
        ga, gb = (np.where(d > 2.0, 0.5, g) + rng.normal(0, 0.04, d.shape) for d, g in ((dA, gA), (dB, gB)))
        r = DepthResult(depth.copy(), np.ones((H, W), np.float32), _view("a", 0.0), ["b"], nA.copy())
        src = {"b": DepthResult(np.zeros((H, W), np.float32), None, _view("b", B), ["a"], nB)}
        cfg = MVSConfig(fill_max_gap=400, reproj_px=1.0, plane_reproj_px=0.0)
        filled, _ = fill_holes(r, src, cfg, 1, ga.astype(np.float32), {"b": (gb.astype(np.float32), src["b"].view)})
        assert filled[~near_a].sum() < 0.15 * wall_rim.sum(), (seed, filled[~near_a].sum(), wall_rim.sum())


def test_edge_fattened_in_both_depth_maps_settles_on_the_surface_the_pixels_show():
    # a textured strip (z = 2.4) before a textured wall (z = 3): in the top half both views' depth maps carry the
    # strip's plane 3 px onto the wall on its right (PatchMatch's windows straddle the edge, and the geometric
    # filter keeps what both maps agree on); the wall's pixels take the wall's plane back where their own
    # neighbourhoods show it, and no pixel that had the right depth loses it
    from photorecon.depth.fill import settle_edges

    strip = (np.array([0.0, 0.0, 1.0]), 2.4, (-0.3, 0.3))
    wall = (np.array([0.0, 0.0, 1.0]), 3.0, None)
    right_of = np.zeros((1, 7), bool)
    right_of[0, 3:] = True  # dilation towards +x by 3 px
    maps = []
    for cx in (0.0, B):
        d, n, g = _render(cx, [strip, wall])
        on_strip = d < 2.7
        fat = ndi.binary_dilation(on_strip, right_of) & ~on_strip
        fat[H // 2:] = False
        df, nf = d.copy(), n.copy()
        df[fat] = 2.4
        nf[fat] = (0, 0, -1)
        maps.append((d, df, nf, g, fat))
    (dA, fA, nA, gA, fatA), (_, fB, nB, gB, _) = maps
    r = DepthResult(fA.copy(), np.ones((H, W), np.float32), _view("a", 0.0), ["b"], nA.copy())
    src = {"b": DepthResult(fB, None, _view("b", B), ["a"], nB)}
    right_before = np.abs(r.depth - dA) < 0.01 * dA
    changed = settle_edges(r, src, gA, {"b": (gB, src["b"].view)})
    right_after = np.abs(r.depth - dA) < 0.01 * dA
    fat = fatA.copy()
    fat[:3] = False  # away from the image border
    assert fat.sum() > 80 and not right_before[fat].any()
    assert right_after[fat].mean() > 0.7, right_after[fat].mean()
    assert not (right_before & ~right_after).any()  # nothing right made wrong
    assert changed[right_after & ~right_before].all()
