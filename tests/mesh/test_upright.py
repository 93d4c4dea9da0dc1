"""The model's frame (mesh.upright): synthetic scenes turned by random world rotations come out +Y up, centred and
facing the cameras, whichever rule sets the frame."""
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from photorecon.cameras import Intrinsics, View, invert_rigid, look_at, look_at_views, project, rigid
from photorecon.errors import BadArgumentError, EmptyMeshError
from photorecon.mesh.upright import apply, apply_views, camera_up, upright_frame

INTR = Intrinsics.from_fov(640, 480, 60.0)
BASE = np.array([0.3, -0.2, 0.0])  # the box's base centre on the ground z = 0 (world z up before the rotation)
SIZE = np.array([0.5, 0.3, 0.4])


def _angle(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _grid(half: float, n: int, z: float = 0.0) -> trimesh.Trimesh:
    """A square (2 half) x (2 half) of n x n cells at height z, facing +z."""
    s = np.linspace(-half, half, n + 1)
    X, Y = np.meshgrid(s, s, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), (i + n + 1).ravel(), (i + n + 2).ravel(), (i + 1).ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return trimesh.Trimesh(V, F, process=False)


def _box(with_bottom: bool = True) -> trimesh.Trimesh:
    """The object: a 0.5 x 0.3 x 0.4 box turned 25 degrees about z, standing on z = 0 with its base centre at
    BASE, subdivided so its faces are small."""
    box = trimesh.creation.box(extents=SIZE)
    box = box.subdivide().subdivide()
    if not with_bottom:
        box.update_faces(box.triangles_center[:, 2] > -SIZE[2] / 2 + 1e-9)
        box.remove_unreferenced_vertices()
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 25, degrees=True).as_matrix()
    T[:3, 3] = BASE + [0, 0, SIZE[2] / 2]
    box.apply_transform(T)
    return box


def _ring(n=12, elevation=30.0, arc=360.0, radius=3.0) -> list[View]:
    target = BASE + [0, 0, 0.2]
    az = np.radians(np.linspace(0, arc, n, endpoint=arc < 360))
    el = np.radians(elevation)
    P = target + radius * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.full(n, np.sin(el))], 1)
    return [View(f"v{i:02d}", INTR, T) for i, T in enumerate(look_at_views(P, target, up=(0, 0, 1)))]


def _object_scene(noise: float = 0.0, **ring):
    """The box on a 4 x 4 table, its vertices moved by Gaussian ``noise`` (scene units), and a ring of cameras."""
    mesh = trimesh.util.concatenate([_grid(2.0, 40), _box()])
    if noise:
        mesh.vertices = mesh.vertices + np.random.default_rng(0).normal(0, noise, mesh.vertices.shape)
    return mesh, _ring(**ring)


def _turn(mesh, views, seed):
    """The scene moved by a random rigid transform W (world' = W world): (mesh', views', W)."""
    rng = np.random.default_rng(seed)
    W = rigid(Rotation.random(random_state=seed).as_matrix(), rng.normal(0, 3, 3))
    m = mesh.copy()
    m.apply_transform(W)
    inv = invert_rigid(W)
    return m, [View(v.name, v.intrinsics, v.cam_from_world @ inv) for v in views], W


def _model_from_original(up, W):
    """The whole chain from the unturned world to the model's frame."""
    return up.model_from_world @ W


@pytest.mark.parametrize("seed, noise", [(1, 0.0), (2, 0.005), (3, 0.005)])
def test_object_on_a_table_stands_on_plus_y_with_its_base_centre_at_the_origin(seed, noise):
    mesh, views = _object_scene(noise)
    m, vs, W = _turn(mesh, views, seed)
    up = upright_frame(m, vs, scene="object")
    assert up.rule == "support plane"
    M = _model_from_original(up, W)
    assert _angle(M[:3, :3] @ [0, 0, 1], [0, 1, 0]) < 2.0  # the table's normal (world z) is the model's +Y
    base = M[:3, :3] @ BASE + M[:3, 3]
    assert np.linalg.norm(base) < 0.01, base  # 2% of the box's smallest side
    top = M[:3, :3] @ (BASE + [0, 0, SIZE[2]]) + M[:3, 3]
    assert top[1] == pytest.approx(SIZE[2], abs=0.01)  # not upside down: the box's top is 0.4 above the origin
    assert np.allclose(np.linalg.det(up.model_from_world[:3, :3]), 1.0) and np.isclose(up.model_from_world[3, 3], 1)
    cams = np.array([v.center for v in apply_views(up.model_from_world, vs)])
    assert (cams[:, 1] > 1.0).all()  # the cameras above the table


def test_auto_tells_an_object_capture_and_the_plane_points_to_the_cameras():
    mesh, views = _object_scene()
    m, vs, W = _turn(mesh, views, 7)
    up = upright_frame(m, vs, scene="auto")
    assert up.rule == "support plane"
    n, c = up.plane
    assert _angle(n, W[:3, :3] @ [0, 0, 1]) < 2.0
    assert all(n @ v.center - c > 0 for v in vs)
    assert _angle(up.up_world, n) < 1e-9


