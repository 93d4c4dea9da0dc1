import numpy as np
import pytest

from photorecon.cameras import (Intrinsics, backproject_depth, camera_center, invert_rigid, look_at, look_at_views,
                                project, ring_positions, sphere_positions)
from photorecon.conventions import intrinsics_from_colmap
from photorecon.errors import BadArgumentError

rng = np.random.default_rng(1)


@pytest.mark.parametrize("intr", [
    Intrinsics(640, 480, 500, 500, 319.5, 239.5),
    intrinsics_from_colmap("SIMPLE_RADIAL", 640, 480, [520, 320, 240, -0.08]),
    intrinsics_from_colmap("RADIAL", 640, 480, [520, 320, 240, -0.08, 0.01]),
    intrinsics_from_colmap("OPENCV", 640, 480, [520, 515, 322, 238, -0.1, 0.02, 0.001, -0.0015]),
])
def test_backprojected_depth_projects_to_its_pixels(intr):
    T = look_at([1.0, -2.0, 0.5], [0.0, 0.0, 0.0])
    depth = rng.uniform(1.0, 4.0, size=(intr.height, intr.width))
    depth[::7, ::5] = 0  # invalid pixels are skipped
    pts, uv = backproject_depth(depth, intr, T, return_pixels=True)
    assert len(pts) == np.count_nonzero(depth)
    uv2, z = project(pts, intr, T)
    np.testing.assert_allclose(uv2, uv, atol=1e-6)
    np.testing.assert_allclose(z, depth[depth > 0], rtol=1e-9)
    # pixels come in row-major order: (0, 0) is skipped (depth 0), the next one is column 1 of row 0
    assert depth[0, 0] == 0 and uv[0].tolist() == [1.0, 0.0]


def test_backprojection_grid_orientation():
    """A wide, short image: the pixel to the right of centre maps to +x in the camera, below to +y."""
    intr = Intrinsics(8, 4, 10.0, 10.0, 3.5, 1.5)
    depth = np.ones((4, 8))
    pts, uv = backproject_depth(depth, intr, np.eye(4), return_pixels=True)
    right = pts[(uv[:, 0] == 7) & (uv[:, 1] == 1)][0]
    below = pts[(uv[:, 0] == 3) & (uv[:, 1] == 3)][0]
    assert right[0] == pytest.approx(0.35) and below[1] == pytest.approx(0.15)


def test_mask_and_shape_checks():
    intr = Intrinsics(4, 3, 5, 5, 1.5, 1)
    with pytest.raises(ValueError, match=r"expected shape \(H, W\) = \(3, 4\)"):
        backproject_depth(np.ones((4, 3)), intr, np.eye(4))
    d = np.ones((3, 4))
    d[0, 0] = np.nan
    d[0, 1] = -1
    m = np.ones((3, 4), bool)
    m[2, 3] = False
    assert len(backproject_depth(d, intr, np.eye(4), mask=m)) == 12 - 3


def test_scaled_intrinsics_map_pixel_centres():
    intr = Intrinsics(640, 480, 500, 500, 319.5, 239.5)
    half = intr.scaled(320, 240)
    assert (half.fx, half.cx, half.cy) == (250, 159.5, 119.5)
    # the same 3D point lands on corresponding pixels: u' = (u + 0.5) * s - 0.5
    p = np.array([[0.3, -0.2, 2.0]])
    u, _ = project(p, intr, np.eye(4))
    u2, _ = project(p, half, np.eye(4))
    np.testing.assert_allclose(u2, (u + 0.5) * 0.5 - 0.5)


def test_colmap_pixel_centre_shift():
    intr = intrinsics_from_colmap("PINHOLE", 640, 480, [500, 500, 320, 240])
    assert (intr.cx, intr.cy) == (319.5, 239.5)


def test_from_fov():
    intr = Intrinsics.from_fov(640, 480, 90.0)
    assert intr.fx == pytest.approx(320.0)
    uv, _ = project([[1.0, 0, 1.0]], intr, np.eye(4))  # 45 degrees right = right image edge (pixel 639.5)
    assert uv[0, 0] == pytest.approx(639.5)


def test_rigs():
    ring = ring_positions(12, 2.0, elevation_deg=30)
    assert np.allclose(np.linalg.norm(ring, axis=1), 2.0) and np.allclose(ring[:, 2], 1.0)
    sph = sphere_positions(100, 3.0)
    assert np.allclose(np.linalg.norm(sph, axis=1), 3.0)
    assert sph[:, 2].min() < -2.5 and sph[:, 2].max() > 2.5  # covers top and bottom
    hemi = sphere_positions(50, 3.0, hemisphere=True)
    assert hemi[:, 2].min() > 0
    views = look_at_views(np.r_[sph, [[0, 0, 3.0]]])
    intr = Intrinsics.from_fov(64, 48, 60)
    for T in views:
        uv, _ = project(np.zeros((1, 3)), intr, T)
        np.testing.assert_allclose(uv[0], [intr.cx, intr.cy], atol=1e-9)
    np.testing.assert_allclose(camera_center(views[0]), sph[0])
    np.testing.assert_allclose(invert_rigid(views[0]) @ views[0], np.eye(4), atol=1e-12)


@pytest.mark.parametrize("kwargs,msg", [
    (dict(width=0, height=10, fx=1, fy=1, cx=0, cy=0), "positive"),
    (dict(width=10, height=10, fx=-1, fy=1, cx=0, cy=0), "focal"),
    (dict(width=10, height=10, fx=np.nan, fy=1, cx=0, cy=0), "finite"),
    (dict(width=10, height=10, fx=1, fy=1, cx=0, cy=0, model="FISHEYE"), "expected one of"),
    (dict(width=10, height=10, fx=1, fy=1, cx=0, cy=0, k1=0.1), "no parameter k1"),
])
def test_bad_intrinsics(kwargs, msg):
    with pytest.raises(ValueError, match=msg):
        Intrinsics(**kwargs)


def test_look_at_degenerate():
    with pytest.raises(BadArgumentError, match="parallel"):
        look_at([0, 0, 3], [0, 0, 0], up=[0, 0, 1])
    with pytest.raises(BadArgumentError, match="coincide"):
        look_at([1, 1, 1], [1, 1, 1])
