"""Which views get depth maps (``--depth-views``): coverage of the sparse points kept, redundant views dropped.
Synthetic cameras and surface points (visibility by ray casting); no image is rendered."""
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from conftest import coarse_maps
from photorecon.cameras import View
from photorecon.depth.mvs import MVSConfig
from photorecon.depth.views import choose_depth_views
from photorecon.render import Renderer
from photorecon.synthetic import SynthConfig, make_scene, make_views, normalize_mesh, sparse_model_from_surface


@pytest.fixture(scope="module")
def renderer():
    return Renderer(normalize_mesh(make_scene("blob"))[0])


def _model(renderer, views: int, rig: str = "sphere", points: int = 2000):
    return sparse_model_from_surface(renderer, make_views(SynthConfig(views=views, rig=rig, width=320, height=240)),
                                     points)


def _chosen_viewers(model, chosen) -> tuple[np.ndarray, np.ndarray]:
    """Per sparse point: how many views observe it, and how many of the chosen ones."""
    index = model.point_index()
    all_, sel = np.zeros(len(model.points), int), np.zeros(len(model.points), int)
    for name, (_, ids) in model.observations.items():
        rows = [index[int(i)] for i in ids]
        all_[rows] += 1
        if name in chosen:
            sel[rows] += 1
    return all_, sel


def test_redundant_capture_keeps_coverage_with_fewer_views(renderer):
    """120 views around one object: about a third get depth maps, and every sparse point seen by at least three
    views is still seen by at least three chosen ones (all of them by at least two)."""
    model = _model(renderer, 120)
    choice = choose_depth_views(model, MVSConfig())
    assert choice.reason == "coverage" and choice.total == 120 and choice.uncovered_points == 0
    assert 20 <= len(choice.chosen) <= 60, len(choice.chosen)
    seen, chosen = _chosen_viewers(model, set(choice.chosen))
    assert (chosen[seen >= 3] >= 3).mean() >= 0.99
    assert (chosen[seen >= 2] >= 2).all()
    # a higher coverage asks for more views
    assert len(choose_depth_views(model, MVSConfig(depth_view_coverage=5)).chosen) > len(choice.chosen)


def test_small_capture_keeps_every_view(renderer):
    for n in (8, 12, 30):
        model = _model(renderer, n)
        assert len(choose_depth_views(model, MVSConfig()).chosen) == n
    model = _model(renderer, 120)
    assert len(choose_depth_views(model, MVSConfig(depth_views="all")).chosen) == 120


def test_duplicated_views_are_dropped(renderer):
    """Each of 30 views taken twice from nearly the same pose (1 mm, 0.1 degree apart): about half dropped, and
    never both of a pair when the single set needs only one of them."""
    base = make_views(SynthConfig(views=30, width=320, height=240))
    rng = np.random.default_rng(0)
    twins = []
    for v in base:
        T = v.cam_from_world.copy()
        a = np.radians(0.1)
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        T[:3, :3] = R @ T[:3, :3]
        T[:3, 3] += rng.normal(size=3) * 1e-3
        twins += [v, replace(v, name=v.name + "_b", cam_from_world=T, image_file=None)]
    model = sparse_model_from_surface(renderer, twins, 2000)
    choice = choose_depth_views(model, MVSConfig())
    assert 0.4 * 60 <= 60 - len(choice.chosen) <= 0.6 * 60, len(choice.chosen)
    pairs = {v.name for v in base}
    both = [n for n in pairs if n in choice.chosen and n + "_b" in choice.chosen]
    assert len(both) <= 2, both
    seen, chosen = _chosen_viewers(model, set(choice.chosen))
    assert (chosen[seen >= 6] >= 3).mean() >= 0.99  # seen from three distinct poses: still three chosen


def test_views_without_points_are_kept(renderer):
    model = _model(renderer, 60)
    lonely = View("lonely", model.views[0].intrinsics, model.views[0].cam_from_world)
    model = replace(model, views=model.views + [lonely])
    choice = choose_depth_views(model, MVSConfig())
    assert "lonely" in choice.chosen and len(choice.chosen) < 61
    no_points = replace(model, points=np.zeros((0, 3)), observations={})
    assert choose_depth_views(no_points, MVSConfig()).reason == "no sparse points"


