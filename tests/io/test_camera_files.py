"""Malformed camera files: every reader (transforms.json, NeRF Blender, COLMAP text, IDR/NeuS, LLFF, Strecha)
answers a missing key, an empty list, a wrong shape or a NaN with one line that names the file and what to fix,
as an ``InputDataError`` (exit 3), never a bare ``KeyError`` text, a traceback or a later stage's error."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from photorecon.cli import main
from photorecon.errors import InputDataError
from photorecon.io.dataset import read_model

EYE = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
INTR = {"fl_x": 10, "cx": 4, "cy": 3, "w": 8, "h": 6}
CAM = "1 PINHOLE 8 6 10 10 3.5 2.5\n"
IMAGE = "1 1 0 0 0 0 0 0 1 a.png\n\n"


def _png(path, w=8, h=6):
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.full((h, w, 3), 200, np.uint8))


def _transforms(folder, frames, **top):
    folder.mkdir(parents=True, exist_ok=True)
    _png(folder / "images" / "a.png")
    p = folder / "transforms.json"
    p.write_text(json.dumps({**INTR, **top, "frames": frames}))
    return p


def _colmap(folder, cameras=CAM, images=IMAGE, points=""):
    d = folder / "sparse" / "0"
    d.mkdir(parents=True)
    (d / "cameras.txt").write_text(cameras)
    (d / "images.txt").write_text(images)
    (d / "points3D.txt").write_text(points)
    return folder


def _message(path) -> str:
    with pytest.raises(InputDataError) as exc:
        read_model(path)
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_reconstruct_with_a_transforms_json_without_frames_is_exit_3_naming_the_file(tmp_path, capsys):
    poses = _transforms(tmp_path / "cams", [])
    _png(tmp_path / "photos" / "a.png")
    out = tmp_path / "out"
    assert main(["-q", "reconstruct", str(tmp_path / "photos"), "-o", str(out), "--poses", str(poses)]) == 3
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(poses) in err and "has no frames" in err, err
    assert not out.exists() or not any(out.iterdir())


def test_empty_camera_files_of_every_format_are_refused(tmp_path):
    assert "has no frames" in _message(_transforms(tmp_path / "t", []))
    blender = tmp_path / "b"
    blender.mkdir()
    (blender / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.8, "frames": []}))
    assert "has no frames" in _message(blender)
    assert "has no cameras" in _message(_colmap(tmp_path / "c", images=""))
    llff = tmp_path / "l"
    llff.mkdir()
    np.save(llff / "poses_bounds.npy", np.zeros((0, 17)))
    _png(llff / "images" / "000.png")
    assert "no camera (0 rows)" in _message(llff / "poses_bounds.npy")


def test_blender_split_without_frames_beside_others_is_allowed(tmp_path):
    frame = {"file_path": "./train/r_0", "transform_matrix": EYE}
    (tmp_path / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.8, "frames": [frame]}))
    (tmp_path / "transforms_val.json").write_text(json.dumps({"camera_angle_x": 0.8, "frames": []}))
    _png(tmp_path / "train" / "r_0.png")
    assert [v.name for v in read_model(tmp_path).views] == ["train_r_0"]


@pytest.mark.parametrize("frame, expected", [
    ({"file_path": "images/a.png"}, "frame 0 has no transform_matrix (a 4x4 camera-to-world matrix)"),
    ({"transform_matrix": EYE}, "frame 0 has no file_path"),
    ({"file_path": None, "transform_matrix": EYE}, "file_path: expected a file path"),
    ({"file_path": "images/a.png", "transform_matrix": "abc"}, "transform_matrix: expected a 4x4 matrix of numbers"),
    ({"file_path": "images/a.png", "transform_matrix": [[1, 0], [0, 1, 0, 0]]}, "expected a 4x4 matrix of numbers"),
    ({"file_path": "images/a.png", "transform_matrix": EYE, "depth_file_path": None}, "depth_file_path: expected"),
    ({"file_path": "images/a.png", "transform_matrix": EYE, "fl_x": "x"}, "fl_x: expected a number, got 'x'"),
    (3, "frame 0: expected an object with file_path and transform_matrix"),
])
def test_transforms_json_frame_errors_name_the_key(tmp_path, frame, expected):
    path = _transforms(tmp_path, [frame])
    msg = _message(path)
    assert str(path) in msg and expected in msg, msg


@pytest.mark.parametrize("top, expected", [
    ({"applied_transform": "x"}, "applied_transform: expected a 3x4 matrix of numbers"),
    ({"applied_transform": [1, 2]}, "applied_transform: expected a 3x4 matrix of numbers"),
    ({"photorecon_world": "sideways"}, "photorecon_world 'sideways' is not one of"),
])
def test_transforms_json_world_errors(tmp_path, top, expected):
    path = _transforms(tmp_path, [{"file_path": "images/a.png", "transform_matrix": EYE}], **top)
    assert expected in _message(path)


def test_blender_frame_without_transform_matrix(tmp_path):
    (tmp_path / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.8,
                                                               "frames": [{"file_path": "./train/r_0"}]}))
    _png(tmp_path / "train" / "r_0.png")
    assert "transforms_train.json: frame 0 has no transform_matrix" in _message(tmp_path)


@pytest.mark.parametrize("cameras, images, points, expected", [
    (CAM, "# header\n1 0 0 0 0 0 0 0 1 a.png\n\n", "", "images.txt: zero quaternion in line 2"),
    (CAM, "1 nan 0 0 0 0 0 0 1 a.png\n\n", "", "images.txt line 1: image a.png: QW QX QY QZ TX TY TZ must be finite"),
    (CAM, "1 1 0 0 0 0 0 0 2 a.png\n\n", "", "image a.png uses camera 2, which"),
    (CAM, "1 1 0 0 0 0 0 0 1 a.png\n1 2\n", "", "POINTS2D line (line 2) holds 2 numbers"),
    (CAM + CAM, IMAGE, "", "cameras.txt: cannot parse camera line 2: camera 1 is listed twice"),
    ("1 PINHOLE 8 x 10 10 3.5 2.5\n", IMAGE, "", "WIDTH, HEIGHT: 'x' is not an integer"),
    (CAM, IMAGE, "1 0 0\n", "points3D.txt: cannot parse point line 1"),
    (CAM, IMAGE, "1 nan 0 0 1 2 3 0.1\n", "X Y Z must be finite"),
    (CAM, IMAGE, "1 0 0 0 300 2 3 0.1\n", "R G B must be 0..255"),
])
def test_colmap_text_errors_name_the_file_and_line(tmp_path, cameras, images, points, expected):
    msg = _message(_colmap(tmp_path, cameras, images, points))
    assert expected in msg, msg
    assert "NaN/inf" not in msg and "KeyError" not in msg


def test_colmap_text_last_image_without_its_points_line_is_read(tmp_path):
    """A final pose line with no POINTS2D line after it is an image with no points, not a dropped image."""
    model = read_model(_colmap(tmp_path, images="1 1 0 0 0 0 0 0 1 a.png\n\n2 1 0 0 0 1 0 0 1 b.png"))
    assert [v.name for v in model.views] == ["a", "b"]


def _neus(folder, **mats):
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "cameras_sphere.npz", **mats)
    _png(folder / "image" / "000.png")
    return folder / "cameras_sphere.npz"


def test_neus_errors_name_the_matrix(tmp_path):
    P = np.eye(4)
    P[:3] = np.array([[10, 0, 3.5], [0, 10, 2.5], [0, 0, 1.0]]) @ np.c_[np.eye(3), [0, 0, 4]]
    assert "scale_mat_0 holds 16 NaN or infinite entries" in _message(
        _neus(tmp_path / "a", world_mat_0=P, scale_mat_0=np.full((4, 4), np.nan)))
    assert "world_mat_0 holds <U1 values; expected a matrix of real numbers" in _message(
        _neus(tmp_path / "b", world_mat_0=np.full((3, 4), "a"), scale_mat_0=np.eye(4)))


def test_llff_errors_name_the_entry(tmp_path):
    M = np.zeros((3, 5))
    M[:, :3] = np.eye(3)
    M[:, 4] = [6, 8, 10]
    np.save(tmp_path / "poses_bounds.npy", np.r_[M.ravel(), np.nan, 5][None])
    _png(tmp_path / "images" / "000.png")
    assert "row 0: near not finite" in _message(tmp_path / "poses_bounds.npy")
    np.save(tmp_path / "poses_bounds.npy", np.ones((1, 17), bool))
    assert "array of real numbers, got bool values" in _message(tmp_path / "poses_bounds.npy")


def test_strecha_non_finite_names_the_block(tmp_path):
    good = "10 0 3.5\n0 10 2.5\n0 0 1\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n0 0 -4\n8 6\n"
    (tmp_path / "0000.jpg.camera").write_text(good.replace("8 6", "nan 6"))
    assert "non-finite number (NaN or inf) in size" in _message(tmp_path)


def test_colmap_binary_zero_quaternion_is_refused_not_read_as_identity(tmp_path):
    """pycolmap turns a stored 0 0 0 0 rotation into the identity; the reader refuses it instead."""
    import pycolmap

    text = _colmap(tmp_path / "t", images="1 0 0 0 0 0 0 0 1 a.png\n\n2 1 0 0 0 0 0 0 1 b.png\n\n") / "sparse" / "0"
    binary = tmp_path / "b"
    binary.mkdir()
    pycolmap.Reconstruction(str(text)).write_binary(str(binary))
    msg = _message(binary)
    assert str(binary) in msg and "image a.png: zero quaternion" in msg, msg
