"""Convention converters: round trips on random poses, semantic tests that pin meaning, hand-computed values."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from photorecon import conventions as cv
from photorecon.cameras import Intrinsics, camera_center, look_at, project, transform_points

rng = np.random.default_rng(0)


def random_pose(rng):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    T[:3, 3] = rng.normal(size=3) * 5
    return T


POSES = [random_pose(rng) for _ in range(50)]


def roundtrips():
    yield "colmap", lambda T: cv.opencv_from_colmap(*cv.colmap_from_opencv(T))
    yield "opengl", lambda T: cv.opencv_from_opengl(cv.opengl_from_opencv(T))
    yield "blender", lambda T: cv.opencv_from_blender(cv.blender_from_opencv(T))
    for w in cv.NERF_WORLDS:
        yield f"nerf-{w}", lambda T, w=w: cv.opencv_from_nerf(cv.nerf_from_opencv(T, w), w)
    yield "pytorch3d", lambda T: cv.opencv_from_pytorch3d(*cv.pytorch3d_from_opencv(T))
    yield "open3d", lambda T: cv.opencv_from_open3d(cv.open3d_extrinsic(T))
    # chains through two foreign conventions
    yield "colmap->gl->p3d", lambda T: cv.opencv_from_pytorch3d(*cv.pytorch3d_from_opencv(
        cv.opencv_from_opengl(cv.opengl_from_opencv(cv.opencv_from_colmap(*cv.colmap_from_opencv(T))))))


@pytest.mark.parametrize("name,fn", list(roundtrips()), ids=[n for n, _ in roundtrips()])
def test_roundtrip_random_poses(name, fn):
    for T in POSES:
        np.testing.assert_allclose(fn(T), T, atol=1e-9, rtol=0)


def test_intrinsics_roundtrips():
    intr = Intrinsics(640, 480, 500.5, 510.25, 318.3, 241.7)
    for space in ("screen", "ndc"):
        back = cv.intrinsics_from_pytorch3d(cv.pytorch3d_intrinsics(intr, space), 640, 480, space)
        for k in ("fx", "fy", "cx", "cy"):
            assert abs(getattr(back, k) - getattr(intr, k)) < 1e-9
    for model, params in [("SIMPLE_PINHOLE", [500, 320, 240]), ("PINHOLE", [500, 501, 320, 240]),
                          ("SIMPLE_RADIAL", [500, 320, 240, 0.01]), ("RADIAL", [500, 320, 240, 0.01, -0.002]),
                          ("OPENCV", [500, 501, 320, 240, 0.01, -0.002, 0.001, 0.0005])]:
        i = cv.intrinsics_from_colmap(model, 640, 480, params)
        assert cv.colmap_from_intrinsics(i) == (model, 640, 480, [float(p) for p in params])
    o3 = cv.intrinsics_from_open3d(cv.open3d_intrinsic(intr))
    assert (o3.fx, o3.fy, o3.cx, o3.cy) == (intr.fx, intr.fy, intr.cx, intr.cy)


# --- semantic tests -------------------------------------------------------------------------------------
INTR = Intrinsics(640, 480, 500.0, 500.0, 319.5, 239.5)


def test_opencv_identity_camera_sees_plus_z():
    uv, z = project([[0, 0, 1], [1, 0, 1], [0, 1, 1]], INTR, np.eye(4))
    np.testing.assert_allclose(uv[0], [INTR.cx, INTR.cy])
    assert uv[1, 0] > INTR.cx and abs(uv[1, 1] - INTR.cy) < 1e-12  # +x world -> right
    assert uv[2, 1] > INTR.cy  # +y world -> down
    assert z[0] == 1


def test_opengl_identity_camera_looks_down_minus_z():
    T_cv = cv.opencv_from_opengl(np.eye(4))
    uv, z = project([[0, 0, -1], [0, 1, -1], [1, 0, -1]], INTR, T_cv)
    assert z[0] == pytest.approx(1.0)
    np.testing.assert_allclose(uv[0], [INTR.cx, INTR.cy])
    assert uv[1, 1] < INTR.cy  # +y is up in OpenGL -> upper half of the image
    assert uv[2, 0] > INTR.cx  # +x is right


def test_pytorch3d_identity_sees_plus_x_on_the_left():
    T_cv = cv.opencv_from_pytorch3d(np.eye(3), np.array([0.0, 0.0, 3.0]))
    uv, z = project([[1, 0, 0], [0, 1, 0], [0, 0, 0]], INTR, T_cv)
    assert np.all(z == 3)
    assert uv[0, 0] < INTR.cx  # +x world on the left half
    assert uv[1, 1] < INTR.cy  # +y world in the upper half
    np.testing.assert_allclose(uv[2], [INTR.cx, INTR.cy])


def test_pytorch3d_projection_matches_article_K():
    """Project with PyTorch3D's own formulas (row vectors, 4x4 K, NDC) and compare with OpenCV pixels."""
    T = look_at([2.0, -1.0, 1.5], [0.1, 0.2, 0.0])
    R, t = cv.pytorch3d_from_opencv(T)
    pts = rng.normal(size=(20, 3)) * 0.3
    uv_cv, _ = project(pts, INTR, T)
    X_view = pts @ R + t
    for space in ("screen", "ndc"):
        K = cv.pytorch3d_intrinsics(INTR, space)
        h = np.c_[X_view, np.ones(len(X_view))] @ K.T
        xy = h[:, :2] / h[:, 3:4]
        if space == "ndc":
            s = min(INTR.width, INTR.height) / 2
            # PyTorch3D NDC: +x left, +y up; pixel centre i sits at continuous coordinate i + 0.5
            u = INTR.width / 2 - xy[:, 0] * s - 0.5
            v = INTR.height / 2 - xy[:, 1] * s - 0.5
        else:
            # screen K applies to view coordinates whose x, y point left/up; the image axes point right/down
            u = 2 * (INTR.cx + 0.5) - xy[:, 0] - 0.5
            v = 2 * (INTR.cy + 0.5) - xy[:, 1] - 0.5
        np.testing.assert_allclose(np.c_[u, v], uv_cv, atol=1e-9)