@pytest.mark.slow
def test_depth_stage_and_fusion_use_only_the_chosen_views(tmp_path):
    """48 views of one object: the depth stage writes depth maps for the chosen views only (the report says how
    many of how many), and fusing those gives the object's surface."""
    from photorecon.depth.mvs import run_mvs
    from photorecon.fusion import FusionConfig, fuse, load_frames
    from photorecon.io.dataset import Dataset
    from photorecon.metrics import mesh_metrics
    from photorecon.synthetic import synthesize

    data = tmp_path / "data"
    synthesize(SynthConfig(scene="blob", views=48, width=80, height=60, points=1500, seed=2), data)
    ds = Dataset.open(data)
    cfg = MVSConfig(method="sweep", n_sources=4, n_depths=48, min_consistent=1, min_confidence=0.5)
    chosen = set(choose_depth_views(ds.model, cfg).chosen)
    rep = run_mvs(ds, tmp_path / "depth", cfg)
    assert rep.depth_views["of"] == 48 and rep.depth_views["chosen"] == len(chosen) <= 36
    written = {p.name[:-4] for p in (tmp_path / "depth").glob("*.npy") if p.name.count(".") == 1}
    assert written <= chosen and len(written) >= 0.9 * len(chosen) and rep.views == len(written)
    dsd = Dataset.open(data, depth_dir=tmp_path / "depth")
    frames = load_frames(dsd, FusionConfig(), [v for v in dsd.views if dsd.has_depth(v)])
    m = mesh_metrics(fuse(frames, FusionConfig(trunc_voxels=3.0), dsd.model.points),
                     __import__("trimesh").load(data / "gt_mesh.ply", process=False), n_samples=20_000)
    assert m.fscore >= 0.85, m  # the sweep at 80x60 scores about 0.90 here (0.899 in one run of many)



def test_coarse_depth_choice_covers_the_surface_it_hides_with_fewer_views():
    """``--depth-views coarse`` on a room of objects (a box, a sphere, a cylinder, an open cup: surfaces they hide
    from one another) seen by 100 views from above: from the coarse depth maps alone it keeps at most 40 of them
    (28 measured; 54 for a cover of every sample), and the surface three of all the views see well is seen well
    by three chosen ones almost everywhere (0.97 measured), by two nearly everywhere (0.99) (ground truth by ray
    casting, occlusion included)."""
    from photorecon.depth.views import coarse_depth_views

    mesh = normalize_mesh(make_scene("room"))[0]
    renderer = Renderer(mesh)
    views = make_views(SynthConfig(views=100, rig="hemisphere", width=160, height=120))
    choice = coarse_depth_views(views, coarse_maps(renderer, views, normals=True), MVSConfig(depth_views="coarse"))
    assert choice.reason == "coarse depth coverage" and choice.total == 100
    assert len(choice.chosen) <= 40, len(choice.chosen)
    pts, tri = trimesh.sample.sample_surface_even(mesh, 4000, seed=1)
    normals = mesh.face_normals[tri]
    seen = np.array([renderer.visible(pts, v, normals, min_cos=0.5)[0] for v in views])  # (views, points)
    chosen = np.isin([v.name for v in views], choice.chosen)
    well = seen.sum(0) >= 3
    assert (seen[chosen][:, well].sum(0) >= 3).mean() >= 0.94
    assert (seen[chosen][:, well].sum(0) >= 2).mean() >= 0.98


def _short_tracks(model, keep: int, seed: int = 0):
    """``model`` with each sparse point observed by at most ``keep`` of the views that observe it (chosen at
    random), as the short tracks of a handheld capture of a shiny object."""
    rng = np.random.default_rng(seed)
    viewers: dict = {}
    for name, (_, ids) in model.observations.items():
        for i in ids:
            viewers.setdefault(int(i), []).append(name)
    kept = {(i, n) for i, names in viewers.items()
            for n in rng.permutation(names)[:keep]}
    obs = {}
    for name, (uv, ids) in model.observations.items():
        m = np.array([(int(i), name) in kept for i in ids], bool)
        obs[name] = (uv[m], ids[m])
    return replace(model, observations=obs)


