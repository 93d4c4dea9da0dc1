"""Metric scale: ArUco markers of known size, EXIF GPS, the similarity applied to a model, units recorded."""
from __future__ import annotations

import json
import logging

import cv2
import numpy as np
import pytest
from PIL import Image

from photorecon.cameras import Intrinsics, View, look_at, project
from photorecon.errors import BadArgumentError
from photorecon.io.colmap_text import SparseModel, read_colmap_text, write_colmap_text
from photorecon.io.images import write_image
from photorecon.io.nerf import write_transforms
from photorecon.testing import write_gps_jpeg
from photorecon.poses.scale import (ScaleConfig, apply_similarity, enu_from_geodetic, geodetic_from_enu, given_units,
                              gps_alignment, marker_scale, read_gps, scale_output)

W, H = 640, 480
EDGE = 0.3  # marker edge in the scene's own units
MARKER_PX, PAD = 200, 40  # texture: each marker 200 px with a 40 px white quiet zone
IDS = (3, 7)


def _texture() -> np.ndarray:
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    tiles = [np.pad(cv2.aruco.generateImageMarker(d, i, MARKER_PX), PAD, constant_values=255) for i in IDS]
    return np.concatenate(tiles, axis=1)


def _plane_from_texture(tex: np.ndarray) -> np.ndarray:
    """3x3: texture pixel (u, v, 1) -> plane point (X, Y, 1) on z = 0; k scene units per texel, centred;
    v runs along -Y so that the texture reads unmirrored from above (+z). A marker's black square covers
    texels [PAD - 0.5, PAD + 199.5] (pixel centres at integers)."""
    k = EDGE / MARKER_PX
    th, tw = tex.shape
    return np.array([[k, 0, -k * (tw - 1) / 2], [0, -k, k * (th - 1) / 2], [0, 0, 1.0]])


def _true_corners(tex: np.ndarray) -> dict[int, np.ndarray]:
    A = _plane_from_texture(tex)
    out = {}
    for j, mid in enumerate(IDS):
        u0 = j * (MARKER_PX + 2 * PAD) + PAD - 0.5
        uv = np.array([[u0, PAD - 0.5], [u0 + MARKER_PX, PAD - 0.5], [u0 + MARKER_PX, PAD - 0.5 + MARKER_PX],
                       [u0, PAD - 0.5 + MARKER_PX]])
        XY = (np.c_[uv, np.ones(4)] @ A.T)[:, :2]
        out[mid] = np.c_[XY, np.zeros(4)]
    return out


def _marker_scene(n_views: int = 6, world_scale: float = 1.0):
    """Views of the marker plane (z = 0) rendered exactly by a homography; the world then scaled by
    ``world_scale`` (camera translations multiplied), so a marker edge measures EDGE * world_scale."""
    tex = _texture()
    A = _plane_from_texture(tex)
    intr = Intrinsics.from_fov(W, H, 50)
    views, images = [], []
    for i in range(n_views):
        az = 2 * np.pi * i / n_views + 0.3
        el = np.radians(55 + 10 * (i % 2))
        eye = 1.3 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T = look_at(eye, [0.02 * i, -0.01 * i, 0.0])
        Hm = intr.K @ np.c_[T[:3, 0], T[:3, 1], T[:3, 3]] @ A
        img = cv2.warpPerspective(tex, Hm, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                  borderValue=128)
        images.append(np.repeat(img[:, :, None], 3, axis=2))
        T = T.copy()
        T[:3, 3] *= world_scale
        views.append(View(f"v{i:02d}", intr, T, image_file=f"v{i:02d}.png"))
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-0.3, 0.3, (50, 2)), np.zeros(50)] * world_scale
    return SparseModel(views, pts, np.full((50, 3), 200, np.uint8), np.arange(1, 51)), images


def _write_images(tmp_path, model, images):
    paths = []
    for v, img in zip(model.views, images):
        p = tmp_path / v.image_file
        write_image(p, img)
        paths.append(p)
    return paths


