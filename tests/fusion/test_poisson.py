"""Poisson meshing, watertight closing, floater removal and preview framing, against synthetic ground truth."""
import numpy as np
import pytest
import trimesh

from photorecon.cameras import Intrinsics, View, look_at
from photorecon.errors import BadArgumentError, NoDepthError
from photorecon.fusion import DepthFrame, FusionConfig, fuse, load_frames, oriented_points, surface_report
from photorecon.io.dataset import Dataset
from photorecon.mesh import CleanConfig, boundary_edges, clean
from photorecon.metrics import mesh_metrics
from photorecon.report.preview import bulk_frame
from photorecon.testing import synth_scene


@pytest.fixture(scope="module")
def sphere_small(tmp_path_factory):
    """16 sphere views of the blob at 160x120: every side seen."""
    return synth_scene(tmp_path_factory, "poisson_sphere", scene="blob", views=16, width=160, height=120,
                       points=300, seed=2)


@pytest.fixture(scope="module")
def ring_small(tmp_path_factory):
    """12 ring views (elevation 20 deg) of the blob at 160x120: the bottom is never seen."""
    return synth_scene(tmp_path_factory, "poisson_ring", scene="blob", rig="ring", views=12, width=160,
                       height=120, points=300, seed=2)


def test_normals_from_depth_face_the_camera_and_match_the_truth(sphere_small):
    ds = Dataset.open(sphere_small)
    f = load_frames(ds, FusionConfig())[0]
    P, N, ok = oriented_points(f)
    assert len(P) > 0.8 * np.count_nonzero(f.depth)  # only silhouette pixels lack four neighbours
    assert np.allclose(np.linalg.norm(N, axis=1), 1, atol=1e-6)
    toward = np.einsum("nc,nc->n", N, f.view.center - P)
    assert (toward > 0).all()
    # against the true surface normal at the nearest point of the ground-truth mesh
    gt = trimesh.load(sphere_small / "gt_mesh.ply", process=False)
    import open3d as o3d

    from photorecon.mesh import raycasting_scene

    hit = raycasting_scene(gt).compute_closest_points(o3d.core.Tensor(P[::50].astype(np.float32)))
    true_n = gt.face_normals[hit["primitive_ids"].numpy()]
    cos = np.abs(np.einsum("nc,nc->n", N[::50], true_n))
    assert np.median(cos) > 0.98, np.median(cos)
    # given (PatchMatch-style, camera frame) normals win over the estimated ones: a constant one comes back
    n_cam = np.zeros(f.depth.shape + (3,), np.float32)
    n_cam[..., 2] = -1.0  # facing the camera
    P2, N2, _ = oriented_points(DepthFrame(f.view, f.depth, normal=n_cam))
    assert np.allclose(N2, -f.view.cam_from_world[2, :3], atol=1e-6)


def test_poisson_mesher_matches_ground_truth(sphere_small):
    ds = Dataset.open(sphere_small)
    frames = load_frames(ds, FusionConfig())
    mesh = clean(fuse(frames, FusionConfig(mesher="poisson"), ds.model.points), cameras=ds.views)
    gt = trimesh.load(sphere_small / "gt_mesh.ply", process=False)
    m = mesh_metrics(mesh, gt, n_samples=30_000)
    assert m.fscore >= 0.98 and m.fscore_half >= 0.95, m
    assert mesh.metadata["mesher"] == "poisson" and mesh.metadata["poisson_cell"] > 0
    assert mesh.visual.kind == "vertex" and np.asarray(mesh.visual.vertex_colors)[:, :3].std() > 5  # colours


@pytest.mark.slow
def test_watertight_closes_the_unseen_bottom_and_says_how_much_is_invented(ring_small):
    ds = Dataset.open(ring_small)
    frames = load_frames(ds, FusionConfig())
    tsdf = clean(fuse(frames, FusionConfig(mesher="tsdf"), ds.model.points), cameras=ds.views)
    plain = clean(fuse(frames, FusionConfig(mesher="poisson")), cameras=ds.views)
    closed = clean(fuse(frames, FusionConfig(mesher="poisson", watertight=True)), cameras=ds.views)
    r_tsdf, r_plain, r_closed = (surface_report(m, frames) for m in (tsdf, plain, closed))
    assert r_closed["watertight"] and r_closed["boundary_edges"] == 0 and closed.is_watertight
    assert not r_tsdf["watertight"] and r_tsdf["boundary_edges"] > 20
    assert not r_plain["watertight"] and r_plain["boundary_edges"] > 20
    # the ring never sees the bottom: the closed surface invents it, the trimmed ones (almost) nothing
    assert 0.05 < r_closed["invented_fraction"] < 0.4, r_closed
    assert r_plain["invented_fraction"] < 0.04 and r_tsdf["invented_fraction"] < 0.01, (r_plain, r_tsdf)
    # the invented part is where the cameras did not look: the bottom (the ring is 20 deg above it)
    from scipy.spatial import cKDTree

    from photorecon.fusion import observed_points

    pts = closed.sample(20_000)
    d, _ = cKDTree(observed_points(frames, r_closed["invent_distance"] / 2)).query(pts)
    invented = pts[d > r_closed["invent_distance"]]
    assert np.percentile(invented[:, 2], 90) < -0.5, np.percentile(invented[:, 2], [10, 50, 90])
    gt = trimesh.load(ring_small / "gt_mesh.ply", process=False)
    assert closed.bounds[0, 2] > gt.bounds[0, 2] - 0.05  # closed, not ballooned below the truth
    # the observed part stays accurate
    assert mesh_metrics(plain, gt, n_samples=20_000).precision > 0.99