def test_a_rig_of_upside_down_cameras_still_stands_on_its_table():
    mesh, views = _object_scene(0.002)
    flipped = [View(v.name, v.intrinsics, np.diag([-1.0, -1.0, 1.0, 1.0]) @ v.cam_from_world) for v in views]
    m, vs, W = _turn(mesh, flipped, 15)
    assert _angle(camera_up(vs)[0], W[:3, :3] @ [0, 0, 1]) > 178.0  # the photos' up is the world's down
    up = upright_frame(m, vs)
    assert up.rule == "support plane"
    M = _model_from_original(up, W)
    assert _angle(M[:3, :3] @ [0, 0, 1], [0, 1, 0]) < 2.0
    assert (M[:3, :3] @ (BASE + [0, 0, SIZE[2]]) + M[:3, 3])[1] > 0.39


def test_forward_faces_the_cameras_of_a_half_ring():
    mesh, views = _object_scene(n=9, arc=180.0)
    m, vs, W = _turn(mesh, views, 4)
    up = upright_frame(m, vs, scene="object")
    C = np.array([v.center for v in apply_views(up.model_from_world, vs)])
    mean = C.mean(0)
    assert mean[2] > 1.0 and abs(mean[0]) < 0.05 * mean[2]  # the cameras' mean on +Z, not off to the side
    assert _angle(np.cross(up.up_world, up.forward_world), up.model_from_world[0, :3]) < 1e-9  # X = Y x Z


def test_a_full_ring_faces_the_first_camera():
    mesh, views = _object_scene()
    m, vs, W = _turn(mesh, views, 5)
    up = upright_frame(m, vs, scene="object")
    first = apply_views(up.model_from_world, vs)[0].center
    assert abs(first[0]) < 1e-6 * np.linalg.norm(first) and first[2] > 2.0


def _facade(pitch_deg=0.0, yaw_spread_deg=0.0, n=8):
    """A wall (x from -3 to 3, z from 0 to 4 at y = 2) with boxes on it and the ground before it; cameras 3 to 5
    units in front of it at eye height (z = 1.6) looking at it, level, pitched by ``pitch_deg`` (up > 0) and
    turned up to +-``yaw_spread_deg`` from facing the wall."""
    wall = _grid(2.0, 12)
    wall.apply_transform(rigid(Rotation.from_euler("x", 90, degrees=True).as_matrix(), [0, 2.0, 2.0]))
    ground = _grid(3.0, 12)
    bumps = []
    for k, x in enumerate(np.linspace(-1.5, 1.5, 4)):
        b = trimesh.creation.box(extents=[0.4, 0.3, 0.5])
        b.apply_translation([x, 1.85, 1.0 + 0.6 * (k % 2)])
        bumps.append(b)
    mesh = trimesh.util.concatenate([wall, ground, *bumps])
    views = []
    xs = np.linspace(-2.0, 2.0, n)
    yaws = np.linspace(-yaw_spread_deg, yaw_spread_deg, n)
    for i, (x, yaw) in enumerate(zip(xs, yaws)):
        eye = np.array([x, -2.0 - (i % 2), 1.6])
        d = np.array([np.sin(np.radians(yaw)), np.cos(np.radians(yaw)), 0.0])
        d = np.cos(np.radians(pitch_deg)) * d + [0, 0, np.sin(np.radians(pitch_deg))]
        views.append(View(f"f{i:02d}", INTR, look_at(eye, eye + d, up=(0, 0, 1))))
    return mesh, views


@pytest.mark.parametrize("seed", [11, 12])
def test_open_scene_takes_the_cameras_up(seed):
    mesh, views = _facade()
    m, vs, W = _turn(mesh, views, seed)
    up = upright_frame(m, vs, scene="auto")  # side-by-side cameras with parallel axes: an open scene
    assert up.rule == "camera up"
    M = _model_from_original(up, W)
    assert _angle(M[:3, :3] @ [0, 0, 1], [0, 1, 0]) < 2.0
    for v in apply_views(up.model_from_world, vs):  # each camera's up (-y) is the model's +Y, not upside down
        assert _angle(-v.cam_from_world[1, :3], [0, 1, 0]) < 2.0
    # the origin on the ground (world z = 0) under the scene's middle; the wall faces +Z, towards the cameras
    o = M[:3, :3] @ [0, 1.0, 0] + M[:3, 3]
    assert abs(o[1]) < 0.05
    wall_normal = M[:3, :3] @ [0, -1.0, 0]
    assert _angle(wall_normal, [0, 0, 1]) < 2.0


def test_pitched_cameras_facing_different_ways_are_level_across_their_x_axes():
    mesh, views = _facade(pitch_deg=-20.0, yaw_spread_deg=40.0)
    m, vs, W = _turn(mesh, views, 13)
    up, how = camera_up(vs)
    assert "x axes" in how
    assert _angle(up, W[:3, :3] @ [0, 0, 1]) < 0.5  # exact: each camera's x axis is level
    mean = np.mean([-v.cam_from_world[1, :3] for v in vs], 0)
    assert _angle(mean, W[:3, :3] @ [0, 0, 1]) > 10.0  # the mean up leans with the pitch