def test_marker_scale_recovers_an_arbitrary_world_scale(tmp_path):
    factor = 3.7  # the model's world is 3.7x the scene's: an edge measures 0.3 * 3.7 model units
    model, images = _marker_scene(world_scale=factor)
    paths = _write_images(tmp_path, model, images)
    res = marker_scale(model, paths, 0.10, "4x4_50")
    assert res.markers == 2 and res.views == 6
    true_s = 0.10 / (EDGE * factor)
    err = abs(res.scale / true_s - 1)
    assert err <= 0.005, f"scale error {100 * err:.3f}%"
    assert res.spread < 0.005 and res.reprojection_px < 0.5
    # the scaled model: corners triangulated again measure 0.10 m, and the true corners map to metres
    scaled = apply_similarity(model, res.scale)
    res2 = marker_scale(scaled, paths, 0.10, "DICT_4X4_50")
    assert abs(res2.scale - 1) <= 0.005


def test_apply_similarity_keeps_projections_and_maps_centres():
    model, _ = _marker_scene(n_views=4)
    rng = np.random.default_rng(1)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    s, t = 2.5, np.array([10.0, -3.0, 0.7])
    out = apply_similarity(model, s, R, t)
    X = model.points
    Xn = s * X @ R.T + t
    assert np.allclose(out.points, Xn)
    for v, vn in zip(model.views, out.views):
        uv, z = project(X, v.intrinsics, v.cam_from_world)
        uvn, zn = project(Xn, vn.intrinsics, vn.cam_from_world)
        assert np.abs(uvn - uv).max() < 1e-8  # same pixels
        assert np.allclose(zn, s * z)  # depths scale with the world
        assert np.allclose(vn.center, s * R @ v.center + t)
    assert out.observations is model.observations
    with pytest.raises(BadArgumentError):
        apply_similarity(model, -1.0)
    with pytest.raises(BadArgumentError):
        apply_similarity(model, 1.0, np.diag([1.0, 1.0, -1.0]))


def test_marker_not_found_warns_and_keeps_units_arbitrary(tmp_path, caplog):
    model, images = _marker_scene(n_views=3)
    blank = [np.full_like(im, 128) for im in images]
    out = tmp_path / "out"
    (out / "images").mkdir(parents=True)
    _write_images(out / "images", model, blank)
    write_colmap_text(model, out / "sparse" / "0")
    write_transforms(model.views, out / "transforms.json")
    before = read_colmap_text(out / "sparse" / "0")
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        info = scale_output(out, None, ScaleConfig(marker_size=0.1))
    assert info["units"] == "arbitrary" and info["marker"]["scale"] is None
    assert any("no 4x4_50 ArUco marker detected" in r.getMessage() for r in caplog.records)
    assert json.loads((out / "transforms.json").read_text())["units"] == "arbitrary"
    after = read_colmap_text(out / "sparse" / "0")
    assert np.allclose(after.views[0].cam_from_world, before.views[0].cam_from_world)


def test_scale_output_rewrites_model_and_transforms_in_metres(tmp_path):
    factor = 0.37
    model, images = _marker_scene(world_scale=factor)
    out = tmp_path / "out"
    (out / "images").mkdir(parents=True)
    _write_images(out / "images", model, images)
    write_colmap_text(model, out / "sparse" / "0")
    write_transforms(model.views, out / "transforms.json", mask_dir="masks")
    info = scale_output(out, None, ScaleConfig(marker_size=0.10))
    assert info["units"] == "metre" and info["method"] == "markers"
    true_s = 0.10 / (EDGE * factor)
    assert abs(info["marker"]["scale"] / true_s - 1) <= 0.005
    scaled = read_colmap_text(out / "sparse" / "0")
    # camera centres now in metres: the scene's cameras were 1.3 units from the marker = 1.3 * 0.10 / 0.3 m
    dist = np.linalg.norm(scaled.views[0].center)
    assert abs(dist / (1.3 * 0.10 / EDGE) - 1) < 0.01
    data = json.loads((out / "transforms.json").read_text())
    assert data["units"] == "metre" and data["frames"][0]["mask_path"] == "masks/v00.png"  # other keys kept
    c2w = np.array(data["frames"][0]["transform_matrix"])
    assert np.allclose(c2w[:3, 3], scaled.views[0].center, atol=1e-6)
    assert given_units(out / "transforms.json") == "metre" and given_units(out) == "metre"
    assert given_units(out / "sparse" / "0") == "metre" and given_units(None) == "arbitrary"
    # a re-run measures the scaled model: scale 1, nothing moves
    info2 = scale_output(out, None, ScaleConfig(marker_size=0.10))
    assert abs(info2["marker"]["scale"] - 1) <= 0.005


