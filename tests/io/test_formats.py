"""Camera formats: NeRF Blender-synthetic, IDR/NeuS cameras_sphere.npz, LLFF poses_bounds.npy, per-frame
transforms.json intrinsics. Each has a semantic test (a 3D point lands on a pixel computed by hand from the
format's own definition), a round trip and bad-input tests. Pure numpy, tiny images."""
from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from photorecon.cameras import Intrinsics, View, look_at, project
from photorecon.cli import main
from photorecon.errors import InputDataError
from photorecon.io.dataset import Dataset, read_model
from photorecon.io.formats import decompose_projection, read_llff, read_neus, write_llff, write_neus
from photorecon.io.nerf import read_blender, read_transforms, write_blender


def _png(path, w, h, alpha=False):
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.full((h, w, 4 if alpha else 3), 200, np.uint8)
    if alpha:
        img[:, : w // 2, 3] = 0  # left half transparent
    cv2.imwrite(str(path), img)


def _uv(view, X):
    uv, z = project(np.array([X], float), view.intrinsics, view.cam_from_world)
    assert z[0] > 0
    return uv[0]


def _random_views(n, seed=0, w=40, h=30):
    rng = np.random.default_rng(seed)
    intr = Intrinsics(w, h, 35.0, 35.0, (w - 1) / 2, (h - 1) / 2)
    views = []
    for i in range(n):
        eye = rng.normal(size=3)
        eye = 4 * eye / np.linalg.norm(eye)
        views.append(View(f"{i:03d}", intr, look_at(eye, rng.normal(size=3) * 0.1), image_file=f"{i:03d}.png"))
    return views


# --- NeRF Blender-synthetic ----------------------------------------------------------------------------------
def _blender_scene(tmp_path, angle_y=None):
    """One 8x6 RGBA view: camera at (0, 0, 4) looking down -z (OpenGL), camera_angle_x = 2 atan(1/2)."""
    d = {"camera_angle_x": 2 * math.atan(0.5),
         "frames": [{"file_path": "./train/r_0", "rotation": 0.0,
                     "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]}]}
    if angle_y is not None:
        d["camera_angle_y"] = angle_y
    (tmp_path / "transforms_train.json").write_text(json.dumps(d))
    _png(tmp_path / "train" / "r_0.png", 8, 6, alpha=True)
    return tmp_path / "transforms_train.json"


def test_blender_point_lands_on_hand_computed_pixel(tmp_path):
    (v,) = read_transforms(_blender_scene(tmp_path))
    # fl_x = 0.5 * 8 / tan(atan(1/2)) = 8; cx, cy = W/2, H/2 = 4, 3 in NeRF pixels = 3.5, 2.5 in OpenCV pixels.
    i = v.intrinsics
    assert (i.width, i.height) == (8, 6)
    assert i.fx == pytest.approx(8) and i.fy == pytest.approx(8)
    assert (i.cx, i.cy) == pytest.approx((3.5, 2.5))
    # X = (1, 0.5, 0): OpenGL camera coords (1, 0.5, -4) -> OpenCV (1, -0.5, 4): u = 8/4 + 3.5, v = -4/4 + 2.5.
    # The point is above the axis (world +y is up in the image), so it lands in the upper half.
    assert _uv(v, [1, 0.5, 0]) == pytest.approx([5.5, 1.5])
    assert v.image_path.endswith("train/r_0.png")


def test_blender_camera_angle_y_and_folder_of_splits(tmp_path):
    path = _blender_scene(tmp_path, angle_y=2 * math.atan(0.75))  # fl_y = 0.5 * 6 / 0.75 = 4
    (v,) = read_transforms(path)
    assert v.intrinsics.fy == pytest.approx(4) and v.intrinsics.fx == pytest.approx(8)
    test = json.loads(path.read_text())
    test["frames"][0]["file_path"] = "./test/r_0"
    (tmp_path / "transforms_test.json").write_text(json.dumps(test))
    _png(tmp_path / "test" / "r_0.png", 8, 6, alpha=True)
    model = read_model(tmp_path)
    assert [w.name for w in model.views] == ["train_r_0", "test_r_0"]  # every split has its own r_0
    assert model.views[1].image_path.endswith("test/r_0.png")
    assert [w.image_file for w in model.views] == ["train/r_0.png", "test/r_0.png"]


def test_blender_alpha_is_the_mask(tmp_path):
    _blender_scene(tmp_path)
    ds = Dataset.open(tmp_path)
    m = ds.mask(ds.views[0])
    assert m.shape == (6, 8) and not m[:, :4].any() and m[:, 4:].all()
    assert ds.image(ds.views[0]).shape == (6, 8, 3)  # read as stored, alpha dropped


def test_blender_round_trip_and_cli(tmp_path):
    views = _random_views(3)
    out = write_blender(views, tmp_path / "transforms_val.json")
    d = json.loads(out.read_text())
    assert "fl_x" not in d and d["frames"][0]["file_path"] == "./val/000"
    for k in range(3):
        _png(tmp_path / "val" / f"{k:03d}.png", 40, 30)
    back = read_transforms(out)
    for a, b in zip(views, back):
        assert b.name == a.name
        np.testing.assert_allclose(b.cam_from_world, a.cam_from_world, atol=1e-12)
        assert b.intrinsics.fx == pytest.approx(a.intrinsics.fx)
        assert (b.intrinsics.cx, b.intrinsics.cy) == pytest.approx((a.intrinsics.cx, a.intrinsics.cy))
    # CLI: Blender -> transforms.json -> Blender keeps the cameras
    assert main(["-q", "convert", str(out), str(tmp_path / "t.json")]) == 0
    assert main(["-q", "convert", str(tmp_path / "t.json"), str(tmp_path / "transforms_val.json")]) == 8  # exists
    assert main(["-q", "convert", str(tmp_path / "t.json"), str(tmp_path / "transforms_val.json"), "--overwrite"]) == 0
    again = read_transforms(tmp_path / "transforms_val.json")
    np.testing.assert_allclose(again[2].cam_from_world, views[2].cam_from_world, atol=1e-12)


def test_blender_refuses_cameras_it_cannot_hold(tmp_path):
    views = _random_views(2)
    views[1] = View("x", Intrinsics(40, 30, 35.0, 35.0, 25.0, 14.5), views[1].cam_from_world)
    with pytest.raises(InputDataError, match="transforms_train.json.*principal point"):
        write_blender(views, tmp_path / "transforms_train.json")


def test_blender_missing_angle_is_one_line_exit_3(tmp_path, capsys):
    path = _blender_scene(tmp_path)
    d = json.loads(path.read_text())
    del d["camera_angle_x"]
    path.write_text(json.dumps(d))
    assert main(["-q", "convert", str(path), str(tmp_path / "o.json")]) == 3
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "transforms_train.json frame 0" in err and "camera_angle_x" in err


# --- per-frame intrinsics in transforms.json ------------------------------------------------------------
def test_transforms_per_frame_intrinsics_override_top_level(tmp_path):
    d = {"fl_x": 10, "fl_y": 10, "cx": 4, "cy": 3, "w": 8, "h": 6,
         "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()},
                    {"file_path": "b.png", "transform_matrix": np.eye(4).tolist(),
                     "fl_x": 20, "fl_y": 21, "cx": 8, "cy": 6, "w": 16, "h": 12}]}
    (tmp_path / "transforms.json").write_text(json.dumps(d))
    a, b = read_transforms(tmp_path / "transforms.json")
    assert (a.intrinsics.width, a.intrinsics.fx, a.intrinsics.cx) == (8, 10, 3.5)
    assert (b.intrinsics.width, b.intrinsics.height, b.intrinsics.fx, b.intrinsics.fy) == (16, 12, 20, 21)
    assert (b.intrinsics.cx, b.intrinsics.cy) == (7.5, 5.5)  # NeRF pixel centres (0.5, 0.5) -> OpenCV (0, 0)


# --- IDR / NeuS --------------------------------------------------------------------------------------------
K_NEUS = np.array([[100.0, 0, 30], [0, 120, 20], [0, 0, 1]])
S_NEUS = np.array([[2.0, 0, 0, 1], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]])  # X_world = 2 X_norm + (1, 0, 0)


def _neus_scene(tmp_path, n_images=1, **extra):
    # Camera at (0, 0, -5) looking along +z, axes = world axes: P = K [I | (0, 0, 5)], stored times -2.5
    # (a projection is defined up to scale, sign included).
    Wm = np.eye(4)
    Wm[:3] = -2.5 * K_NEUS @ np.hstack([np.eye(3), [[0], [0], [5]]])
    np.savez(tmp_path / "cameras_sphere.npz", world_mat_0=Wm, scale_mat_0=S_NEUS, **extra)
    for k in range(n_images):
        _png(tmp_path / "image" / f"{k:03d}.png", 64, 48)
    return tmp_path / "cameras_sphere.npz"


def test_neus_point_lands_on_hand_computed_pixel_in_both_worlds(tmp_path):
    path = _neus_scene(tmp_path)
    # Original world: X = (1, 2, 5) -> camera (1, 2, 10) -> u = 100 * 0.1 + 30 = 40, v = 120 * 0.2 + 20 = 44
    # (K in OpenCV's pixel convention: no half-pixel shift).
    (v,) = read_neus(path, world="original")
    assert (v.intrinsics.fx, v.intrinsics.fy, v.intrinsics.cx, v.intrinsics.cy) == pytest.approx((100, 120, 30, 20))
    assert (v.intrinsics.width, v.intrinsics.height) == (64, 48)
    assert _uv(v, [1, 2, 5]) == pytest.approx([40, 44])
    np.testing.assert_allclose(v.center, [0, 0, -5], atol=1e-12)
    # Normalised world (P = world_mat @ scale_mat): X_norm = (0, 1, 2.5) is X_world = (1, 2, 5): the same pixel.
    (n,) = read_model(tmp_path).views  # folder -> normalised by default
    assert _uv(n, [0, 1, 2.5]) == pytest.approx([40, 44])
    np.testing.assert_allclose(n.center, [-0.5, 0, -2.5], atol=1e-12)
    assert n.image_path.endswith("image/000.png")


def test_neus_decomposition_positive_K_proper_rotation():
    rng = np.random.default_rng(1)
    for _ in range(20):
        T = look_at(rng.normal(size=3) * 3 + [0, 0, 5], rng.normal(size=3) * 0.1)
        K = np.array([[rng.uniform(50, 500), 0, rng.uniform(10, 50)], [0, rng.uniform(50, 500), rng.uniform(10, 50)],
                      [0, 0, 1]])
        P = rng.choice([-1, 1]) * rng.uniform(0.1, 10) * K @ T[:3]
        K2, T2 = decompose_projection(P, "test")
        np.testing.assert_allclose(K2, K, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(T2, T, atol=1e-9)
        assert np.linalg.det(T2[:3, :3]) == pytest.approx(1)


def test_neus_round_trip_and_cli(tmp_path):
    views = _random_views(3, seed=2)
    S = S_NEUS
    write_neus(views, tmp_path / "cameras_sphere.npz", scale_mat=S)
    for k in range(3):
        _png(tmp_path / "image" / f"{k:03d}.png", 40, 30)
    for a, b in zip(views, read_neus(tmp_path / "cameras_sphere.npz", world="original")):
        np.testing.assert_allclose(b.cam_from_world, a.cam_from_world, atol=1e-9)
        np.testing.assert_allclose(b.intrinsics.K, a.intrinsics.K, atol=1e-9)
    X_norm = np.array([0.1, -0.2, 0.3])
    X_world = S[:3, :3] @ X_norm + S[:3, 3]
    for a, b in zip(views, read_neus(tmp_path / "cameras_sphere.npz")):
        assert _uv(b, X_norm) == pytest.approx(_uv(a, X_world))
    # CLI: NeuS (original world) -> COLMAP text -> NeuS: the world_mats come back
    assert main(["-q", "convert", str(tmp_path / "cameras_sphere.npz"), str(tmp_path / "colmap"),
                 "--neus-world", "original"]) == 0
    assert main(["-q", "convert", str(tmp_path / "colmap"), str(tmp_path / "again.npz")]) == 0
    with np.load(tmp_path / "cameras_sphere.npz") as z0, np.load(tmp_path / "again.npz") as z1:
        np.testing.assert_allclose(z1["world_mat_1"], z0["world_mat_1"], atol=1e-6)


def test_neus_bad_inputs(tmp_path, capsys):
    np.savez(tmp_path / "cameras_sphere.npz", camera_mat_0=np.eye(4))
    _png(tmp_path / "image" / "000.png", 8, 6)
    with pytest.raises(InputDataError, match=r"cameras_sphere.npz: no 'world_mat_0'"):
        read_neus(tmp_path / "cameras_sphere.npz")
    _neus_scene(tmp_path, n_images=2)  # one camera, two images
    assert main(["-q", "convert", str(tmp_path / "cameras_sphere.npz"), str(tmp_path / "o.json")]) == 3
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "cameras_sphere.npz: 1 cameras but 2 images" in err


# --- LLFF -------------------------------------------------------------------------------------------------
def _llff_row(C=(0, 0, 5), hwf=(6, 8, 8), bounds=(1.0, 9.0)):
    # Camera looking down world -z with image-up = world +y. LLFF axes are [down, right, backwards]:
    # down = world (0, -1, 0), right = (1, 0, 0), backwards = (0, 0, 1).
    M = np.zeros((3, 5))
    M[:, 0], M[:, 1], M[:, 2] = [0, -1, 0], [1, 0, 0], [0, 0, 1]
    M[:, 3], M[:, 4] = C, hwf
    return np.concatenate([M.ravel(), bounds])


def test_llff_point_lands_on_hand_computed_pixel(tmp_path):
    np.save(tmp_path / "poses_bounds.npy", _llff_row()[None])
    _png(tmp_path / "images" / "IMG_0.JPG.png", 8, 6)
    (v,) = read_model(tmp_path / "poses_bounds.npy").views
    # X = (1, 0.5, 0) -> OpenCV camera (1, -0.5, 5): u = 8 * 1/5 + 3.5 = 5.1, v = 8 * -0.5/5 + 2.5 = 1.7
    # (principal point at the image centre, (W-1)/2, (H-1)/2 in OpenCV pixels).
    assert _uv(v, [1, 0.5, 0]) == pytest.approx([5.1, 1.7])
    assert (v.extra["near"], v.extra["far"]) == (1.0, 9.0)


def test_llff_downscaled_images_scale_intrinsics(tmp_path):
    np.save(tmp_path / "poses_bounds.npy", _llff_row()[None])
    _png(tmp_path / "images" / "a.png", 16, 12)  # twice the file's 8x6
    (v,) = read_llff(tmp_path)
    # f = 16, centre (7.5, 5.5): u = 16 * 1/5 + 7.5 = 10.7, v = 16 * -0.5/5 + 5.5 = 3.9
    assert _uv(v, [1, 0.5, 0]) == pytest.approx([10.7, 3.9])


def test_llff_round_trip_bounds_from_points_and_cli(tmp_path):
    views = _random_views(3, seed=3)
    pts = np.random.default_rng(0).normal(size=(200, 3)) * 0.3
    write_llff(views, tmp_path / "poses_bounds.npy", points=pts)
    arr = np.load(tmp_path / "poses_bounds.npy")
    assert arr.shape == (3, 17)
    for k in range(3):
        _png(tmp_path / "images" / f"{k:03d}.png", 40, 30)
    back = read_llff(tmp_path)
    for a, b in zip(views, back):
        np.testing.assert_allclose(b.cam_from_world, a.cam_from_world, atol=1e-12)
        assert b.intrinsics == a.intrinsics.pinhole()
        z = pts @ a.cam_from_world[:3, :3].T[:, 2] + a.cam_from_world[2, 3]
        assert b.extra["near"] == pytest.approx(np.percentile(z, 0.1))
        assert b.extra["far"] == pytest.approx(np.percentile(z, 99.9))
    # CLI: LLFF -> transforms.json (no points) -> LLFF needs --bounds
    assert main(["-q", "convert", str(tmp_path), str(tmp_path / "t.json")]) == 0
    assert main(["-q", "convert", str(tmp_path / "t.json"), str(tmp_path / "o" / "poses_bounds.npy")]) == 3
    assert main(["-q", "convert", str(tmp_path / "t.json"), str(tmp_path / "o" / "poses_bounds.npy"),
                 "--bounds", "0.5", "7"]) == 0
    again = np.load(tmp_path / "o" / "poses_bounds.npy")
    np.testing.assert_allclose(again[:, :15], arr[:, :15], atol=1e-12)
    np.testing.assert_allclose(again[:, 15:], [[0.5, 7]] * 3)


def test_llff_bad_inputs(tmp_path, capsys):
    np.save(tmp_path / "poses_bounds.npy", np.zeros((2, 15)))
    _png(tmp_path / "images" / "a.png", 8, 6)
    assert main(["-q", "convert", str(tmp_path / "poses_bounds.npy"), str(tmp_path / "o.json")]) == 3
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "poses_bounds.npy: expected an N x 17 array" in err and "(2, 15)" in err
    np.save(tmp_path / "poses_bounds.npy", np.stack([_llff_row(), _llff_row()]))
    with pytest.raises(InputDataError, match=r"poses_bounds.npy: 2 cameras but 1 images in .*images"):
        read_llff(tmp_path)
    _png(tmp_path / "images" / "b.png", 9, 9)  # not a resize of 8x6
    with pytest.raises(InputDataError, match="row 1: image .*b.png is 9x9"):
        read_llff(tmp_path)
