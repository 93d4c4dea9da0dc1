"""Where every camera and dataset reader reads from, and the names it accepts.

One path rule (``io.paths.inside``) for every reader: a name in a camera or dataset file, or a file in a folder
the user named, never resolves outside that folder (``..``, absolute paths, links), and a refusal is exit 3
with one line, before anything is copied, the inputs unchanged byte for byte. Then the names themselves:
spaces, two photos that would be one view, names too long for the files named after them; every
transforms.json ``camera_model``; fisheye cameras undistorted with OpenCV's fisheye model."""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import tree_hash
from photorecon.cameras import Intrinsics, View, look_at
from photorecon.cli import main
from photorecon.errors import InputDataError, NoImagesError, SfMError
from photorecon.io.colmap_text import SparseModel, read_colmap_text, write_colmap_text
from photorecon.io.dataset import read_model
from photorecon.io.formats import write_llff, write_neus
from photorecon.io.nerf import read_transforms, write_blender, write_transforms
from photorecon.poses.ingest import list_images

ROOT = Path(__file__).resolve().parents[2]
W, H = 40, 30


def _png(path: Path, seed: int = 0) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.random.default_rng(seed).integers(0, 255, (H, W, 3), dtype=np.uint8)
    assert cv2.imwrite(str(path), img)
    return path


def _views(n: int = 3) -> list[View]:
    intr = Intrinsics(W, H, 35.0, 35.0, (W - 1) / 2, (H - 1) / 2)
    views = []
    for i in range(n):
        a = 2 * np.pi * i / n
        views.append(View(f"v{i}", intr, look_at([4 * np.cos(a), 0.5, 4 * np.sin(a)], [0, 0, 0]),
                          image_file=f"v{i}.png"))
    return views


def _last_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


# --- one path rule, every reader -------------------------------------------------------------------------------------
def _escape(attack: str, base: Path, secret: Path, link_at: Path) -> str:
    """A name, relative to ``base``, that reaches ``secret`` outside the input: ``..``, an absolute path, or
    ``link_at`` made a link to ``secret`` (its name returned)."""
    if attack == "dotdot":
        return os.path.relpath(secret, base)
    if attack == "absolute":
        return str(secret)
    link_at.parent.mkdir(parents=True, exist_ok=True)
    link_at.unlink(missing_ok=True)
    link_at.symlink_to(secret)
    return link_at.relative_to(base).as_posix()


def _colmap_scene(tmp, attack, binary=False):
    images = tmp / "in" / "images"
    views = _views()
    for i, v in enumerate(views):
        _png(images / v.image_file, i)
    name = _escape(attack, images, tmp / "outside" / "x.png", images / "x.png")
    views[0] = dataclasses.replace(views[0], image_file=name)
    model = tmp / "in" / "model"
    if binary:
        from photorecon.io.colmap import write_colmap_binary

        write_colmap_binary(SparseModel(views), model)
    else:
        write_colmap_text(SparseModel(views), model)
    return ["reconstruct", images, "--poses", model]


def _transforms_scene(tmp, attack, key="file_path"):
    images = tmp / "in" / "images"
    views = _views()
    for i, v in enumerate(views):
        _png(images / v.image_file, i)
    cams = tmp / "in" / "cams" / "transforms.json"
    write_transforms(views, cams)
    data = json.loads(cams.read_text())
    data["frames"][0][key] = _escape(attack, cams.parent, tmp / "outside" / "x.png", cams.parent / "x.png")
    cams.write_text(json.dumps(data))
    return ["reconstruct", images, "--poses", cams]


def _blender_scene(tmp, attack):
    scene = tmp / "in" / "scene"
    views = _views()
    for i, v in enumerate(views):
        _png(scene / "train" / v.image_file, i)
    write_blender(views, scene / "transforms_train.json")
    data = json.loads((scene / "transforms_train.json").read_text())
    name = _escape(attack, scene, tmp / "outside" / "x.png", scene / "train" / "x.png")
    data["frames"][0]["file_path"] = name[:-4] if attack != "symlink" else "./train/x"  # Blender: no extension
    (scene / "transforms_train.json").write_text(json.dumps(data))
    return ["reconstruct", scene / "train", "--poses", scene / "transforms_train.json"]