@pytest.mark.slow
def test_large_capture_auto_also_covers_the_coarse_surface(tmp_path):
    """``--depth-views auto`` on 40 or more views: after the sparse points' cover, PatchMatch's coarsest round
    for the views it kept and the cover of that dense surface among them; the depth maps written are that
    choice's, and fusing them gives the object's surface."""
    from photorecon.depth.config import MVS_PRESETS
    from photorecon.depth.mvs import run_mvs
    from photorecon.depth.views import COARSE_MIN_VIEWS
    from photorecon.fusion import FusionConfig, fuse, load_frames
    from photorecon.io.dataset import Dataset
    from photorecon.metrics import mesh_metrics
    from photorecon.synthetic import synthesize

    data = tmp_path / "data"
    synthesize(SynthConfig(scene="blob", views=COARSE_MIN_VIEWS + 8, width=96, height=72, points=3000, seed=3), data)
    ds = Dataset.open(data)
    ds = replace(ds, model=_short_tracks(ds.model, 3))  # as a handheld capture's: few views observe each point
    cfg = MVSConfig(**MVS_PRESETS["fast"])
    sparse = choose_depth_views(ds.model, cfg)
    assert len(sparse.chosen) >= COARSE_MIN_VIEWS  # the short tracks ask for nearly every view
    rep = run_mvs(ds, tmp_path / "depth", cfg)
    dv = rep.depth_views
    assert dv["reason"] == "coverage, then coarse depth coverage" and dv["of"] == COARSE_MIN_VIEWS + 8
    assert dv["chosen"] < len(sparse.chosen) and dv["surface_samples"] > 0
    written = {p.name[:-4] for p in (tmp_path / "depth").glob("*.npy") if p.name.count(".") == 1}
    assert rep.views == len(written) and len(written) >= 0.9 * dv["chosen"]
    dsd = Dataset.open(data, depth_dir=tmp_path / "depth")
    frames = load_frames(dsd, FusionConfig(), [v for v in dsd.views if dsd.has_depth(v)])
    m = mesh_metrics(fuse(frames, FusionConfig(trunc_voxels=3.0), dsd.model.points),
                     trimesh.load(data / "gt_mesh.ply", process=False), n_samples=20_000)
    assert m.fscore >= 0.95, m  # 1.000 measured


def test_half_resolution_keeps_the_finest_view_of_a_surface_full():
    """``views.half_resolution_views`` on hand-made observations of 100 samples: of three views along nearly the
    same ray, the finest (footprint 0.8) stays full and the others (1.0 and 0.9: within 1.25x of it) go to half;
    a fourth view 40 degrees away stays full (no full view near its direction), and so does a fifth that sees
    half the samples alone."""
    from photorecon.depth.views import half_resolution_views

    n = 100
    def obs(view, samples, direction, footprint):
        d = np.asarray(direction, float) / np.linalg.norm(direction)
        return (np.full(len(samples), view), np.asarray(samples), np.tile(d, (len(samples), 1)),
                np.full(len(samples), footprint))
    a40 = np.radians(40)
    parts = [obs(0, range(n), [0, 0, 1], 1.0), obs(1, range(n), [0, 0.05, 1], 0.8), obs(2, range(n), [0.05, 0, 1], 0.9),
             obs(3, range(n), [np.sin(a40), 0, np.cos(a40)], 0.8), obs(4, range(n + 50), [0, -0.05, 1], 0.8)]
    vi, pi, u, foot = (np.concatenate([p[i] for p in parts]) for i in range(4))
    finest = np.full(n + 50, np.inf)
    np.minimum.at(finest, pi, foot)
    levels = half_resolution_views(vi, pi, u, foot, finest[pi] / foot, np.ones(5, bool), n + 50)
    assert levels[4][0] == 0  # the most weight (150 samples): judged first, full
    assert levels[3][0] == 0 and levels[3][1] == 0.0  # 40 degrees from every full view
    assert [levels[k][0] for k in (0, 1, 2)] == [1, 1, 1]  # view 4 sees their samples at 0.8 from nearby
    only = half_resolution_views(vi, pi, u, foot, finest[pi] / foot, np.array([True, True, True, False, False]), n + 50)
    assert only[1][0] == 0 and only[0][0] == 1 and only[2][0] == 1  # the finest of the three stays full


