"""The textured model's frame (mesh.model.model_frame, reconstruct's model stage): OUT/model.glb stands upright in
glTF's frame (+Y up) whatever the reconstruction's frame, an object on its support plane with its base centre at
the origin, an open scene up along its cameras' up; report.json gives the rule and the transform from the
reconstruction's frame (mesh.ply, sparse/0, transforms.json), which stay as they were. Synthetic scenes: a box on
a table rendered by a ring of cameras, the cameras given in a randomly turned world."""
import json

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from photorecon.cameras import View, invert_rigid, rigid
from photorecon.cli import main
from photorecon.io.cameras.transforms import write_transforms
from photorecon.io.dataset import Dataset
from photorecon.mesh.export import load_mesh
from photorecon.mesh.model import frame_info, model_frame
from photorecon.mesh.upright import apply_views

BOX = np.array([0.5, 0.4, 0.45])  # the object: a box standing on the table z = 0, turned 20 degrees about z
BASE = np.array([0.25, -0.15, 0.0])  # its base centre (before the synthetic scene's normalisation)
TURN_SEED = 5


def _angle(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _scene_mesh() -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=BOX).subdivide().subdivide()
    T = rigid(Rotation.from_euler("z", 20, degrees=True).as_matrix(), BASE + [0, 0, BOX[2] / 2])
    box.apply_transform(T)
    table = trimesh.creation.box(extents=(2.4, 2.4, 0.02)).apply_translation((0, 0, -0.01))
    return trimesh.util.concatenate([box, table])


@pytest.fixture(scope="module")
def turned_capture(tmp_path_factory):
    """The box on its table seen by 12 ring cameras at 200x150 with rendered depth maps, the cameras given in
    a world turned by a random rigid W (world' = W world; photos and depth maps do not change). Returns
    (folder, W, the box's base centre and the table's normal in the turned world, scene scale)."""
    from photorecon.synthetic import SynthConfig, synthesize

    root = tmp_path_factory.mktemp("frame")
    src = root / "scene.ply"
    _scene_mesh().export(src)
    data = root / "data"
    synthesize(SynthConfig(mesh=str(src), rig="ring", views=12, width=200, height=150, radius=3.0,
                           elevation=30.0, points=500, seed=2), data)
    norm = json.loads((data / "scene.json").read_text())["normalization"]
    centre, scale = np.array(norm["center"]), float(norm["scale"])
    views = Dataset.open(data).views
    rng = np.random.default_rng(TURN_SEED)
    W = rigid(Rotation.random(random_state=TURN_SEED).as_matrix(), rng.normal(0, 3, 3))
    inv = invert_rigid(W)
    turned = [View(v.name, v.intrinsics, v.cam_from_world @ inv, image_file=v.image_file) for v in views]
    write_transforms(turned, data / "transforms.json", world="none", depth_dir="depth", mask_dir="masks")
    base = W[:3, :3] @ ((BASE - centre) / scale) + W[:3, 3]
    return data, W, base, W[:3, :3] @ [0, 0, 1.0], 1.0 / scale


def _reconstruct(data, out, *flags):
    assert main(["-q", "reconstruct", str(data / "images"), "-o", str(out), "--poses", str(data / "transforms.json"),
                 "--depth", str(data / "depth"), "--model-faces", "20000", *flags]) == 0
    return json.loads((out / "report.json").read_text())


def _glb(path) -> trimesh.Trimesh:
    return trimesh.load(path, process=False, force="mesh")


def _surface_distance(mesh: trimesh.Trimesh, pts: np.ndarray) -> np.ndarray:
    import open3d as o3d

    from photorecon.mesh.convert import raycasting_scene

    return raycasting_scene(mesh).compute_distance(o3d.core.Tensor(np.asarray(pts, np.float32))).numpy()


