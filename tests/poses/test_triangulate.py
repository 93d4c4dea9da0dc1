"""Sparse points for given cameras (photorecon.poses.triangulate): poses fixed, points on the true surface."""
import logging

import cv2
import numpy as np
import pytest
import trimesh
from PIL import Image

from photorecon.cameras import project
from photorecon.errors import BadArgumentError, OutputError
from photorecon.io.colmap_text import SparseModel
from photorecon.io.dataset import read_model
from photorecon.poses.triangulate import TriangulateConfig, TriangulateStats, overlap_pairs, triangulate_given

from conftest import tree_hash

CFG = TriangulateConfig(threads=2)


def _bare(model: SparseModel) -> SparseModel:
    """The cameras only, as users bring them (no points, no observations)."""
    return SparseModel(model.views)


def _distance_to_gt(root, points):
    import open3d as o3d

    from photorecon.mesh import raycasting_scene

    gt = trimesh.load(root / "gt_mesh.ply", process=False)
    scene = raycasting_scene(gt)
    d = scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()
    return d, float(np.linalg.norm(gt.extents))


def _check_result(root, given: SparseModel, out: SparseModel):
    # the cameras are exactly the given ones
    assert [v.name for v in out.views] == [v.name for v in given.views]
    for a, b in zip(out.views, given.views):
        assert a.intrinsics == b.intrinsics
        np.testing.assert_allclose(a.cam_from_world, b.cam_from_world, rtol=0, atol=1e-9)
    # enough points, on the true surface
    n = len(out.points)
    assert n > 200
    assert out.colors.shape == (n, 3) and out.colors.dtype == np.uint8 and out.colors.max() > 0
    assert out.point_ids.shape == (n,) and len(np.unique(out.point_ids)) == n
    assert out.errors.shape == (n,) and np.all(out.errors < 4.0)
    d, size = _distance_to_gt(root, out.points)
    assert np.median(d) < 0.005 * size, (np.median(d), size)
    # observations in photorecon pixels: the points project onto their features (a half-pixel slip fails)
    index = out.point_index()
    residuals = []
    for v in out.views:
        uv, ids = out.observations[v.name]
        assert uv.shape == (len(ids), 2)
        keep = ids >= 0
        assert set(ids[keep].tolist()) <= set(index)
        proj, z = project(out.points[[index[int(p)] for p in ids[keep]]], v.intrinsics, v.cam_from_world)
        assert np.all(z > 0)
        residuals.append(np.linalg.norm(proj - uv[keep], axis=1))
    res = np.concatenate(residuals)
    assert len(res) >= 2 * n  # every point seen at least twice
    assert np.median(res) < 0.3, np.median(res)


@pytest.mark.slow
def test_triangulate_given_keeps_cameras_and_lands_on_surface(ring16, tmp_path):
    given = _bare(read_model(ring16))
    before = tree_hash(ring16)
    stats = TriangulateStats()
    out = triangulate_given(ring16 / "images", given, tmp_path / "work", CFG, stats)
    _check_result(ring16, given, out)
    assert stats.points == len(out.points) and stats.matcher == "exhaustive" and stats.warning is None
    assert tree_hash(ring16) == before  # nothing written into the input
    assert (tmp_path / "work" / "database.db").is_file()


@pytest.mark.slow
def test_triangulate_given_grey_alpha_images_and_overlap_pairs(ring16, tmp_path):
    """Grey + alpha PNGs (alpha 0 = no data), matched only on overlapping pairs."""
    images = tmp_path / "grey"
    images.mkdir()
    given = _bare(read_model(ring16))
    for v in given.views:
        rgb = cv2.imread(str(ring16 / "images" / v.image_file), cv2.IMREAD_COLOR)
        grey = cv2.cvtColor(rgb, cv2.COLOR_BGR2GRAY)
        alpha = np.full_like(grey, 255)
        alpha[:, :8] = 0
        Image.fromarray(np.dstack([grey, alpha]), mode="LA").save(images / f"{v.name}.png")
    with Image.open(images / f"{given.views[0].name}.png") as im:
        assert im.mode == "LA"
    stats = TriangulateStats()
    out = triangulate_given(images, given, tmp_path / "work", TriangulateConfig(threads=2, matcher="overlap"), stats)
    _check_result(ring16, given, out)
    assert stats.matcher == "overlap" and stats.pairs < 16 * 15 // 2
    assert (tmp_path / "work" / "masks").is_dir()
    for v in out.views:  # no feature in the masked-out band
        uv, _ = out.observations[v.name]
        assert uv[:, 0].min() >= 7.0


