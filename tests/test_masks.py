"""The alpha channel of RGBA / grey + alpha images is a mask: Dataset.mask, fusion and reconstruct --poses."""
import dataclasses
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


def test_fusion_excludes_masked_background(rgba, blob_small):
    gt = trimesh.load(blob_small / "gt_mesh.ply", process=False)
    tol = 0.02 * np.linalg.norm(gt.bounds[1] - gt.bounds[0])
    ds = Dataset.open(rgba)
    masked = fuse(load_frames(ds, FusionConfig()), FusionConfig())
    assert len(masked.vertices) > 1000 and _inside(masked, gt.bounds, tol).all()
    # the control: the same depth maps without the masks put the wall into the mesh
    unmasked = fuse(load_frames(ds, FusionConfig(use_masks=False)), FusionConfig(use_masks=False))
    assert (~_inside(unmasked, gt.bounds, tol)).sum() > 1000


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
    from photorecon.pipeline import _undistort_given

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
    res = _undistort_given(SparseModel(views), images, tmp_path / "out")
    for v, src in zip(res.views, views):
        assert not v.intrinsics.has_distortion
        mask = cv2.imread(str(tmp_path / "out" / "masks" / f"{v.name}.png"), cv2.IMREAD_GRAYSCALE) > 0
        img = cv2.imread(str(tmp_path / "out" / "images" / f"{v.name}.png"), cv2.IMREAD_GRAYSCALE) >= 128
        orig = read_alpha(images / f"{v.name}.png") > 0
        assert (mask != img).mean() < 0.005  # mask and image undistorted alike
        assert (mask != orig).mean() > 0.01  # ... and really undistorted