def test_depth_resolution_halves_views_whose_surface_full_views_see_as_finely(renderer):
    """``--depth-resolution auto``: among the views the coarse surface's cover keeps, a view gets its depth map at
    half resolution when full-resolution views see 90% of its surface from within 20 degrees at a footprint at
    most 1.25x its own. A ring of 12 (30 degrees apart) keeps every view full; a ring of 72 halves some of the
    views the cover keeps (15 of 33 measured), each next to a full one; ``full`` halves none."""
    from photorecon.depth.views import HALF_COVERED, HALF_MAX_ANGLE_DEG, coarse_depth_views

    ring12 = make_views(SynthConfig(views=12, rig="ring", width=160, height=120))
    choice = coarse_depth_views(ring12, coarse_maps(renderer, ring12, normals=True), MVSConfig(depth_views="coarse"))
    assert len(choice.chosen) == 12 and set(choice.resolution) == set(choice.chosen)
    assert all(lvl == 0 for lvl, _ in choice.resolution.values())

    ring = make_views(SynthConfig(views=72, rig="ring", width=160, height=120))
    maps = coarse_maps(renderer, ring, normals=True)
    choice = coarse_depth_views(ring, maps, MVSConfig(depth_views="coarse"))
    half = [n for n in choice.chosen if choice.level(n) == 1]
    full = [n for n in choice.chosen if choice.level(n) == 0]
    assert len(half) >= 5 and len(full) >= 8, (len(half), len(full))
    assert choice.to_dict()["half_resolution"] == len(half)
    centre = {v.name: v.center / np.linalg.norm(v.center) for v in ring}
    cos_max = np.cos(np.radians(HALF_MAX_ANGLE_DEG + 5))  # rays to the surface, not to the centre: a margin
    for n in half:
        assert choice.resolution[n][1] >= HALF_COVERED and choice.resolution_reason(n).startswith("half: ")
        assert max(float(centre[n] @ centre[f]) for f in full) >= cos_max, n
    for n in full:
        assert choice.resolution[n][1] < HALF_COVERED and choice.resolution_reason(n).startswith("full: ")
    assert not coarse_depth_views(ring, maps, MVSConfig(depth_views="coarse", depth_resolution="full")).resolution