def _listed_scene(tmp, attack, fmt):
    """NeuS and LLFF pair cameras with the sorted files of a folder: a link in it is the only way out."""
    scene = tmp / "in" / "scene"
    folder = scene / {"neus": "image", "neus-images": "images", "llff": "images"}[fmt]
    views = _views()
    for i, v in enumerate(views[1:], 1):
        _png(folder / v.image_file, i)
    _escape(attack, folder, tmp / "outside" / "x.png", folder / "v0.png")
    if fmt == "llff":
        write_llff(views, scene / "poses_bounds.npy", bounds=(1.0, 8.0))
    else:
        write_neus(views, scene / "cameras_sphere.npz")
    return ["reconstruct", folder, "--poses", scene]


def _strecha_scene(tmp, attack):
    """Strecha: one camera file per image, found by listing the folder; a link to one outside is the way out."""
    images = tmp / "in" / "images"
    cams = tmp / "in" / "gt_dense_cameras"
    cams.mkdir(parents=True)
    for i, v in enumerate(_views()):
        _png(images / v.image_file, i)
        R = v.cam_from_world[:3, :3].T
        C = -R @ v.cam_from_world[:3, 3]
        K = v.intrinsics.K
        rows = [*K.tolist(), [0, 0, 0], *R.tolist(), C.tolist(), [W, H]]
        text = "\n".join(" ".join(repr(float(x)) for x in r) for r in rows) + "\n"
        target = cams / f"{v.image_file}.camera"
        if i == 0:  # the camera file of view 0 lives outside, linked in
            target = tmp / "outside" / f"{v.image_file}.camera"
            target.parent.mkdir(parents=True, exist_ok=True)
            (cams / target.name).symlink_to(target)
        target.write_text(text)
    return ["reconstruct", images, "--poses", cams]


def _dataset_with_depth(tmp):
    """``tmp/in/DS`` with the three views' images and constant depth maps; (its folder, the views)."""
    ds = tmp / "in" / "DS"
    views = _views()
    (ds / "depth").mkdir(parents=True)
    for i, v in enumerate(views):
        _png(ds / "images" / v.image_file, i)
        np.save(ds / "depth" / f"{v.name}.npy", np.full((H, W), 4.0, np.float32))
    return ds, views


def _dataset_scene(tmp, attack, key):
    """A dataset folder (``mvs``/``fuse`` read it): its transforms.json names depth maps and masks."""
    ds, views = _dataset_with_depth(tmp)
    write_transforms(views, ds / "transforms.json", depth_dir="depth", mask_dir="masks")
    data = json.loads((ds / "transforms.json").read_text())
    secret = tmp / "outside" / ("x.npy" if key == "depth_file_path" else "x.png")
    if key == "depth_file_path":
        np.save(secret, np.full((H, W), 4.0, np.float32))
    data["frames"][0][key] = _escape(attack, ds, secret, ds / "depth" / "x.npy" if key == "depth_file_path"
                                     else ds / "masks" / "x.png")
    (ds / "transforms.json").write_text(json.dumps(data))
    return ["fuse", ds]


def _dataset_colmap_scene(tmp, attack):
    """A dataset whose sparse/0 names its images (relative to DS/images)."""
    ds = tmp / "in" / "DS"
    views = _views()
    for i, v in enumerate(views):
        _png(ds / "images" / v.image_file, i)
    name = _escape(attack, ds / "images", tmp / "outside" / "x.png", ds / "images" / "x.png")
    views[0] = dataclasses.replace(views[0], image_file=name)
    write_colmap_text(SparseModel(views), ds / "sparse" / "0")
    return ["mvs", ds]


def _dataset_files_scene(tmp, attack, folder):
    """A dataset's own depth/NAME.npy or masks/NAME.png, a link to a file elsewhere."""
    ds, views = _dataset_with_depth(tmp)
    write_colmap_text(SparseModel(views), ds / "sparse" / "0")
    secret = tmp / "outside" / ("x.npy" if folder == "depth" else "x.png")
    if folder == "depth":
        np.save(secret, np.full((H, W), 4.0, np.float32))
    _escape(attack, ds, secret, ds / folder / ("v0.npy" if folder == "depth" else "v0.png"))
    return ["fuse", ds]


