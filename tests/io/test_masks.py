"""The alpha channel of RGBA / grey + alpha images is a mask: Dataset.mask, fusion and reconstruct --poses."""
import dataclasses
import json
import shutil
import struct
import zlib

import cv2
import numpy as np
import pytest
import trimesh

from photorecon.cli import main
from photorecon.fusion import FusionConfig, fuse, load_frames
from photorecon.io.colmap_text import SparseModel
from photorecon.io.dataset import Dataset
from photorecon.io.images import read_alpha, read_image


def _write_grey_alpha_png(path, grey, alpha):
    """An 8-bit grey + alpha PNG (colour type 4), written by hand: OpenCV cannot write two channels."""
    h, w = grey.shape
    rows = np.dstack([grey, alpha]).astype(np.uint8).reshape(h, 2 * w)
    raw = b"".join(b"\x00" + r.tobytes() for r in rows)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 4, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


@pytest.fixture(scope="module")
def rgba(blob_small, tmp_path_factory):
    """blob_small with its masks moved into the images' alpha (no masks/ folder), and depth maps that see a
    background wall behind the object wherever the mask is 0."""
    root = tmp_path_factory.mktemp("rgba")
    shutil.copytree(blob_small / "sparse", root / "sparse")
    (root / "images").mkdir()
    (root / "depth").mkdir()
    ds = Dataset.open(blob_small)
    for v in ds.views:
        rgb, mask, depth = ds.image(v), ds.mask(v), ds.depth(v)
        assert mask is not None and mask.any() and not mask.all()
        bgra = np.dstack([cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), np.where(mask, 255, 0).astype(np.uint8)])
        cv2.imwrite(str(root / "images" / f"{v.name}.png"), bgra)
        wall = np.where(mask, depth, 1.5 * depth[mask].max()).astype(np.float32)
        np.save(root / "depth" / f"{v.name}.npy", wall)
    return root


def test_alpha_is_the_mask(rgba, blob_small):
    ds, ref = Dataset.open(rgba), Dataset.open(blob_small)
    assert not (rgba / "masks").exists()
    for v in ds.views[:4]:
        m = ds.mask(v)
        assert m is not None and m.dtype == bool
        np.testing.assert_array_equal(m, ref.mask(v))
        np.testing.assert_array_equal(ds.image(v), ref.image(v))  # colour kept as stored, alpha dropped
    # an explicit masks/NAME.png wins over the alpha
    v = ds.views[0]
    (rgba / "masks").mkdir()
    try:
        cv2.imwrite(str(rgba / "masks" / f"{v.name}.png"), np.full((v.intrinsics.height, v.intrinsics.width), 255, np.uint8))
        assert ds.mask(v).all()
    finally:
        shutil.rmtree(rgba / "masks")
    # plain RGB images: no mask, and the PNG is not decoded to find that out
    assert read_alpha(blob_small / "images" / f"{v.name}.png") is None and ref.mask(v) is not None


def test_grey_alpha_png(tmp_path):
    grey = np.arange(12 * 16, dtype=np.uint8).reshape(12, 16)
    alpha = np.zeros((12, 16), np.uint8)
    alpha[3:9, 4:10] = 200
    p = tmp_path / "la.png"
    _write_grey_alpha_png(p, grey, alpha)
    np.testing.assert_array_equal(read_alpha(p), alpha)
    img = read_image(p)
    assert img.shape == (12, 16, 3)
    np.testing.assert_array_equal(img, np.dstack([grey] * 3))  # not blended with black where alpha is 0
    with pytest.raises(Exception, match="la_bad.png"):
        (tmp_path / "la_bad.png").write_bytes(p.read_bytes()[:40])
        read_alpha(tmp_path / "la_bad.png")


def _inside(mesh, box, tol):
    v = np.asarray(mesh.vertices)
    return np.all((v >= box[0] - tol) & (v <= box[1] + tol), axis=1)