def test_bad_input_no_usable_points_and_watertight_without_poisson():
    intr = Intrinsics(32, 24, 30.0, 30.0, 15.5, 11.5)
    lone = np.zeros((24, 32), np.float32)
    lone[5, 5] = 2.0  # a single pixel: no neighbours, no normal
    with pytest.raises(NoDepthError, match="usable depth points"):
        fuse([DepthFrame(View("v", intr, look_at([0, 0, -2], [0, 0, 0], up=[0, -1, 0])), lone)], FusionConfig(mesher="poisson"))
    with pytest.raises(BadArgumentError, match="--watertight needs --mesher poisson"):
        fuse([], FusionConfig(mesher="tsdf", watertight=True))


def test_cli_poisson_bad_input_exit_codes(tmp_path, ring_small):
    import shutil

    from photorecon.cli import main

    bad = tmp_path / "bad"
    shutil.copytree(ring_small, bad)
    for p in (bad / "depth").glob("*.npy"):
        np.save(p, np.zeros(np.load(p).shape, np.float32))
    assert main(["-q", "fuse", str(bad), "-o", str(tmp_path / "o1"), "--mesher", "poisson"]) == 6
    assert not (tmp_path / "o1" / "mesh.ply").exists()
    assert main(["-q", "fuse", str(ring_small), "-o", str(tmp_path / "o2"), "--watertight"]) == 2


def _sphere_at(center, radius, subdiv=3):
    s = trimesh.creation.icosphere(subdivisions=subdiv, radius=radius)
    s.apply_translation(center)
    return s


def test_floaters_dropped_details_kept():
    """A small component far from the main surface goes; a small one close to it (a detail) and the main
    surface stay; tiny debris goes wherever it is."""
    main = _sphere_at((0, 0, 0), 1.0, 4)
    near = _sphere_at((1.12, 0, 0), 0.08)  # 4% of the diagonal (3.5) from the surface, 0.6% of its area
    far = _sphere_at((6, 0, 0), 0.15)  # 5 units away, 2% of the area
    debris = _sphere_at((0, 1.03, 0), 0.005, 1)
    mesh = trimesh.util.concatenate([main, near, far, debris])
    out = clean(mesh, CleanConfig())
    x = out.vertices[:, 0]
    assert x.max() < 1.3 and x.max() > 1.15  # the far sphere went, the near one stayed
    assert len(out.faces) == len(main.faces) + len(near.faces)  # so did the debris
    assert out.vertices[:, 1].max() < 1.01
    # "far" is relative to the scene: with cameras close by (1.5 from the centre, less than the scene's 3.4
    # extent) the same gap of 0.04 counts as far at floater_distance 0.02 (0.03), not without them (0.068)
    cams = np.array([[0, 0, 1.5], [0, 0, -1.5], [0, 1.5, 0]])
    assert len(clean(mesh, CleanConfig(floater_distance=0.02)).faces) == len(main.faces) + len(near.faces)
    assert len(clean(mesh, CleanConfig(floater_distance=0.02), cameras=cams).faces) == len(main.faces)
    # floater_distance large keeps both small spheres; the grid default keeps everything
    loose = clean(mesh, CleanConfig(floater_distance=10.0))
    assert len(loose.faces) == len(main.faces) + len(near.faces) + len(far.faces)


def test_preview_frames_the_bulk_not_a_far_fragment():
    main = _sphere_at((0, 0, 0), 1.0, 4)
    far = _sphere_at((30, 0, 0), 0.1)
    center, radius = bulk_frame(trimesh.util.concatenate([main, far]))
    assert np.linalg.norm(center) < 0.1 and 0.9 < radius < 1.1
    lo, hi = trimesh.util.concatenate([main, far]).bounds
    assert np.linalg.norm((lo + hi) / 2) > 10  # what the bounding box would have framed


def test_boundary_edges_counts_hole_rims():
    s = trimesh.creation.icosphere(subdivisions=2)
    assert boundary_edges(s) == 0
    assert boundary_edges(trimesh.Trimesh(s.vertices, s.faces[1:], process=False)) == 3