def test_overlap_pairs_ring_neighbours_and_not_opposites(ring16):
    views = read_model(ring16).views
    pairs = overlap_pairs(views, neighbors=4)
    assert pairs and all(i < j for i, j in pairs)
    centres = np.array([v.center for v in views])
    for i, j in pairs:  # 4 neighbours each on a ring of 16: never the camera across the ring
        axis_i, axis_j = views[i].world_from_cam[:3, 2], views[j].world_from_cam[:3, 2]
        assert axis_i @ axis_j > 0, (views[i].name, views[j].name)
    # each camera is paired with its nearest neighbour on the ring
    paired = {(i, j) for i, j in pairs} | {(j, i) for i, j in pairs}
    for i in range(len(views)):
        d = np.linalg.norm(centres - centres[i], axis=1)
        d[i] = np.inf
        assert (i, int(np.argmin(d))) in paired


def test_triangulate_given_textureless_warns_and_returns_model_unchanged(tmp_path, caplog):
    from photorecon.cameras import Intrinsics, View, look_at

    images = tmp_path / "flat"
    images.mkdir()
    intr = Intrinsics.from_fov(96, 72, 50)
    views = [View(f"v{k}", intr, look_at([3 * np.cos(a), 3 * np.sin(a), 0.5], [0, 0, 0]))
             for k, a in enumerate([0.0, 0.3, 0.6])]
    for v in views:
        cv2.imwrite(str(images / f"{v.name}.png"), np.full((72, 96, 3), 128, np.uint8))
    given = SparseModel(views)
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        out = triangulate_given(images, given, tmp_path / "work", CFG)
    assert out is given and len(out.points) == 0
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "0 points" in warnings[0] and "\n" not in warnings[0]


def test_triangulate_given_refuses_work_dir_inside_images_and_bad_models(ring16):
    given = _bare(read_model(ring16))
    with pytest.raises(OutputError, match="inside the image folder"):
        triangulate_given(ring16 / "images", given, ring16 / "images" / "work", CFG)
    with pytest.raises(BadArgumentError, match="at least 2 views"):
        triangulate_given(ring16 / "images", SparseModel(given.views[:1]), "/tmp/unused", CFG)
    assert not (ring16 / "images" / "work").exists()


def _pair_rows(database):
    import sqlite3

    with sqlite3.connect(database) as db:  # a plain scan, as COLMAP's reader does: pair-id (rowid) order
        return (db.execute("SELECT pair_id, rows, data FROM matches").fetchall(),
                db.execute("SELECT pair_id, rows, config, data FROM two_view_geometries").fetchall())


@pytest.mark.slow
def test_given_cameras_match_on_any_number_of_threads_to_the_same_points(ring16, tmp_path):
    """The matcher's threads store the pairs in the order they finish; the database keys them by pair id, so
    the triangulator reads them in the same order whatever that order was, and each pair's RANSAC is seeded:
    two threads twice and one thread give the same bytes."""
    given = _bare(read_model(ring16))
    runs = {}
    for name, threads in (("a", 2), ("b", 2), ("one", 1)):
        stats = TriangulateStats()
        cfg = TriangulateConfig(threads=threads, matcher="overlap", overlap_neighbors=8)
        runs[name] = (triangulate_given(ring16 / "images", given, tmp_path / name, cfg, stats), stats)
    ref, ref_stats = runs["a"]
    assert len(ref.points) > 200 and ref_stats.matcher == "overlap" and ref_stats.pairs < 16 * 15 // 2
    matches, geometries = _pair_rows(tmp_path / "a" / "database.db")
    assert len(matches) == ref_stats.pairs and [r[0] for r in matches] == sorted(r[0] for r in matches)
    assert sum(r[1] > 0 for r in geometries) > 16  # verified pairs, not only empty rows
    for name in ("b", "one"):
        out, _ = runs[name]
        assert _pair_rows(tmp_path / name / "database.db") == (matches, geometries), name
        for field in ("points", "colors", "point_ids", "errors"):
            assert getattr(out, field).tobytes() == getattr(ref, field).tobytes(), (name, field)
        assert out.observations.keys() == ref.observations.keys()
        for v, (uv, ids) in ref.observations.items():
            assert out.observations[v][0].tobytes() == uv.tobytes() and out.observations[v][1].tobytes() == ids.tobytes()