def _masks_option_scene(tmp, attack):
    """``--masks DIR``: a mask in it that is a link to a file elsewhere."""
    images = tmp / "in" / "images"
    views = _views()
    for i, v in enumerate(views):
        _png(images / v.image_file, i)
    write_colmap_text(SparseModel(views), tmp / "in" / "model")
    masks = tmp / "in" / "masks"
    masks.mkdir()
    for v in views[1:]:
        cv2.imwrite(str(masks / v.image_file), np.full((H, W), 255, np.uint8))
    _escape(attack, masks, tmp / "outside" / "x.png", masks / "v0.png")
    return ["reconstruct", images, "--poses", tmp / "in" / "model", "--masks", masks]


READERS = {
    "colmap-text": lambda t, a: _colmap_scene(t, a),
    "colmap-bin": lambda t, a: _colmap_scene(t, a, binary=True),
    "transforms": lambda t, a: _transforms_scene(t, a),
    "blender": _blender_scene,
    "neus": lambda t, a: _listed_scene(t, a, "neus"),
    "neus-images": lambda t, a: _listed_scene(t, a, "neus-images"),
    "llff": lambda t, a: _listed_scene(t, a, "llff"),
    "strecha": _strecha_scene,
    "dataset-depth": lambda t, a: _dataset_scene(t, a, "depth_file_path"),
    "dataset-mask": lambda t, a: _dataset_scene(t, a, "mask_path"),
    "dataset-colmap": _dataset_colmap_scene,
    "dataset-depth-link": lambda t, a: _dataset_files_scene(t, a, "depth"),
    "dataset-mask-link": lambda t, a: _dataset_files_scene(t, a, "masks"),
    "masks-option": _masks_option_scene,
}
CASES = [(r, a) for r in READERS for a in ("dotdot", "absolute", "symlink")
         if a == "symlink" or r not in ("neus", "neus-images", "llff", "strecha", "dataset-depth-link",
                                        "dataset-mask-link", "masks-option")]


@pytest.mark.parametrize("reader,attack", CASES)
def test_no_reader_reads_a_file_outside_the_folder_it_was_given(tmp_path, reader, attack, capsys):
    _png(tmp_path / "outside" / "x.png", 9)  # a readable image of the right size: only its place is wrong
    argv = READERS[reader](tmp_path, attack)
    out = tmp_path / "out"
    before = tree_hash(tmp_path)
    assert main(["-q", *map(str, argv), "-o", str(out)]) == InputDataError.exit_code
    line = _last_line(capsys.readouterr().err)
    assert "refused" in line and ("outside" in line or "leaves" in line or "absolute" in line), line
    assert tree_hash(tmp_path) == before
    assert not out.exists()  # nothing copied, no output left


def test_a_photo_folder_of_links_to_photos_elsewhere_is_read(tmp_path):
    """A folder the user made of links (a subset of a larger capture) names no file itself: its photos are read
    where the links point, and nothing there is changed."""
    photos = tmp_path / "in" / "photos"
    for i in range(3):
        _png(tmp_path / "all" / f"p{i}.png", i)
        photos.mkdir(parents=True, exist_ok=True)
        (photos / f"p{i}.png").symlink_to(tmp_path / "all" / f"p{i}.png")
    imgs, other = list_images(photos)
    assert [p.name for p in imgs] == ["p0.png", "p1.png", "p2.png"] and other == []
    assert all(p.resolve().parent == (tmp_path / "all").resolve() for p in imgs)


def test_a_name_inside_the_folder_through_dotdot_or_a_link_is_read(tmp_path):
    """The rule is about where a file is, not how it is spelt: ``sub/../v0.png`` and a link to a file in the
    same folder are read."""
    scene = tmp_path / "scene"
    views = _views()
    for i, v in enumerate(views):
        _png(scene / "images" / v.image_file, i)
    (scene / "images" / "alias.png").symlink_to(scene / "images" / "v1.png")
    write_transforms(views, scene / "transforms.json")
    data = json.loads((scene / "transforms.json").read_text())
    data["frames"][0]["file_path"] = "images/sub/../v0.png"
    data["frames"][1]["file_path"] = "images/alias.png"
    (scene / "transforms.json").write_text(json.dumps(data))
    v = read_transforms(scene / "transforms.json")
    assert [x.image_file for x in v] == ["v0.png", "alias.png", "v2.png"]