@pytest.mark.slow
def test_bunny_demo_article_vs_fused_vs_watertight(tmp_path):
    """``photorecon demo --scene bunny`` at a tiny size (12 ring views, 160x120): the article's concatenated grids
    are doubled shells almost everywhere, the fused surfaces are single; the watertight one is closed, closes
    the unseen bottom (recall above the open TSDF's) and stays close to the bunny. Measured: F@1% 0.944
    (precision 0.938, recall 0.950), invented 10%, article doubled 0.99, TSDF 0.001."""
    from photorecon.demo import DemoConfig, run_bunny_demo
    from photorecon.io.images import read_image

    s = run_bunny_demo(tmp_path / "bunny", DemoConfig(scene="bunny", views=12, width=160, height=120))
    rows = {r["method"]: r for r in s["rows"]}
    art, tsdf, wt = rows["article"], rows["tsdf"], rows["watertight"]
    assert art["doubled_shells"] > 0.9 and tsdf["doubled_shells"] < 0.05 and wt["doubled_shells"] < 0.05, rows
    assert wt["watertight"] and wt["boundary_edges"] == 0, wt
    assert not tsdf["watertight"] and not art["watertight"]
    assert wt["fscore_1pct"] >= 0.93 and wt["precision_1pct"] >= 0.92, wt
    assert wt["recall_1pct"] > tsdf["recall_1pct"] + 0.05, (wt, tsdf)
    assert 0.03 < wt["invented_fraction"] < 0.2 and tsdf["invented_fraction"] < 0.01, (wt, tsdf)
    # what the cameras saw is right (seen F@1% ~1); the loss is in the part no camera saw, the guessed base
    assert wt["seen"]["fscore"] > 0.98 and tsdf["seen"]["fscore"] > 0.95, (wt["seen"], tsdf["seen"])  # 0.996, 0.971
    assert wt["unseen"]["fscore"] < wt["seen"]["fscore"] - 0.1 and wt["unseen"]["share_truth"] > 0.03, wt
    img = read_image(tmp_path / "bunny" / "side_by_side.png")
    assert img.shape[1] == 3 * (img.shape[0] // 2)  # three columns (methods), two rows (side, below)
    for k in range(3):  # every column shows a bunny, not a blank tile
        col = img[:, k * img.shape[0] // 2:(k + 1) * img.shape[0] // 2]
        assert (col.min(2) < 200).mean() > 0.05


def test_watertight_patch_colour_follows_its_rim():
    """A sphere cut open below z = -0.3, its colour linear in x and y (red and blue ramps): the patch that
    --watertight invents over the opening gets the rim's colours diffused across it, so inside the patch the
    colour stays close to the same linear ramp (a harmonic function reproduces it), not the flat or nearest-rim
    colour (which copies the rim's colour inward: 28 of 255 off on average, against 9 measured)."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    from photorecon.fusion.poisson import _close

    def ramp(p):
        return np.stack([(p[:, 0] + 1) / 2, np.full(len(p), 0.5), 1 - (p[:, 1] + 1) / 2], 1)

    sph = trimesh.creation.icosphere(4)
    cap = trimesh.Trimesh(sph.vertices, sph.faces[sph.triangles_center[:, 2] > -0.3], process=False)
    cap.remove_unreferenced_vertices()
    cap.visual.vertex_colors = (np.c_[ramp(cap.vertices), np.ones(len(cap.vertices))] * 255).astype(np.uint8)
    pts, fi = trimesh.sample.sample_surface(cap, 30000, seed=1)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    cloud.normals = o3d.utility.Vector3dVector(cap.face_normals[fi])
    cloud.colors = o3d.utility.Vector3dVector(ramp(pts))
    cell = 2.2 / 64
    closed = _close(cap, cloud, 6, cell)
    assert closed.is_watertight
    d, _ = cKDTree(pts).query(closed.vertices)
    invented = d > 3 * cell
    assert invented.sum() > 500
    col = np.asarray(closed.visual.vertex_colors)[invented, :3] / 255.0
    err = np.abs(col - ramp(closed.vertices[invented]))[:, [0, 2]] * 255
    assert err.mean() < 14 and np.percentile(err, 90) < 35, (err.mean(), np.percentile(err, 90))
    # not flat: the patch spans most of the rim's range of red
    assert np.ptp(col[:, 0]) > 0.6


@pytest.mark.slow
def test_poisson_surface_gives_the_same_mesh_every_time():
    """The same oriented points give the same Poisson surface, vertex for vertex (Open3D's Poisson on more than
    one thread gives a different mesh each run: here 3 different ones in 3 runs of a noisy sphere)."""
    import open3d as o3d

    from photorecon.mesh import poisson_surface

    rng = np.random.default_rng(0)
    s = trimesh.creation.icosphere(subdivisions=6)
    P = np.asarray(s.vertices) * (1 + 0.01 * rng.standard_normal((len(s.vertices), 1)))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    cloud.normals = o3d.utility.Vector3dVector(np.array(s.vertex_normals, np.float64))
    runs = [poisson_surface(cloud, 8)[0] for _ in range(3)]
    V0 = np.asarray(runs[0].vertices)
    assert np.abs(np.linalg.norm(V0, axis=1) - 1).max() < 0.05  # the sphere
    for m in runs[1:]:
        assert np.array_equal(np.asarray(m.vertices), V0)
        assert np.array_equal(np.asarray(m.triangles), np.asarray(runs[0].triangles))