@pytest.mark.slow
def test_fusion_excludes_masked_background(rgba, blob_small):
    gt = trimesh.load(blob_small / "gt_mesh.ply", process=False)
    tol = 0.02 * np.linalg.norm(gt.bounds[1] - gt.bounds[0])
    ds = Dataset.open(rgba)
    masked = fuse(load_frames(ds, FusionConfig()), FusionConfig())
    assert len(masked.vertices) > 1000 and _inside(masked, gt.bounds, tol).all()
    # the control: the same depth maps without the masks put the wall into the mesh
    unmasked = fuse(load_frames(ds, FusionConfig(use_masks=False)), FusionConfig(use_masks=False))
    assert (~_inside(unmasked, gt.bounds, tol)).sum() > 1000


@pytest.mark.slow
def test_reconstruct_given_poses_writes_alpha_masks(rgba, blob_small, tmp_path):
    out = tmp_path / "out"
    assert main(["-q", "reconstruct", str(rgba / "images"), "-o", str(out), "--poses", str(blob_small / "transforms.json"),
                 "--depth", str(rgba / "depth")]) == 0
    ds = Dataset.open(out)
    for v in ds.views:
        np.testing.assert_array_equal(cv2.imread(str(out / "masks" / f"{v.name}.png"), cv2.IMREAD_GRAYSCALE) > 0,
                                      read_alpha(rgba / "images" / f"{v.name}.png") > 0)
        assert read_alpha(ds.image_path(v)) is None  # OUT/images are RGB; the mask lives in OUT/masks
    gt = trimesh.load(blob_small / "gt_mesh.ply", process=False)
    mesh = trimesh.load(out / "mesh.ply", process=False)
    assert _inside(mesh, gt.bounds, 0.02 * np.linalg.norm(gt.bounds[1] - gt.bounds[0])).all()


def test_undistorted_mask_follows_the_image(rgba, tmp_path):
    from photorecon.poses.ingest import ingest_given

    # images whose colour is their mask, behind a distorted camera
    images = tmp_path / "images"
    images.mkdir()
    model = Dataset.open(rgba).model
    views = []
    for v in model.views[:3]:
        a = read_alpha(rgba / "images" / f"{v.name}.png")
        cv2.imwrite(str(images / f"{v.name}.png"), np.dstack([a, a, a, a]))
        intr = dataclasses.replace(v.intrinsics, model="OPENCV", k1=-0.25, k2=0.05)
        views.append(dataclasses.replace(v, intrinsics=intr))
    res = ingest_given(SparseModel(views), images, tmp_path / "out")
    for v, src in zip(res.views, views):
        assert not v.intrinsics.has_distortion
        mask = cv2.imread(str(tmp_path / "out" / "masks" / f"{v.name}.png"), cv2.IMREAD_GRAYSCALE) > 0
        img = cv2.imread(str(tmp_path / "out" / "images" / f"{v.name}.png"), cv2.IMREAD_GRAYSCALE) >= 128
        orig = read_alpha(images / f"{v.name}.png") > 0
        assert (mask != img).mean() < 0.005  # mask and image undistorted alike
        assert (mask != orig).mean() > 0.01  # ... and really undistorted


# --- --masks DIR: a user's mask folder for sfm, mvs, fuse and reconstruct -------------------------------------
def _backdrop_depth(view, radius=2.0):
    """z-depth (H, W) of the far side of a sphere of ``radius`` around the origin: a backdrop shell behind
    the object, seen by every pixel whose ray reaches it."""
    from photorecon.cameras import invert_rigid

    intr = view.intrinsics
    rays = intr.pixel_rays(intr.pixel_grid().reshape(-1, 2))  # z = 1
    world_from_cam = invert_rigid(view.cam_from_world)
    norm = np.linalg.norm(rays, axis=1)
    d = (rays @ world_from_cam[:3, :3].T) / norm[:, None]
    o = world_from_cam[:3, 3]
    b, c = d @ o, o @ o - radius ** 2
    disc = b * b - c
    s = np.where(disc > 0, -b + np.sqrt(np.maximum(disc, 0)), 0)
    return (s / norm).reshape(intr.height, intr.width).astype(np.float32)