def test_enu_round_trip():
    origin = (-33.8568, 151.2153, 40.0)  # southern and eastern hemispheres
    enu = np.array([[0, 0, 0], [100.0, -50, 3], [-2000, 1500, -20]])
    lla = geodetic_from_enu(enu, origin)
    assert np.abs(enu_from_geodetic(lla, origin) - enu).max() < 1e-6
    # 1 arc-second of latitude is about 30.9 m north
    d = enu_from_geodetic([[origin[0] + 1 / 3600, origin[1], origin[2]]], origin)[0]
    assert abs(d[1] - 30.87) < 0.1 and abs(d[0]) < 1e-6


def test_gps_alignment_recovers_enu_positions(tmp_path):
    origin = (47.3769, 8.5417, 408.0)
    rng = np.random.default_rng(2)
    enu = np.c_[rng.uniform(-20, 20, (6, 2)), rng.uniform(1.5, 4.0, 6)]  # walking around, 1.5-4 m up
    enu[0] = 0  # the first photo is the ENU origin
    lla = geodetic_from_enu(enu, origin)
    # the model: the same centres in an arbitrary frame (rotated, scaled by 0.05, shifted)
    ang = 0.7
    Rm = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]]) @ \
        np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]])
    centres = 0.05 * enu @ Rm.T + [1.0, 2.0, 3.0]
    intr = Intrinsics.from_fov(32, 24, 60)
    views = []
    paths = []
    for i, c in enumerate(centres):
        T = look_at(c, centres.mean(0) + [0.0, 0.0, 0.01], up=Rm @ [0, 0, 1.0])
        views.append(View(f"p{i}", intr, T))
        paths.append(tmp_path / f"p{i}.jpg")
        write_gps_jpeg(paths[-1], lla[i])
    assert np.allclose(read_gps(paths[1]), lla[1], rtol=0, atol=1e-3)  # altitude stored to the mm
    model = SparseModel(views)
    sim = gps_alignment(model, paths)
    assert sim is not None and sim.photos == 6 and sim.rms_m < 0.02
    assert abs(sim.s - 20.0) < 0.01
    aligned = apply_similarity(model, sim.s, sim.R, sim.t)
    err = np.linalg.norm(np.array([v.center for v in aligned.views]) - enu, axis=1)
    assert err.max() < 0.03, err  # a few cm
    # through the poses hook: the photos found by name in the input folder, the model rewritten in ENU metres
    out = tmp_path / "out"
    write_colmap_text(model, out / "sparse" / "0")
    info = scale_output(out, tmp_path, ScaleConfig())
    assert info["units"] == "metre" and info["method"] == "gps" and abs(info["factor"] - 20.0) < 0.01
    enu_out = np.array([v.center for v in read_colmap_text(out / "sparse" / "0").views])
    assert np.abs(enu_out - enu).max() < 0.03
    assert json.loads((out / "transforms.json").read_text())["units"] == "metre"
    assert scale_output(out, tmp_path, ScaleConfig(gps=False))["units"] == "arbitrary"
    # fewer than 3 photos with GPS: a warning, no alignment
    for p in paths[2:]:
        Image.new("RGB", (32, 24)).save(p, "JPEG")
    assert read_gps(paths[2]) is None
    assert gps_alignment(model, paths) is None