# --- names -----------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", [" leading space.png", "double  space.png", "trailing space .png", "tab\tname.png",
                                  "~tilde.png", "..dots.png"])
def test_colmap_text_names_are_the_rest_of_the_line(tmp_path, name):
    views = _views()
    views[0] = dataclasses.replace(views[0], name=Path(name).stem, image_file=name)
    write_colmap_text(SparseModel(views), tmp_path)
    got = read_colmap_text(tmp_path).views
    assert got[0].image_file == name and got[0].name == Path(name).stem
    assert [v.image_file for v in got[1:]] == ["v1.png", "v2.png"]


@pytest.mark.slow
def test_photos_named_with_spaces_reconstruct_from_given_cameras(blob_small, tmp_path, capsys):
    """Photos named " leading space.png" and "double  space.png": read, undistorted and fused like any other."""
    images, depth, model = tmp_path / "images", tmp_path / "depth", tmp_path / "model"
    shutil.copytree(blob_small / "images", images)
    shutil.copytree(blob_small / "depth", depth)
    m = read_model(blob_small / "sparse" / "0")
    rename = {"view_000": " leading space", "view_001": "double  space"}
    views = []
    for v in m.views:
        if v.name in rename:
            new = rename[v.name]
            (images / f"{v.name}.png").rename(images / f"{new}.png")
            (depth / f"{v.name}.npy").rename(depth / f"{new}.npy")
            v = dataclasses.replace(v, name=new, image_file=f"{new}.png")
        views.append(v)
    write_colmap_text(SparseModel(views), model)
    out = tmp_path / "out"
    assert main(["-q", "reconstruct", str(images), "--poses", str(model), "--depth", str(depth), "-o", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["poses"]["registered"] == 12 and report["depth"]["views"] == 12
    got = {v.image_file for v in read_model(out).views}
    assert {" leading space.png", "double  space.png"} <= got
    assert (out / "images" / " leading space.png").is_file()
    # a message names such a file as it is, both spaces kept
    (images / "double  space.png").rename(tmp_path / "elsewhere.png")
    capsys.readouterr()
    assert main(["-q", "reconstruct", str(images), "--poses", str(model), "--depth", str(depth), "-o",
                 str(tmp_path / "out2")]) == 3
    assert "image double  space.png not found" in _last_line(capsys.readouterr().err)


def test_two_photos_that_would_be_one_view_are_refused_naming_both(blob_small, tmp_path, capsys):
    """view_000.png and view_000.jpg (two different photos): SfM and --poses both refuse, exit 3, naming both
    files, before anything is written."""
    photos = tmp_path / "photos"
    shutil.copytree(blob_small / "images", photos)
    cv2.imwrite(str(photos / "view_000.jpg"), cv2.imread(str(blob_small / "images" / "view_001.png")))
    m = read_model(blob_small / "sparse" / "0")
    extra = dataclasses.replace(m.views[1], name="view_000", image_file="view_000.jpg")
    write_colmap_text(SparseModel(m.views + [extra]), tmp_path / "model")
    before = tree_hash(tmp_path)
    said = []
    for argv, where in ((["sfm", photos], photos), (["reconstruct", photos, "--poses", tmp_path / "model"],
                                                     tmp_path / "model")):
        assert main(["-q", *map(str, argv), "-o", str(tmp_path / "out")]) == 3
        line = _last_line(capsys.readouterr().err)
        head = f"photorecon {argv[0]}: error: {where}: "
        assert line.startswith(head), line  # the folder or camera file, then what is wrong: no function's name
        said.append(line[len(head):])
        assert tree_hash(tmp_path) == before and not (tmp_path / "out").exists()
    assert said[0] == said[1]  # both paths say the same thing
    assert said[0].startswith("'view_000.jpg' and 'view_000.png' would both be view 'view_000'") and \
        said[0].endswith("rename or remove one of them"), said[0]


def test_a_name_too_long_for_the_files_named_after_it_is_named_as_the_cause(blob_small, tmp_path, capsys):
    photos = tmp_path / "photos"
    shutil.copytree(blob_small / "images", photos)
    long = "v" * 251 + ".png"  # 255 bytes: the file system takes it, NAME.normal.npy would not fit
    (photos / "view_003.png").rename(photos / long)
    before = tree_hash(tmp_path)
    assert main(["-q", "sfm", str(photos), "-o", str(tmp_path / "out")]) == 3
    line = _last_line(capsys.readouterr().err)
    assert f"{photos}/{'v' * 30}...{'v' * 16}.png: file name is 255 bytes long; rename it to at most 223 bytes" in line, line
    assert tree_hash(tmp_path) == before and not (tmp_path / "out").exists()
    m = read_model(blob_small / "sparse" / "0")
    views = [dataclasses.replace(v, image_file=long) if v.name == "view_003" else v for v in m.views]
    write_colmap_text(SparseModel(views), tmp_path / "model")
    assert main(["-q", "reconstruct", str(photos), "--poses", str(tmp_path / "model"), "-o", str(tmp_path / "out")]) == 3
    assert "file name is 255 bytes long" in _last_line(capsys.readouterr().err)
    assert not (tmp_path / "out").exists()


# --- transforms.json camera models; fisheye ------------------------------------------------------------------------
def _transforms_with(tmp_path, **top):
    views = _views()
    for i, v in enumerate(views):
        _png(tmp_path / "images" / v.image_file, i)
    write_transforms(views, tmp_path / "transforms.json")
    data = json.loads((tmp_path / "transforms.json").read_text())
    for k in ("camera_model", "k1", "k2", "p1", "p2"):
        data.pop(k, None)
    data.update(top)
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    return tmp_path / "transforms.json"


@pytest.mark.parametrize("top,model,dist", [
    ({}, "PINHOLE", {}),
    ({"camera_model": "PINHOLE"}, "PINHOLE", {}),
    ({"camera_model": "SIMPLE_PINHOLE"}, "PINHOLE", {}),
    ({"camera_model": "OPENCV", "k1": 0.1, "p2": 0.01}, "OPENCV", {"k1": 0.1, "p2": 0.01}),
    ({"camera_model": "SIMPLE_RADIAL", "k1": -0.05}, "OPENCV", {"k1": -0.05}),
    ({"camera_model": "RADIAL", "k1": -0.05, "k2": 0.01}, "OPENCV", {"k1": -0.05, "k2": 0.01}),
    ({"camera_model": "OPENCV_FISHEYE", "k1": 0.1, "k2": -0.02, "k3": 0.003, "k4": -0.001}, "OPENCV_FISHEYE",
     {"k1": 0.1, "k2": -0.02, "k3": 0.003, "k4": -0.001}),
    ({"camera_model": "OPENCV_FISHEYE"}, "OPENCV_FISHEYE", {}),
    ({"is_fisheye": True, "k1": 0.1, "k4": 0.002}, "OPENCV_FISHEYE", {"k1": 0.1, "k4": 0.002}),  # instant-ngp
])
def test_every_readable_camera_model_keeps_its_lens(tmp_path, top, model, dist):
    views = read_transforms(_transforms_with(tmp_path, **top))
    for v in views:
        intr = v.intrinsics
        assert intr.model == model
        for k in ("k1", "k2", "k3", "k4", "p1", "p2"):
            assert getattr(intr, k) == pytest.approx(dist.get(k, 0.0))
        assert intr.has_distortion == (model != "PINHOLE")


@pytest.mark.parametrize("top,needle", [
    ({"camera_model": "EQUIRECTANGULAR"}, "'EQUIRECTANGULAR' is not supported"),
    ({"camera_model": "OMNIDIRECTIONALSTEREO_L"}, "'OMNIDIRECTIONALSTEREO_L' is not supported"),
    ({"camera_model": "VR180_R"}, "'VR180_R' is not supported"),
    ({"camera_model": "FISHEYE624"}, "'FISHEYE624' is not supported"),
    ({"camera_model": "THIN_PRISM"}, "'THIN_PRISM' is not supported"),
    ({"camera_model": "OPENCV", "k1": 0.1, "k3": 0.02}, "OPENCV camera with k3=0.02"),
    ({"k1": 0.1, "k3": 0.02}, "OPENCV camera with k3=0.02"),  # instant-ngp's 5-parameter OpenCV lens
    ({"camera_model": "OPENCV_FISHEYE", "k1": 0.1, "p1": 0.01}, "OPENCV_FISHEYE camera with p1=0.01"),
])
def test_camera_models_photorecon_cannot_hold_are_refused_naming_the_frame(tmp_path, top, needle, capsys):
    path = _transforms_with(tmp_path, **top)
    before = tree_hash(tmp_path)
    assert main(["-q", "convert", str(path), str(tmp_path / "out.json")]) == 3
    line = _last_line(capsys.readouterr().err)
    assert f"{path} frame 0: " in line and needle in line, line
    assert tree_hash(tmp_path) == before and not (tmp_path / "out.json").exists()


def test_fisheye_projection_is_opencvs():
    intr = Intrinsics(640, 480, 300.0, 310.0, 319.5, 239.5, model="OPENCV_FISHEYE", k1=0.08, k2=-0.03, k3=0.01,
                      k4=-0.002)
    rng = np.random.default_rng(0)
    P = np.c_[rng.uniform(-1.5, 1.5, (50, 2)), rng.uniform(0.8, 3, 50)]
    uv, _ = intr.project_cam(P)
    ref, _ = cv2.fisheye.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), intr.K, intr.dist_coeffs)
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-6)
    rays = intr.pixel_rays(uv)
    np.testing.assert_allclose(rays[:, :2], P[:, :2] / P[:, 2:], atol=1e-8)  # undistort inverts distort