@pytest.fixture(scope="module")
def backdrop(tmp_path_factory):
    """A textured blob in front of a textured backdrop (12 views, 160x120), split the way a user has it:
    ``data/`` (sparse/0, images/, depth/ that sees a backdrop shell wherever the object is not, no masks/)
    and ``usermasks/`` (the object's masks; even views named COLMAP's way, NAME.EXT.png, odd ones NAME.png)."""
    from photorecon.synthetic import SynthConfig, synthesize

    root = tmp_path_factory.mktemp("backdrop")
    synthesize(SynthConfig(scene="blob", views=12, width=160, height=120, points=500, seed=4, background="texture"),
               root / "synth", overwrite=True)
    data, masks = root / "data", root / "usermasks"
    shutil.copytree(root / "synth" / "sparse", data / "sparse")
    shutil.copytree(root / "synth" / "images", data / "images")
    (data / "depth").mkdir()
    masks.mkdir()
    for k, v in enumerate(Dataset.open(root / "synth").views):
        obj = np.load(root / "synth" / "depth" / f"{v.name}.npy")
        hit = obj > 0
        assert hit.any() and not hit.all()
        np.save(data / "depth" / f"{v.name}.npy", np.where(hit, obj, _backdrop_depth(v)).astype(np.float32))
        name = f"{v.name}.png.png" if k % 2 == 0 else f"{v.name}.png"
        shutil.copyfile(root / "synth" / "masks" / f"{v.name}.png", masks / name)
    return root


def test_user_mask_folder_reaches_the_dataset(backdrop):
    ds = Dataset.open(backdrop / "data", masks_dir=backdrop / "usermasks")
    plain = Dataset.open(backdrop / "data")
    for v in ds.views:
        truth = cv2.imread(str(backdrop / "synth" / "masks" / f"{v.name}.png"), cv2.IMREAD_GRAYSCALE) > 0
        np.testing.assert_array_equal(ds.mask(v), truth)  # both namings found
        assert plain.mask(v) is None  # no DATASET/masks, RGB images: no mask


@pytest.mark.slow
def test_fuse_with_masks_drops_the_backdrop(backdrop, tmp_path):
    gt = trimesh.load(backdrop / "synth" / "gt_mesh.ply", process=False)
    tol = 0.02 * np.linalg.norm(gt.bounds[1] - gt.bounds[0])
    data, masks = backdrop / "data", backdrop / "usermasks"
    assert main(["-q", "fuse", str(data), "-o", str(tmp_path / "masked"), "--masks", str(masks)]) == 0
    masked = trimesh.load(tmp_path / "masked" / "mesh.ply", process=False)
    assert len(masked.vertices) > 1000 and _inside(masked, gt.bounds, tol).all()
    # the control: the same depth maps without --masks fuse the backdrop shell too
    assert main(["-q", "fuse", str(data), "-o", str(tmp_path / "unmasked")]) == 0
    unmasked = trimesh.load(tmp_path / "unmasked" / "mesh.ply", process=False)
    assert (~_inside(unmasked, gt.bounds, tol)).sum() > 1000


