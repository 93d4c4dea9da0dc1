"""Synthetic scenes: rendered depth lies on the ground truth, COLMAP / transforms.json agree, colours agree."""
import json

import cv2
import numpy as np
import pytest
import trimesh

from photorecon.cameras import backproject_depth
from photorecon.conventions import opencv_from_nerf
from photorecon.errors import BadArgumentError, InputDataError
from photorecon.io.colmap_text import read_colmap_text
from photorecon.io.images import read_image
from photorecon.synthetic import SynthConfig, make_scene, synthesize


def _point_to_mesh(points, mesh_path):
    import open3d as o3d

    m = o3d.t.io.read_triangle_mesh(str(mesh_path))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(m)
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


@pytest.mark.parametrize("scene", ["blob", "knot", "room"])
def test_depth_backprojects_onto_ground_truth(tmp_path, scene):
    synthesize(SynthConfig(scene=scene, views=3, width=160, height=120, points=300), tmp_path, overwrite=True)
    model = read_colmap_text(tmp_path / "sparse" / "0")
    gt = trimesh.load(tmp_path / "gt_mesh.ply", process=False)
    diag = np.linalg.norm(gt.bounds[1] - gt.bounds[0])
    n_pts = 0
    for v in model.views:
        depth = np.load(tmp_path / "depth" / f"{v.name}.npy")
        assert depth.dtype == np.float32 and depth.shape == (120, 160)
        pts = backproject_depth(depth, v.intrinsics, v.cam_from_world)
        n_pts += len(pts)
        d = _point_to_mesh(pts, tmp_path / "gt_mesh.ply")
        assert d.max() < 1e-4 * diag, f"{scene} {v.name}: max distance {d.max():.2e} vs diag {diag:.2f}"
        mask = cv2.imread(str(tmp_path / "masks" / f"{v.name}.png"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(mask > 0, depth > 0)
        assert read_image(tmp_path / "images" / f"{v.name}.png").shape == (120, 160, 3)
        assert (tmp_path / "depth" / f"{v.name}.png").is_file()
    assert n_pts > 1000


def test_colmap_model_reads_with_pycolmap_and_matches_render(blob_small):
    import pycolmap

    rec = pycolmap.Reconstruction(str(blob_small / "sparse" / "0"))
    assert rec.num_reg_images() == 12 and rec.num_points3D() > 500
    depths = {}
    worst = 0.0
    checked = 0
    for image in rec.images.values():
        cam = rec.cameras[image.camera_id]
        T = image.cam_from_world()
        stem = image.name.rsplit(".", 1)[0]
        depths[stem] = np.load(blob_small / "depth" / f"{stem}.npy")
        for p2d in image.points2D:
            if not p2d.has_point3D():
                continue
            xyz = rec.points3D[p2d.point3D_id].xyz
            pc = T * xyz
            uv = cam.img_from_cam(pc)  # pycolmap: COLMAP convention
            worst = max(worst, float(np.abs(uv - p2d.xy).max()))
            # where it was rendered: the z-buffer at that pixel (OpenCV = COLMAP - 0.5) has the point's depth
            u, v = np.round(uv - 0.5).astype(int)
            z = depths[stem][max(v - 1, 0):v + 2, max(u - 1, 0):u + 2]  # 3x3: silhouettes are steep
            assert np.abs(z - pc[2]).min() < 0.01 * pc[2], (stem, u, v, z, pc[2])
            checked += 1
    assert worst < 0.5 and checked > 1000


def test_transforms_json_equals_colmap(blob_small):
    model = read_colmap_text(blob_small / "sparse" / "0")
    data = json.loads((blob_small / "transforms.json").read_text())
    assert len(data["frames"]) == len(model.views)
    for fr, v in zip(data["frames"], model.views):
        assert fr["file_path"] == f"images/{v.name}.png"
        np.testing.assert_allclose(opencv_from_nerf(np.array(fr["transform_matrix"])), v.cam_from_world, atol=1e-9)
        # nerfstudio's principal point is a pixel-corner coordinate, as COLMAP's
        assert data["cx"] == pytest.approx(v.intrinsics.cx + 0.5)


def test_colour_consistent_across_views(blob_small):
    model = read_colmap_text(blob_small / "sparse" / "0")
    imgs = {v.name: read_image(blob_small / "images" / f"{v.name}.png").astype(np.float32) for v in model.views}
    seen: dict[int, list] = {}
    for v in model.views:
        uv, ids = model.observations[v.name]
        img = imgs[v.name]
        cols = cv2.remap(img, uv[:, 0].astype(np.float32)[:, None], uv[:, 1].astype(np.float32)[:, None],
                         cv2.INTER_LINEAR)[:, 0]
        for pid, c in zip(ids, cols):
            seen.setdefault(int(pid), []).append(c)
    diffs = [np.abs(c[0] - c[1]).mean() for c in seen.values() if len(c) >= 2]
    assert len(diffs) > 300
    # same colour up to interpolation (a view-dependent light would give tens of levels)
    assert np.median(diffs) < 6.0, np.median(diffs)


def test_textured_mesh_file_uses_its_texture(tmp_path):
    from PIL import Image

    box = trimesh.creation.box(extents=(1, 1, 1))
    uv = np.c_[(box.vertices[:, 0] + 0.5), (box.vertices[:, 1] + 0.5)]
    tex = np.zeros((64, 64, 3), np.uint8)
    tex[:, :32] = (255, 0, 0)
    tex[:, 32:] = (0, 0, 255)
    box.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(tex))
    path = tmp_path / "box.obj"
    box.export(path)
    out = tmp_path / "out"
    synthesize(SynthConfig(mesh=str(path), views=2, width=64, height=48, points=50), out)
    info = json.loads((out / "scene.json").read_text())
    assert info["appearance"] == "texture"
    img = read_image(out / "images" / "view_000.png")
    surf = img[cv2.imread(str(out / "masks" / "view_000.png"), 0) > 0].astype(int)
    assert (surf[:, 0] > surf[:, 1] + 40).any() and (surf[:, 2] > surf[:, 1] + 40).any()


def test_normalisation_written(tmp_path):
    m = trimesh.creation.icosphere(subdivisions=2, radius=5.0)
    m.apply_translation((10, 0, 0))
    path = tmp_path / "s.ply"
    m.export(path)
    synthesize(SynthConfig(mesh=str(path), views=1, width=32, height=24, points=0), tmp_path / "o")
    info = json.loads((tmp_path / "o" / "scene.json").read_text())
    c, s = np.array(info["normalization"]["center"]), info["normalization"]["scale"]
    gt = trimesh.load(tmp_path / "o" / "gt_mesh.ply", process=False)
    np.testing.assert_allclose(gt.vertices * s + c, m.vertices, atol=1e-5)


def test_bad_inputs(tmp_path):
    empty = tmp_path / "empty.ply"
    trimesh.Trimesh(vertices=np.zeros((3, 3)), faces=np.zeros((0, 3), int)).export(empty)
    with pytest.raises(InputDataError, match="no faces"):
        synthesize(SynthConfig(mesh=str(empty), views=2), tmp_path / "a")
    with pytest.raises(InputDataError, match="no such mesh"):
        synthesize(SynthConfig(mesh=str(tmp_path / "missing.obj"), views=2), tmp_path / "b")
    with pytest.raises(BadArgumentError, match=r"SynthConfig.views \(--views\): expected an integer in 1\.\.100000"):
        synthesize(SynthConfig(views=0), tmp_path / "c")
    with pytest.raises(BadArgumentError, match=r"SynthConfig.width \(--width\): expected an integer in 16\.\."):
        synthesize(SynthConfig(views=2, width=0), tmp_path / "d")
    assert not (tmp_path / "c").exists() and not (tmp_path / "d").exists()
    with pytest.raises(BadArgumentError, match="scene"):
        make_scene("teapot")


def test_cli_synth_and_errors(tmp_path):
    from photorecon.cli import main

    assert main(["-q", "synth", "-o", str(tmp_path / "ok"), "--views", "2", "--width", "48", "--height", "32",
                 "--scene", "knot", "--rig", "ring"]) == 0
    assert len(list((tmp_path / "ok" / "images").glob("*.png"))) == 2
    with pytest.raises(SystemExit) as e:  # refused when the arguments are parsed
        main(["-q", "synth", "-o", str(tmp_path / "bad"), "--views", "0"])
    assert e.value.code == 2
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("mine")
    assert main(["-q", "synth", "-o", str(tmp_path / "foreign"), "--views", "1"]) == 8
    assert (tmp_path / "foreign" / "notes.txt").read_text() == "mine"


def test_layout_names_every_file_synth_writes(tmp_path):
    """The one Layout object and the files a dataset holds agree: every file synth wrote is a path the Layout
    names (nothing written under a hand-made path), and the Dataset reader finds a view's files through it."""
    from photorecon.io.dataset import Dataset
    from photorecon.layout import Layout

    root = synthesize(SynthConfig(scene="blob", views=3, width=48, height=36, points=50), tmp_path / "d").root
    lay = Layout(root)
    ds = Dataset.open(root)
    named = {lay.transforms, lay.gt_mesh, lay.scene, *(lay.sparse / f for f in ("cameras.txt", "images.txt", "points3D.txt"))}
    for v in ds.views:
        assert ds.image_path(v) == lay.image(v.image_file) and ds.depth_path(v) == lay.depth_map(v.name)
        assert ds.mask_path(v) == lay.mask(v.name)
        named |= {lay.image(v.image_file), lay.depth_map(v.name), lay.mask(v.name), lay.depth / f"{v.name}.png"}
    written = {p for p in root.rglob("*") if p.is_file() and p.name != ".photorecon"}
    assert written == named