@pytest.mark.slow
def test_an_object_capture_stands_on_its_table_with_its_base_centre_at_the_origin(turned_capture, tmp_path):
    """model.glb of the box (its table removed by the cleaning) read back with trimesh: the table's normal
    within 2 degrees of +Y (through the reported transform, and fitted to the model's lowest vertices), the
    base centre within a voxel of the origin, nothing below the table; report.json names the rule, and its
    model_from_reconstruction maps the model's source, the closed companion mesh_closed.ply, onto the model
    (simplified: 99% of the model's points within half a voxel of the moved mesh_closed.ply). mesh.ply and the
    cameras stay in the reconstruction's frame."""
    data, W, base, normal, unit = turned_capture
    out = tmp_path / "out"
    rep = _reconstruct(data, out, "--formats", "ply,glb,obj")
    assert rep["mesh"]["scene"]["detected"] == "object"
    frame = rep["texture"]["frame"]
    assert frame["rule"] == "support plane" and frame["units"].startswith("scene units")
    T = np.array(frame["model_from_reconstruction"])
    assert T.shape == (4, 4) and np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    voxel = rep["mesh"]["voxel_size"]
    assert _angle(T[:3, :3] @ normal, [0, 1, 0]) < 0.5  # the true table's normal, in the model's frame: 0.01
    assert np.linalg.norm(T[:3, :3] @ base + T[:3, 3]) < voxel  # the true base centre at the origin: 0.3 voxel
    model = _glb(out / "model.glb")
    V = np.asarray(model.vertices)
    assert V[:, 1].min() > -voxel  # nothing under the table (the cut is 2-4 voxels above it)
    low = V[V[:, 1] < V[:, 1].min() + voxel]  # the box's cut-open bottom edge: a plane across +Y
    _, _, vt = np.linalg.svd(low - low.mean(0))
    assert len(low) > 20 and _angle(vt[2] * np.sign(vt[2][1]), [0, 1, 0]) < 2.0
    # the box, 0.45 high before normalisation, stands 0.45 * unit high
    assert abs(V[:, 1].max() - BOX[2] * unit) < 2 * voxel
    # the transform brings the model's source (an object's closed companion, mesh_closed.ply, in the
    # reconstruction's frame) onto the model
    assert rep["texture"]["surface"] == "closed"
    full = load_mesh(out / "mesh.ply")
    moved = load_mesh(out / "mesh_closed.ply")
    moved.apply_transform(T)
    pts = trimesh.sample.sample_surface(model, 5000, seed=0)[0]
    d = _surface_distance(moved, pts)
    assert np.percentile(d, 99) < 0.5 * voxel, (np.percentile(d, 99) / voxel)
    assert np.allclose(moved.bounds, model.bounds, atol=voxel)
    # mesh.ply stays in the reconstruction's frame, where the turned world has the box
    gt = load_mesh(data / "gt_mesh.ply")
    gt.apply_transform(W)
    d = _surface_distance(gt, trimesh.sample.sample_surface(full, 5000, seed=1)[0])
    assert np.percentile(d, 95) < voxel, (np.percentile(d, 95) / voxel)
    # model.obj: the same vertices as model.glb
    obj = trimesh.load(out / "model.obj", process=False, force="mesh")
    assert np.allclose(obj.bounds, model.bounds, atol=1e-5)
    # the cameras brought into the model's frame see the model where they saw mesh.ply (sparse/0 unchanged)
    views = Dataset.open(out).views
    given = {v.name: v for v in Dataset.open(data).views}
    for v in views[:3]:
        assert np.allclose(v.cam_from_world, given[v.name].cam_from_world @ invert_rigid(W), atol=1e-6)
    cams = apply_views(T, views)
    assert min(c.center[1] for c in cams) > 0  # every camera above the table


@pytest.mark.slow
def test_an_open_scene_takes_its_cameras_up(turned_capture, tmp_path):
    """With --scene open the table stays: the rule is the cameras' up (the ring's cameras are level: their up is
    the table's normal), the ground at Y = 0 under the scene's median."""
    data, W, base, normal, unit = turned_capture
    out = tmp_path / "out"
    rep = _reconstruct(data, out, "--scene", "open")
    frame = rep["texture"]["frame"]
    assert frame["rule"] == "camera up" and "support_plane" not in frame
    T = np.array(frame["model_from_reconstruction"])
    assert _angle(T[:3, :3] @ normal, [0, 1, 0]) < 2.0
    V = np.asarray(_glb(out / "model.glb").vertices)
    voxel = rep["mesh"]["voxel_size"]
    table = V[np.abs(V[:, 1]) < 2 * voxel]  # the table top lies on Y = 0: most of the model's vertices
    assert len(table) > 0.3 * len(V) and abs(np.percentile(V[:, 1], 1)) < 2 * voxel