@pytest.mark.slow
def test_half_resolution_depth_maps_fuse_as_well_as_full_ones(tmp_path):
    """End to end on a ring of 40 photos of the blob at 224x168 (``--depth-views coarse``, PatchMatch): the views
    the choice halves (8 of 27 measured) get depth maps of half the working size, their geometric filter and their
    neighbours' read them at that size, the report says which resolution each view got and why, the fusion's voxel
    follows the full-resolution maps, and the fused surface is about as close to the truth as with every depth map
    at full resolution (F-score at 1% of the diagonal 0.911 against 0.913 measured, at 0.5% 0.836 against
    0.849)."""
    from photorecon.depth.mvs import run_mvs
    from photorecon.fusion import FusionConfig, fuse, load_frames
    from photorecon.fusion.frames import DEPTH_LEVEL, pixel_footprint
    from photorecon.io.dataset import Dataset
    from photorecon.metrics import mesh_metrics
    from photorecon.synthetic import synthesize

    data = tmp_path / "data"
    synthesize(SynthConfig(scene="blob", rig="ring", views=40, width=224, height=168, points=2000, seed=4), data)
    ds = Dataset.open(data)
    gt = trimesh.load(data / "gt_mesh.ply", process=False)
    scores, footprints = {}, {}
    for mode in ("auto", "full"):
        rep = run_mvs(ds, tmp_path / mode, MVSConfig(depth_views="coarse", depth_resolution=mode))
        half = [n for n, s in rep.per_view.items() if s["resolution"] == "half"]
        if mode == "auto":
            assert len(half) >= 3 and rep.depth_views["half_resolution"] >= len(half), rep.depth_views
            for n, s in rep.per_view.items():
                size = (112, 84) if n in half else (224, 168)
                assert tuple(s["size"]) == size and np.load(tmp_path / mode / f"{n}.npy").shape == size[::-1]
                assert s["resolution_reason"].startswith(s["resolution"] + ": ")
        else:
            assert not half
        dsd = Dataset.open(data, depth_dir=tmp_path / mode)
        frames = load_frames(dsd, FusionConfig(), [v for v in dsd.views if dsd.has_depth(v)])
        assert sorted(f.view.name for f in frames if f.view.extra.get(DEPTH_LEVEL)) == sorted(half)
        footprints[mode] = pixel_footprint(frames)
        m = mesh_metrics(fuse(frames, FusionConfig(), dsd.model.points), gt, n_samples=30_000)
        scores[mode] = (m.fscore, m.fscore_half)
    assert footprints["auto"] == pytest.approx(footprints["full"], rel=0.05)
    assert scores["full"][0] >= 0.88 and scores["auto"][0] >= scores["full"][0] - 0.01, scores
    assert scores["auto"][1] >= scores["full"][1] - 0.03, scores


def test_cover_round_runs_near_a_fixed_size_whatever_the_working_resolution():
    """The coarse round that chooses the views runs for every view: the default pyramid is deepened until that
    round's long side is at most ``COVER_MAX_SIDE`` (1600 px: 4 levels, 200 px); an 800-px capture keeps 3 levels,
    a pyramid set by the user and a capture without the cover are left as they are."""
    from photorecon.cameras import Intrinsics
    from photorecon.depth.methods import patchmatch as pm

    def plan(w, h):
        v = View("a", Intrinsics(w, h, w * 0.9, w * 0.9, w / 2, h / 2), np.eye(4))
        return {"a": (v, ["b", "c"], (1.0, 2.0), None)}

    cfg = MVSConfig()
    assert pm.adapt(cfg, plan(1600, 1200), cover=True).pm_levels == 4
    assert pm.adapt(cfg, plan(1600, 1600), cover=True).pm_levels == 4
    assert pm.adapt(cfg, plan(2400, 1800), cover=True).pm_levels == 4  # 300 px
    assert pm.adapt(cfg, plan(4000, 3000), cover=True).pm_levels == 5
    assert pm.adapt(cfg, plan(800, 600), cover=True).pm_levels == 3
    assert pm.adapt(cfg, plan(1600, 1200), cover=False).pm_levels == 3
    assert pm.adapt(replace(cfg, pm_levels=2), plan(1600, 1200), cover=True).pm_levels == 2
    for w in (64, 300, 301, 1600, 6000):
        n = pm.cover_levels(3, w)
        assert w / 2 ** (n - 1) <= pm.COVER_MAX_SIDE and (n == 3 or w / 2 ** (n - 2) > pm.COVER_MAX_SIDE)