def test_open_scene_given_keeps_the_ground_and_uses_camera_up_for_an_object_capture_too():
    mesh, views = _object_scene()
    m, vs, W = _turn(mesh, views, 8)
    up = upright_frame(m, vs, scene="open")
    assert up.rule == "camera up" and up.plane is None
    M = _model_from_original(up, W)
    assert _angle(M[:3, :3] @ [0, 0, 1], [0, 1, 0]) < 2.0  # the ring's cameras are level
    assert abs((M[:3, :3] @ [0, 0, 0] + M[:3, 3])[1]) < 0.02  # the ground at Y = 0


def test_the_cleaned_mesh_uses_the_support_plane_in_its_metadata():
    box = _box(with_bottom=False)
    views = _ring()
    m, vs, W = _turn(box, views, 9)
    n = W[:3, :3] @ [0, 0, 1]
    m.metadata.update(support_normal=",".join(f"{x:.6f}" for x in n), support_offset=float(n @ W[:3, 3]))
    up = upright_frame(m, vs, scene="auto")
    assert up.rule == "support plane" and "metadata" in up.reason
    M = _model_from_original(up, W)
    assert _angle(M[:3, :3] @ [0, 0, 1], [0, 1, 0]) < 0.01
    assert np.linalg.norm(M[:3, :3] @ BASE + M[:3, 3]) < 1e-3


def test_the_model_frame_of_the_moved_mesh_is_the_identity():
    mesh, views = _object_scene()
    m, vs, _ = _turn(mesh, views, 10)
    up = upright_frame(m, vs, scene="object")
    m2, vs2 = apply(up.model_from_world, m), apply_views(up.model_from_world, vs)
    again = upright_frame(m2, vs2, scene="object")
    assert np.abs(again.model_from_world[:3, :3] - np.eye(3)).max() < 0.02
    assert np.abs(again.model_from_world[:3, 3]).max() < 0.01
    assert len(m2.vertices) == len(m.vertices) and np.array_equal(m2.faces, m.faces)


def test_moved_cameras_see_the_moved_mesh_where_they_saw_the_mesh():
    mesh, views = _object_scene()
    m, vs, _ = _turn(mesh, views, 6)
    up = upright_frame(m, vs, scene="object")
    m2, vs2 = apply(up.model_from_world, m), apply_views(up.model_from_world, vs)
    for v, v2 in zip(vs[:3], vs2[:3]):
        uv, z = project(m.vertices, v.intrinsics, v.cam_from_world)
        uv2, z2 = project(m2.vertices, v2.intrinsics, v2.cam_from_world)
        assert np.allclose(uv, uv2, atol=1e-6) and np.allclose(z, z2, atol=1e-9)
        assert v2.name == v.name
    assert m.metadata.get("support_normal") is None and vs[0].cam_from_world is not vs2[0].cam_from_world


def test_apply_moves_the_support_plane_in_the_metadata():
    box = _box(with_bottom=False)
    box.metadata.update(support_normal="0,0,1", support_offset=0.0)
    T = rigid(Rotation.from_euler("x", -90, degrees=True).as_matrix(), [1.0, 2.0, 3.0])
    out = apply(T, box)
    n = np.array([float(x) for x in out.metadata["support_normal"].split(",")])
    assert np.allclose(n, [0, 1, 0], atol=1e-5)  # (x, y, z) -> (x, z, -y) + (1, 2, 3): z = 0 becomes y = 2
    assert out.metadata["support_offset"] == pytest.approx(2.0)
    assert box.metadata["support_normal"] == "0,0,1"  # the input untouched


def test_the_same_inputs_give_the_same_frame():
    mesh, views = _object_scene()
    m, vs, _ = _turn(mesh, views, 3)
    a, b = upright_frame(m, vs), upright_frame(m, vs)
    assert np.array_equal(a.model_from_world, b.model_from_world) and a.rule == b.rule and a.reason == b.reason
    d = a.to_dict()
    assert d["rule"] == "support plane" and len(d["model_from_world"]) == 4 and "support_plane" in d


def test_an_empty_mesh_is_a_clear_error():
    with pytest.raises(EmptyMeshError, match="no vertex"):
        upright_frame(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)), _ring())


def test_bad_arguments_are_clear_errors():
    mesh, views = _object_scene()
    with pytest.raises(BadArgumentError, match="scene expected"):
        upright_frame(mesh, views, scene="indoor")
    with pytest.raises(BadArgumentError, match="no camera and no support plane"):
        upright_frame(mesh, [], scene="open")
    with pytest.raises(BadArgumentError, match="rigid"):
        apply(np.diag([2.0, 2.0, 2.0, 1.0]), mesh)


def test_a_single_camera_gives_its_own_up():
    mesh, views = _object_scene()
    m, vs, W = _turn(mesh, views, 14)
    up = upright_frame(m, vs[:1], scene="auto")
    assert up.rule == "camera up" and "1 camera" in up.reason
    assert _angle(up.up_world, -vs[0].cam_from_world[1, :3]) < 1e-9
    assert up.model_from_world[2, :3] @ (vs[0].center - up.origin_world) > 0  # facing it