def test_given_fisheye_cameras_are_undistorted_with_the_fisheye_model(tmp_path):
    """Dots on a pinhole image, seen through an OPENCV_FISHEYE lens (k1..k4): --poses's ingest puts each dot
    back where the pinhole camera sees it (within 0.3 px); the same file read as a Brown lens (k3, k4 dropped)
    or not undistorted would be pixels off."""
    from photorecon.poses.ingest import ingest_given

    w, h = 200, 150
    fish = Intrinsics(w, h, 90.0, 90.0, (w - 1) / 2, (h - 1) / 2, model="OPENCV_FISHEYE", k1=0.05, k2=0.02,
                      k3=-0.01, k4=0.004)
    pin = fish.pinhole()
    dots = np.array([[30.0, 25.0], [170.0, 30.0], [100.0, 75.0], [40.0, 120.0], [160.0, 125.0]])
    # the fisheye photo: each of its pixels shows the pinhole image where its ray lands
    uv = pin.pixel_grid().reshape(-1, 2)
    xy = fish.undistort(np.c_[(uv[:, 0] - fish.cx) / fish.fx, (uv[:, 1] - fish.cy) / fish.fy])
    src = np.c_[xy[:, 0] * pin.fx + pin.cx, xy[:, 1] * pin.fy + pin.cy].reshape(h, w, 2).astype(np.float32)
    d = np.linalg.norm(src[:, :, None, :] - dots[None, None].astype(np.float32), axis=-1).min(axis=2)
    photo = np.clip(255 * np.exp(-(d / 3.0) ** 2), 0, 255).astype(np.uint8)
    _png(tmp_path / "images" / "f.png")
    cv2.imwrite(str(tmp_path / "images" / "f.png"), np.dstack([photo] * 3))
    T = look_at([0, 0, -4], [0, 0, 0], up=(0, 1, 0))
    views = [View("f", fish, T, image_file="f.png"), View("g", fish, T, image_file="f.png")]
    write_transforms(views[:1], tmp_path / "transforms.json")
    assert json.loads((tmp_path / "transforms.json").read_text())["camera_model"] == "OPENCV_FISHEYE"
    (v,) = read_transforms(tmp_path / "transforms.json")
    assert v.intrinsics == fish
    res = ingest_given(SparseModel([dataclasses.replace(v, image_path=None)]), tmp_path / "images", tmp_path / "out")
    assert res.views[0].intrinsics == pin
    out = cv2.imread(str(tmp_path / "out" / "images" / "f.png"), cv2.IMREAD_GRAYSCALE).astype(float)
    for x, y in dots:
        x0, y0 = int(round(x)), int(round(y))
        win = out[y0 - 5:y0 + 6, x0 - 5:x0 + 6]
        gy, gx = np.mgrid[y0 - 5:y0 + 6, x0 - 5:x0 + 6]
        c = np.array([(win * gx).sum(), (win * gy).sum()]) / win.sum()
        assert np.linalg.norm(c - [x, y]) < 0.3, (x, y, c)
    # what a Brown lens with the same k1, k2 would have done puts the corner dots pixels away
    brown = cv2.undistort(np.dstack([photo] * 3), fish.K, np.array([fish.k1, fish.k2, 0, 0]), None, fish.K)[..., 0]
    win = brown[20:31, 25:36].astype(float)
    gy, gx = np.mgrid[20:31, 25:36]
    c = np.array([(win * gx).sum(), (win * gy).sum()]) / max(win.sum(), 1)
    assert np.linalg.norm(c - dots[0]) > 2