def test_colmap_quaternion_by_hand():
    """A 90-degree rotation about z: q = (cos 45, 0, 0, sin 45), computed here by hand."""
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [1, 2, 3]
    q, t = cv.colmap_from_opencv(T)
    h = np.sqrt(0.5)
    np.testing.assert_allclose(q, [h, 0, 0, h], atol=1e-12)
    np.testing.assert_allclose(t, [1, 2, 3])


def test_opengl_by_hand():
    """OpenCV camera at (0, 0, 5) looking at the origin with image-down = -z... computed by hand."""
    T = look_at([0, -5, 0], [0, 0, 0], up=[0, 0, 1])
    # camera looks along +y; x right = (1,0,0); y down = (0,0,-1)
    np.testing.assert_allclose(T[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)
    M = cv.opengl_from_opencv(T)
    # camera-to-world in GL axes: columns = GL x (right), y (up), z (backward) in world; then the centre
    expected = np.array([[1, 0, 0, 0], [0, 0, -1, -5], [0, 1, 0, 0], [0, 0, 0, 1]], float)
    np.testing.assert_allclose(M, expected, atol=1e-12)


def test_nerf_world_orientations_by_hand():
    T = look_at([1.0, 2.0, 3.0], [0, 0, 0])
    c = camera_center(T)
    for world, expect in [("none", c), ("instant-ngp", [c[1], c[0], -c[2]]), ("nerfstudio", [c[0], c[2], -c[1]])]:
        M = cv.nerf_from_opencv(T, world)
        np.testing.assert_allclose(M[:3, 3], expect, atol=1e-12)
        assert np.linalg.det(M[:3, :3]) == pytest.approx(1.0)


def test_look_at_puts_target_at_principal_point():
    for eye in rng.normal(size=(10, 3)) * 4:
        target = rng.normal(size=3)
        uv, z = project(target[None], INTR, look_at(eye, target))
        np.testing.assert_allclose(uv[0], [INTR.cx, INTR.cy], atol=1e-9)
        assert z[0] == pytest.approx(np.linalg.norm(eye - target))


def test_look_at_up_is_image_up():
    T = look_at([3, 0, 0], [0, 0, 0], up=[0, 0, 1])
    uv, _ = project([[0, 0, 1]], INTR, T)
    assert uv[0, 1] < INTR.cy


# --- bad input ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("bad,msg", [
    (np.diag([1.0, 1.0, 1.1, 1.0]), "orthonormal"),
    (np.diag([1.0, 1.0, -1.0, 1.0]), "det"),
    (np.eye(3), "shape"),
    (np.full((4, 4), np.nan), "NaN"),
])
def test_bad_poses_raise_value_error(bad, msg):
    for fn in (cv.colmap_from_opencv, cv.opengl_from_opencv, cv.pytorch3d_from_opencv, cv.nerf_from_opencv,
               cv.open3d_extrinsic, lambda T: transform_points(T, np.zeros((1, 3))) if msg == "shape" else cv.opencv_from_opengl(T)):
        with pytest.raises(ValueError, match=msg):
            fn(bad)


def test_bad_quaternion_and_world_names():
    with pytest.raises(ValueError, match="unit quaternion"):
        cv.opencv_from_colmap([1, 1, 0, 0], [0, 0, 0])
    with pytest.raises(ValueError, match="expected one of"):
        cv.nerf_from_opencv(np.eye(4), "blender-world")
    with pytest.raises(ValueError, match="expected shape"):
        cv.opencv_from_pytorch3d(np.eye(3), [0, 0])


def test_colmap_half_pixel_is_semantic():
    """COLMAP's image centre of a 640x480 camera is (320, 240); photorecon's is (319.5, 239.5): the centre of
    the top-left pixel is (0.5, 0.5) there and (0, 0) here. Points and principal points shift alike."""
    i = cv.intrinsics_from_colmap("PINHOLE", 640, 480, [500, 500, 320, 240])
    assert (i.cx, i.cy) == ((640 - 1) / 2, (480 - 1) / 2)
    top_left_centre_colmap = np.array([[0.5, 0.5]])
    np.testing.assert_array_equal(cv.opencv_from_colmap_pixels(top_left_centre_colmap), [[0.0, 0.0]])
    np.testing.assert_array_equal(cv.colmap_from_opencv_pixels([[0.0, 0.0]]), top_left_centre_colmap)