def test_large_capture_cover_round_at_the_deeper_pyramid(tmp_path, monkeypatch):
    """On a capture the coarse round chooses, the chosen views' depth maps go through the deeper pyramid's every
    round (one more than the default's) and still fuse to the object's surface."""
    from photorecon.depth.methods import patchmatch as pm
    from photorecon.depth.mvs import run_mvs
    from photorecon.depth.views import COARSE_MIN_VIEWS
    from photorecon.fusion import FusionConfig, fuse, load_frames
    from photorecon.io.dataset import Dataset
    from photorecon.metrics import mesh_metrics
    from photorecon.synthetic import synthesize

    monkeypatch.setattr(pm, "COVER_MAX_SIDE", 30)  # 192 px: 3 levels give 48, 4 give 24
    data = tmp_path / "data"
    synthesize(SynthConfig(scene="blob", views=COARSE_MIN_VIEWS + 8, width=192, height=144, points=3000, seed=3), data)
    ds = Dataset.open(data)
    ds = replace(ds, model=_short_tracks(ds.model, 3))
    cfg = MVSConfig(n_sources=4, pm_iterations=3, depth_resolution="full")
    rep = run_mvs(ds, tmp_path / "depth", cfg)
    rounds = {int(k.partition(":")[0][2:]) for k in rep.task_seconds if k.startswith("pm")}
    assert rounds == set(range(5))  # 4 levels, then the geometric round at full resolution
    assert rep.depth_views["reason"] == "coverage, then coarse depth coverage"
    dsd = Dataset.open(data, depth_dir=tmp_path / "depth")
    frames = load_frames(dsd, FusionConfig(), [v for v in dsd.views if dsd.has_depth(v)])
    m = mesh_metrics(fuse(frames, FusionConfig(trunc_voxels=3.0), dsd.model.points),
                     trimesh.load(data / "gt_mesh.ply", process=False), n_samples=20_000)
    assert m.fscore >= 0.97, m  # 0.9996 measured (3 levels: 1.000)


@pytest.mark.slow
def test_quarter_resolution_depth_maps_where_the_mesh_keeps_no_finer_detail(tmp_path, monkeypatch):
    """The capture of ``test_large_capture_cover_round_at_the_deeper_pyramid`` with a mesh that keeps no detail
    finer than a quarter-resolution map has (``mesh_footprint`` says so): every chosen view stops after the
    quarter-resolution round (its map 80x60, no round after it), the report says quarter and why, the fusion reads
    them back at that level, and they still fuse to the object's surface."""
    from photorecon.depth.methods import patchmatch as pm
    from photorecon.depth.mvs import run_mvs
    from photorecon.depth.views import COARSE_MIN_VIEWS
    from photorecon.fusion import FusionConfig, fuse, load_frames
    from photorecon.fusion.frames import DEPTH_LEVEL, frame_footprint
    from photorecon.io.dataset import Dataset
    from photorecon.metrics import mesh_metrics
    from photorecon.synthetic import synthesize

    monkeypatch.setattr(pm, "COVER_MAX_SIDE", 50)  # 320 px: 4 levels, the coarse round at 40 px
    data = tmp_path / "data"
    synthesize(SynthConfig(scene="blob", views=COARSE_MIN_VIEWS + 8, width=320, height=240, points=3000, seed=3), data)
    ds = Dataset.open(data)
    ds = replace(ds, model=_short_tracks(ds.model, 3))
    cfg = MVSConfig(n_sources=4, pm_iterations=3)
    rep = run_mvs(ds, tmp_path / "depth", cfg, mesh_footprint=lambda maps, working: 1.0)  # coarser than any map
    rounds = {int(k.partition(":")[0][2:]) for k in rep.task_seconds if k.startswith("pm")}
    assert rounds == {0, 1}  # the coarse round at an eighth, then the quarter-resolution one
    assert rep.depth_views["quarter_resolution"] == len(rep.per_view) > 10, rep.depth_views
    for n, s in rep.per_view.items():
        assert s["resolution"] == "quarter" and tuple(s["size"]) == (80, 60), s
        assert s["resolution_reason"].startswith("quarter: the fused mesh's voxel")
    dsd = Dataset.open(data, depth_dir=tmp_path / "depth")
    frames = load_frames(dsd, FusionConfig(), [v for v in dsd.views if dsd.has_depth(v)])
    assert {f.view.extra.get(DEPTH_LEVEL) for f in frames} == {2}
    # the voxel the mesh would keep: 1.5 footprints of the quarter-resolution maps (the fusion's own rule counts
    # them at the working resolution, for a budget that keeps a finer voxel)
    voxel = 1.5 * float(np.median([frame_footprint(f) for f in frames]))
    m = mesh_metrics(fuse(frames, FusionConfig(voxel_size=voxel, trunc_voxels=3.0), dsd.model.points),
                     trimesh.load(data / "gt_mesh.ply", process=False), n_samples=20_000)
    assert m.fscore >= 0.95, m  # 0.983 measured (32 depth maps)