# --- the input itself ----------------------------------------------------------------------------------------------
def test_an_image_file_given_as_the_folder_says_what_to_pass(blob_small, tmp_path, capsys):
    img = blob_small / "images" / "view_000.png"
    for cmd in ("reconstruct", "sfm"):
        assert main(["-q", cmd, str(img), "-o", str(tmp_path / "out")]) == NoImagesError.exit_code
        line = _last_line(capsys.readouterr().err)
        assert f"{img}: is an image file, not a folder; pass the folder that holds the photos ({img.parent})" in line


@pytest.mark.slow
def test_an_empty_video_is_photorecons_one_line(tmp_path):
    (tmp_path / "v.mp4").write_bytes(b"")
    (tmp_path / "junk.mp4").write_bytes(np.random.default_rng(0).bytes(3000))
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    for video, why in (("v.mp4", "the video file is empty (0 bytes)"), ("junk.mp4", "cannot open the video")):
        r = subprocess.run([sys.executable, "-m", "photorecon", "-q", "sfm", str(tmp_path / video), "-o",
                            str(tmp_path / "out")], capture_output=True, text=True, env=env, timeout=120, cwd=ROOT)
        assert r.returncode == NoImagesError.exit_code
        assert why in _last_line(r.stderr) and "moov" not in r.stderr, r.stderr