@pytest.mark.slow
def test_reconstruct_carries_user_masks_and_reruns_when_they_change(backdrop, tmp_path):
    data, out = backdrop / "data", tmp_path / "out"
    masks = tmp_path / "usermasks"
    shutil.copytree(backdrop / "usermasks", masks)
    args = ["-q", "reconstruct", str(data / "images"), "-o", str(out), "--poses", str(data / "sparse" / "0"),
            "--depth", str(data / "depth"), "--masks", str(masks)]
    assert main(args) == 0
    for v in Dataset.open(out).views:
        truth = cv2.imread(str(backdrop / "synth" / "masks" / f"{v.name}.png"), cv2.IMREAD_GRAYSCALE) > 0
        np.testing.assert_array_equal(cv2.imread(str(out / "masks" / f"{v.name}.png"), cv2.IMREAD_GRAYSCALE) > 0, truth)
    gt = trimesh.load(backdrop / "synth" / "gt_mesh.ply", process=False)
    mesh = trimesh.load(out / "mesh.ply", process=False)
    assert _inside(mesh, gt.bounds, 0.02 * np.linalg.norm(gt.bounds[1] - gt.bounds[0])).all()

    def stages():
        rep = json.loads((out / "report.json").read_text())["stages"]
        return {k: bool(s.get("cached")) for k, s in rep.items()}

    assert main(args) == 0 and all(stages().values())  # unchanged: nothing reruns
    first = sorted(masks.iterdir())[0]
    m = cv2.imread(str(first), cv2.IMREAD_GRAYSCALE)
    m[:, : m.shape[1] // 2] = 0
    cv2.imwrite(str(first), m)
    assert main(args) == 0
    assert not any(stages().values())  # a changed mask reruns poses (the undistorted masks) and what follows
    name = first.name.split(".")[0]
    assert not (cv2.imread(str(out / "masks" / f"{name}.png"), cv2.IMREAD_GRAYSCALE)[:, : m.shape[1] // 2]).any()


@pytest.mark.slow
def test_sfm_masks_reach_feature_extraction(tmp_path):
    """sfm --masks: COLMAP extracts no keypoint where the mask is 0, and OUT/masks holds the undistorted masks;
    the control extraction without masks finds keypoints on the textured backdrop."""
    import pycolmap

    from photorecon.poses.sfm import SfMConfig, extract
    from photorecon.synthetic import SynthConfig, synthesize

    synthesize(SynthConfig(scene="blob", rig="ring", views=16, width=320, height=240, points=200, seed=5,
                           background="texture"), tmp_path / "synth", overwrite=True)
    images, masks = tmp_path / "synth" / "images", tmp_path / "usermasks"
    masks.mkdir()
    truth = {}
    for k, p in enumerate(sorted((tmp_path / "synth" / "masks").glob("*.png"))):
        truth[p.name] = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) > 0
        shutil.copyfile(p, masks / (f"{p.name}.png" if k % 2 else p.name))
    out = tmp_path / "out"
    assert main(["-q", "sfm", str(images), "-o", str(out), "--masks", str(masks)]) == 0

    def keypoints_outside(db_path):
        db = pycolmap.Database.open(str(db_path))
        try:
            n = total = 0
            for im in db.read_all_images():
                xy = np.floor(db.read_keypoints(im.image_id)[:, :2]).astype(int)  # COLMAP: pixel corner at 0
                m = truth[im.name]
                n += int((~m[np.clip(xy[:, 1], 0, m.shape[0] - 1), np.clip(xy[:, 0], 0, m.shape[1] - 1)]).sum())
                total += len(xy)
            return n, total
        finally:
            db.close()

    outside, total = keypoints_outside(out / "colmap" / "features.db")
    assert total > 2000 and outside == 0
    assert sorted(p.name for p in (out / "colmap" / "masks").iterdir()) == sorted(f"{n}.png" for n in truth)
    # undistorted like the images: at the undistorted camera's size (COLMAP crops a pixel or so here), and,
    # with near-zero distortion, the given masks cut where the principal point moved
    from photorecon.io.dataset import read_model

    distorted = {v.name: v.intrinsics for v in read_model(out / "colmap" / "sparse").views}
    for v in read_model(out / "sparse" / "0").views:
        und = cv2.imread(str(out / "masks" / f"{v.name}.png"), cv2.IMREAD_GRAYSCALE) > 0
        assert und.shape == (v.intrinsics.height, v.intrinsics.width)
        ox, oy = (round(a - b) for a, b in zip((distorted[v.name].cx, distorted[v.name].cy),
                                                (v.intrinsics.cx, v.intrinsics.cy)))
        m = truth[f"{v.name}.png"][oy:oy + und.shape[0], ox:ox + und.shape[1]]
        assert (und != m).mean() < 0.01
    h, w = next(iter(truth.values())).shape[:2]
    cams = [{"model": "SIMPLE_RADIAL", "params": "", "images": sorted(truth), "size": [w, h]}]
    extract(out / "colmap" / "images", tmp_path / "plain.db", cams, SfMConfig())
    outside, total = keypoints_outside(tmp_path / "plain.db")
    assert outside > 1000  # the backdrop is textured: without masks it has keypoints


def test_bad_mask_folders_fail_before_writing(backdrop, tmp_path, capsys):
    data = backdrop / "data"
    wrong = tmp_path / "wrong"
    shutil.copytree(backdrop / "usermasks", wrong)
    bad = sorted(wrong.iterdir())[3]
    cv2.imwrite(str(bad), np.full((60, 80), 255, np.uint8))
    nomatch = tmp_path / "nomatch"
    nomatch.mkdir()
    cv2.imwrite(str(nomatch / "other.png"), np.full((120, 160), 255, np.uint8))
    cases = [
        (["fuse", str(data)], wrong, bad.name),
        (["mvs", str(data)], wrong, bad.name),
        (["reconstruct", str(data / "images"), "--poses", str(data / "sparse" / "0"), "--depth", str(data / "depth")],
         wrong, bad.name),
        (["sfm", str(data / "images")], wrong, bad.name),
        (["fuse", str(data)], nomatch, "nomatch"),
        (["sfm", str(data / "images")], nomatch, "nomatch"),
        (["reconstruct", str(data / "images")], tmp_path / "missing", "missing"),
    ]
    for k, (cmd, masks, named) in enumerate(cases):
        out = tmp_path / f"out{k}"
        capsys.readouterr()
        assert main(["-q", *cmd, "-o", str(out), "--masks", str(masks)]) == 3, cmd
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and named in err, err
        assert masks != wrong or "80x60" in err, err  # says what was found
        assert not out.exists(), cmd  # nothing written


def test_alpha_reaches_colmap_masks(rgba, tmp_path):
    """SfM's mask conversion: an image's alpha becomes COLMAP's NAME.EXT.png; a user's mask wins over it;
    an image with neither gets none."""
    from photorecon.poses.sfm import write_colmap_masks

    names = sorted(p.name for p in (rgba / "images").iterdir())[:3]
    images = [(n, 160, 120) for n in names]
    user = tmp_path / "user"
    user.mkdir()
    cv2.imwrite(str(user / names[1]), np.zeros((120, 160), np.uint8))  # NAME.png for image NAME.png
    plain = tmp_path / "plain"
    plain.mkdir()
    cv2.imwrite(str(plain / names[2]), cv2.imread(str(rgba / "images" / names[2]), cv2.IMREAD_COLOR))
    dst = tmp_path / "colmap_masks"
    dst.mkdir()
    assert write_colmap_masks(images, rgba / "images", user, dst) == 3
    np.testing.assert_array_equal(cv2.imread(str(dst / f"{names[0]}.png"), cv2.IMREAD_GRAYSCALE) > 0,
                                  read_alpha(rgba / "images" / names[0]) > 0)
    assert not cv2.imread(str(dst / f"{names[1]}.png"), cv2.IMREAD_GRAYSCALE).any()
    dst2 = tmp_path / "none"
    dst2.mkdir()
    assert write_colmap_masks([(names[2], 160, 120)], plain, None, dst2) == 0 and not any(dst2.iterdir())