# --- model_frame without a reconstruct run -----------------------------------------------------------------------
def _ring(n=8, turn=None):
    from photorecon.cameras import Intrinsics, look_at_views

    az = np.linspace(0, 2 * np.pi, n, endpoint=False)
    P = 3 * np.stack([np.cos(az) * 0.9, np.sin(az) * 0.9, np.full(n, 0.44)], 1)
    Ts = look_at_views(P, (0, 0, 0), up=(0, 0, 1))
    views = [View(f"v{i}", Intrinsics.from_fov(320, 240, 60.0), T) for i, T in enumerate(Ts)]
    if turn is not None:
        views = [View(v.name, v.intrinsics, v.cam_from_world @ invert_rigid(turn)) for v in views]
    return views


def _ground(turn=None):
    g = trimesh.creation.box(extents=(4, 4, 0.01)).subdivide().subdivide()
    if turn is not None:
        g.apply_transform(turn)
    return g


def test_gps_sets_up_along_east_north_up_z():
    """A GPS-aligned reconstruction is east-north-up: an open scene's up is world +Z even where its cameras are
    tilted (here by 15 degrees); the model's units are metres."""
    tilt = rigid(Rotation.from_euler("x", 15, degrees=True).as_matrix(), np.zeros(3))
    views = _ring(turn=tilt)
    frame = model_frame(_ground(), views, {"scene": {"detected": "open"}}, {"units": "metre", "method": "gps"})
    assert frame.rule == "GPS up" and frame.units == "metres"
    assert _angle(frame.model_from_world[:3, :3] @ [0, 0, 1], [0, 1, 0]) < 1e-6
    plain = model_frame(_ground(), views, {"scene": {"detected": "open"}}, {"units": "arbitrary"})
    assert plain.rule == "camera up" and plain.units.startswith("scene units")
    assert abs(_angle(plain.model_from_world[:3, :3] @ (tilt[:3, :3] @ [0, 0, 1]), [0, 1, 0])) < 1e-6


def test_the_cleanings_plane_wins_over_upside_down_cameras():
    """The fusion stage's record of the plane it removed sets the frame, even when the cameras hang upside down
    (their up points into the table): the model still stands on the table; the report's frame says so."""
    views = _ring()
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # each camera rolled 180 degrees about its optical axis
    upside = [View(v.name, v.intrinsics, flip @ v.cam_from_world) for v in views]
    mesh = trimesh.creation.box(extents=(0.4, 0.4, 0.4)).subdivide().apply_translation((0.1, 0, 0.2))
    mesh.update_faces(mesh.triangles_center[:, 2] > 1e-6)  # cleaned: its bottom went with the table
    fusion = {"scene": {"detected": "object"}, "support_normal": "0,0,1", "support_offset": 0.0, "voxel_size": 0.01}
    frame = model_frame(mesh, upside, fusion, None)
    assert frame.rule == "support plane"
    assert _angle(frame.model_from_world[:3, :3] @ [0, 0, 1], [0, 1, 0]) < 1e-6
    assert np.linalg.norm(frame.model_from_world @ [0.1, 0, 0, 1] - [0, 0, 0, 1]) < 1e-6
    info = frame_info(frame)
    assert info["rule"] == "support plane" and np.allclose(info["model_from_reconstruction"], frame.model_from_world)
    assert info["reconstruction_frame"] == ["mesh.ply", "sparse/0", "transforms.json"]
    without = model_frame(mesh, upside, {"scene": {"detected": "object"}}, None)  # no plane: cameras' up
    assert without.rule == "camera up" and _angle(without.model_from_world[:3, :3] @ [0, 0, 1], [0, 1, 0]) > 170