@pytest.mark.parametrize("kind", ["black", "one grey each", "identical"])
def test_photos_sfm_cannot_match_name_the_likely_cause(tmp_path, kind, capsys):
    from photorecon.poses.ingest import ingest_folder

    photos = tmp_path / "photos"
    h, w = 48, 64  # SIFT's size: the image gate leaves out photos under 32 pixels a side
    for i in range(5):
        img = {"black": np.zeros((h, w, 3), np.uint8), "one grey each": np.full((h, w, 3), 40 * i, np.uint8),
               "identical": np.random.default_rng(0).integers(0, 255, (h, w, 3), dtype=np.uint8)}[kind]
        photos.mkdir(exist_ok=True)
        cv2.imwrite(str(photos / f"p{i}.png"), img)
    if kind == "identical":
        with pytest.raises(SfMError, match="all 5 photos are the same picture"):
            ingest_folder(photos, tmp_path / "work")
    else:
        assert main(["-q", "sfm", str(photos), "-o", str(tmp_path / "out")]) == NoImagesError.exit_code
        assert "all 5 photo(s) are a single flat colour (all black?" in _last_line(capsys.readouterr().err)
    for i in (0, 1):  # two photos with content: the flat ones are left out (copies are no longer all alike)
        cv2.imwrite(str(photos / f"p{i}.png"), np.random.default_rng(i + 1).integers(0, 255, (h, w, 3), np.uint8))
    assert len(ingest_folder(photos, tmp_path / "work2").images) == (5 if kind == "identical" else 2)


def test_neus_reads_images_and_masks_folders(tmp_path):
    """Many copies of the IDR / NeuS layout name the folders images/ and masks/: read like image/ and mask/."""
    views = _views()
    (tmp_path / "masks").mkdir()
    for i, v in enumerate(views):
        _png(tmp_path / "images" / v.image_file, i)
        cv2.imwrite(str(tmp_path / "masks" / v.image_file), np.full((H, W), 255, np.uint8))
    write_neus(views, tmp_path / "cameras_sphere.npz")
    got = read_model(tmp_path).views
    assert [v.image_file for v in got] == ["v0.png", "v1.png", "v2.png"]
    assert [Path(v.mask_file).parent.name for v in got] == ["masks"] * 3
    for a, b in zip(got, views):
        np.testing.assert_allclose(a.cam_from_world, b.cam_from_world, atol=1e-9)
