"""The same photos and settings give the same result, run after run: SfM's cameras (byte for byte as a rule; the
extracted images are numbered by name, not in the order COLMAP's threads finish them; every pair's RANSAC is
seeded), the depth maps, and the mesh file (its vertices and faces in a canonical order, whatever order the
parallel marching cubes took)."""
import numpy as np
import pytest
import trimesh

from photorecon.io.colmap_text import read_colmap_text
from photorecon.testing import synth_scene


@pytest.fixture(scope="module")
def ring_small(tmp_path_factory):
    """16 ring views of the blob at 240x180: SfM in about 3 s."""
    return synth_scene(tmp_path_factory, "ring_small", scene="blob", rig="ring", views=16, width=240, height=180,
                       points=300, seed=5)


def _ids_by_name(database):
    import pycolmap

    db = pycolmap.Database.open(str(database))
    try:
        return {im.name: (im.image_id, db.read_keypoints(im.image_id)) for im in db.read_all_images()}
    finally:
        db.close()


@pytest.mark.slow
def test_sfm_twice_from_scratch_gives_the_same_cameras(ring_small, tmp_path):
    from photorecon.poses.sfm import SfMConfig, run_sfm

    runs = []
    for name in ("a", "b"):  # one thread: with more, the mapper is not repeatable every time (docs/troubleshooting.md)
        out = tmp_path / name
        res = run_sfm(ring_small / "images", out, SfMConfig(threads=1))
        assert len(res.registered) == 16
        runs.append(out)
    a, b = (read_colmap_text(r / "sparse" / "0") for r in runs)
    assert [v.name for v in a.views] == [v.name for v in b.views]
    size = np.ptp([np.linalg.inv(v.cam_from_world)[:3, 3] for v in a.views], axis=0).max()
    for va, vb in zip(a.views, b.views):  # the same cameras (bundle adjustment's threads may sum the last bits
        # of a float in another order on a busy machine: equal to far below any measurable difference)
        assert np.allclose(va.cam_from_world[:3, :3], vb.cam_from_world[:3, :3], atol=1e-9, rtol=0), va.name
        assert np.allclose(va.cam_from_world[:3, 3], vb.cam_from_world[:3, 3], atol=1e-9 * size, rtol=0), va.name
        assert np.allclose(va.intrinsics.K, vb.intrinsics.K, rtol=1e-9, atol=0), va.name
    assert abs(len(a.points) - len(b.points)) <= 0.001 * len(a.points)
    ids = _ids_by_name(runs[0] / "colmap" / "features.db")
    assert [ids[n][0] for n in sorted(ids)] == list(range(1, 17))  # numbered in name order


def test_extraction_numbers_images_by_name_whatever_order_they_come_in(ring_small, tmp_path):
    """Images extracted in reverse name order (as threads finishing in another order would write them) end up
    numbered by name, each with its own keypoints."""
    from photorecon.poses.sfm import SfMConfig, extract

    names = sorted(p.name for p in (ring_small / "images").iterdir())[:6]
    cams = {"model": "SIMPLE_RADIAL", "params": "", "size": [240, 180]}
    fwd = extract(ring_small / "images", tmp_path / "fwd.db", [{**cams, "images": names}], SfMConfig(threads=1))
    rev = extract(ring_small / "images", tmp_path / "rev.db", [{**cams, "images": names[::-1]}], SfMConfig(threads=1))
    a, b = _ids_by_name(fwd), _ids_by_name(rev)
    assert [b[n][0] for n in names] == list(range(1, len(names) + 1))
    for n in names:
        assert len(a[n][1]) > 50 and np.array_equal(a[n][1], b[n][1]), n
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fwd.db", "rev.db"]  # no temporary left


@pytest.mark.slow
def test_given_cameras_triangulate_to_the_same_points_twice(ring_small, tmp_path):
    """Depth ranges and view selection come from these points when cameras are given without them: each pair's
    RANSAC is seeded, and the points are numbered by position (the triangulator's threads number them in any
    order)."""
    from photorecon.io.dataset import Dataset
    from photorecon.poses.triangulate import triangulate_given

    ds = Dataset.open(ring_small)
    a, b = (triangulate_given(ds.layout.images, ds.model, tmp_path / name) for name in ("a", "b"))
    assert len(a.points) > 50 and len(a.points) == len(b.points)
    assert np.allclose(a.points, b.points, rtol=0, atol=1e-9)  # the bundle adjustment's last bits may differ
    assert np.array_equal(a.point_ids, b.point_ids) and np.array_equal(a.point_ids, np.arange(1, len(a.points) + 1))
    assert np.all(np.diff(a.points[:, 0]) >= 0)
    for v in a.views:
        assert np.array_equal(a.observations[v.name][1], b.observations[v.name][1]), v.name


def test_canonical_order_is_the_same_for_any_order_of_the_same_mesh():
    from photorecon.fusion import canonical_order

    rng = np.random.default_rng(1)
    m = trimesh.creation.icosphere(subdivisions=3)
    m.visual.vertex_colors = rng.integers(0, 256, (len(m.vertices), 4), dtype=np.uint8)
    perm = rng.permutation(len(m.vertices))
    faces = np.argsort(perm)[m.faces][rng.permutation(len(m.faces))]
    shuffled = trimesh.Trimesh(m.vertices[perm], np.roll(faces, 1, axis=1),  # each face rotated: same winding
                               vertex_colors=m.visual.vertex_colors[perm], process=False)
    a, b = canonical_order(m), canonical_order(shuffled)
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert np.array_equal(a.visual.vertex_colors, b.visual.vertex_colors)
    assert np.isclose(a.volume, m.volume) and a.volume > 0  # same surface, outward winding kept


@pytest.mark.slow
def test_depth_and_mesh_twice_are_identical_files(blob_small, tmp_path):
    from photorecon.cli import main

    outs = []
    for name in ("a", "b"):
        out = tmp_path / name
        assert main(["-q", "reconstruct", str(blob_small / "images"), "--poses", str(blob_small / "sparse" / "0"),
                     "-o", str(out), "--formats", "ply", "--quality", "preview"]) == 0
        outs.append(out)
    depth = sorted(p.name for p in (outs[0] / "depth").glob("*.npy"))
    assert len(depth) >= 12
    for n in depth:
        assert (outs[0] / "depth" / n).read_bytes() == (outs[1] / "depth" / n).read_bytes(), n
    assert (outs[0] / "mesh.ply").read_bytes() == (outs[1] / "mesh.ply").read_bytes()