def test_gps_in_fewer_than_three_photos_warns(tmp_path, caplog):
    origin = (47.0, 8.0, 400.0)
    lla = geodetic_from_enu([[0, 0, 0], [10.0, 0, 0], [0, 10.0, 0]], origin)
    paths = []
    views = []
    intr = Intrinsics.from_fov(32, 24, 60)
    for i in range(3):
        paths.append(tmp_path / f"p{i}.jpg")
        if i < 2:
            write_gps_jpeg(paths[-1], lla[i])
        else:
            Image.new("RGB", (32, 24)).save(paths[-1], "JPEG")
        views.append(View(f"p{i}", intr, look_at([i, i * i, 1.0], [0, 5.0, -5.0])))
    model = SparseModel(views)
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        assert gps_alignment(model, paths) is None
    assert any("only 2 of 3 photos have EXIF GPS" in r.getMessage() for r in caplog.records)
    # through the hook: units stay arbitrary
    out = tmp_path / "out"
    write_colmap_text(model, out / "sparse" / "0")
    info = scale_output(out, tmp_path, ScaleConfig())
    assert info["units"] == "arbitrary" and "gps" not in info
    # collinear GPS positions: also refused
    lla = geodetic_from_enu([[0, 0, 0], [10.0, 0, 0], [20.0, 0.01, 0]], origin)
    for i in range(3):
        write_gps_jpeg(paths[i], lla[i])
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        assert gps_alignment(model, paths) is None
    assert any("nearly on a line" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("size", [0.0, -0.1, float("nan")])
def test_bad_marker_size_is_a_bad_argument(size):
    with pytest.raises(BadArgumentError, match="--marker-size"):
        ScaleConfig(marker_size=size)
    with pytest.raises(BadArgumentError, match="--marker-dict"):
        ScaleConfig(marker_size=0.1, marker_dict="9x9_7")


def test_cli_marker_size_zero_exits_2(tmp_path, capsys):
    from photorecon.cli import main

    (tmp_path / "photos").mkdir()
    for cmd in ("sfm", "reconstruct"):
        with pytest.raises(SystemExit) as e:  # refused when the arguments are parsed
            main([cmd, str(tmp_path / "photos"), "-o", str(tmp_path / f"out_{cmd}"), "--marker-size", "0"])
        assert e.value.code == 2
        assert "--marker-size" in capsys.readouterr().err
        assert not (tmp_path / f"out_{cmd}").exists()


def _plane_depth(view: View) -> np.ndarray:
    """Z-depth of the plane z = 0 in ``view`` (0 where the ray misses it)."""
    intr = view.intrinsics
    rays = intr.pixel_rays(intr.pixel_grid().reshape(-1, 2))  # camera frame, z = 1
    world_from_cam = view.world_from_cam
    d = rays @ world_from_cam[:3, :3].T
    c = view.center
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -c[2] / d[:, 2]
    t = np.where(np.isfinite(t) & (t > 0), t, 0.0)
    return t.reshape(intr.height, intr.width).astype(np.float32)


@pytest.mark.slow
def test_reconstruct_with_markers_writes_metres(tmp_path):
    """--poses (arbitrary units) + --depth folder + --marker-size: cameras, depth and mesh come out in metres,
    report.json and transforms.json say so."""
    from photorecon.pipeline import ReconstructConfig, StageConfigs, reconstruct

    factor = 3.7
    model, images = _marker_scene(n_views=5, world_scale=factor)
    photos, depth = tmp_path / "photos", tmp_path / "depth"
    photos.mkdir()
    depth.mkdir()
    _write_images(photos, model, images)
    for v in model.views:
        np.save(depth / f"{v.name}.npy", _plane_depth(v))
    write_transforms(model.views, tmp_path / "transforms.json")
    cfgs = StageConfigs(ReconstructConfig(poses=str(tmp_path / "transforms.json"), depth=str(depth), formats="ply"),
                        scale=ScaleConfig(marker_size=0.10))
    out = tmp_path / "out"
    rep = reconstruct(photos, out, cfgs)
    s = 0.10 / (EDGE * factor)
    assert rep["units"] == "metre" and json.loads((out / "report.json").read_text())["units"] == "metre"
    assert json.loads((out / "transforms.json").read_text())["units"] == "metre"
    assert abs(rep["poses"]["scale"]["factor"] / s - 1) <= 0.005
    d_in, d_out = np.load(depth / "v00.npy"), np.load(out / "depth" / "v00.npy")
    assert np.allclose(d_out[d_in > 0], s * d_in[d_in > 0], rtol=0.006)
    import trimesh

    mesh = trimesh.load(out / "mesh.ply", process=False)
    assert np.abs(mesh.vertices[:, 2]).max() < 0.01  # the floor plane, in metres
    assert np.ptp(mesh.vertices[:, :2], axis=0).max() < 3.0 * 1.3 * 0.10 / EDGE  # not the model's units
    # the same cameras given again (now metric, written by photorecon): units stay metre without markers
    rep2 = reconstruct(photos, tmp_path / "out2", StageConfigs(ReconstructConfig(
        poses=str(out / "transforms.json"), depth=str(out / "depth"), formats="ply")))
    assert rep2["units"] == "metre" and rep2["poses"]["scale"]["factor"] == 1.0
