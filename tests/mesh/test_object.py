"""Object capture (``--scene object``): the support plane an object stands on is found and removed with everything
below it, the object kept; scenes without such a plane are left alone. Rendered ground-truth depth, TSDF."""
import numpy as np
import pytest
import trimesh

from photorecon.fusion import DepthFrame, FusionConfig, fuse
from photorecon.mesh import CleanConfig, clean
from photorecon.metrics import distance_to
from photorecon.render import Renderer
from photorecon.synthetic import SynthConfig, make_views

PLANE_Z = -0.4  # the table top; the object (a flat-topped cylinder and a ball on it) stands on it


def _object():
    cyl = trimesh.creation.cylinder(radius=0.3, height=0.5, sections=48)
    cyl.apply_translation((-0.2, 0.0, PLANE_Z + 0.25))
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.2)
    ball.apply_translation((0.3, 0.1, PLANE_Z + 0.2))
    return trimesh.util.concatenate([cyl, ball])


def _table(half=1.2, n=24):
    return trimesh.creation.box(extents=(2 * half, 2 * half, 0.02)).apply_translation((0, 0, PLANE_Z - 0.01))


def _fused(scene, views):
    r = Renderer(scene, seed=0)
    frames = []
    for v in views:
        out = r.render(v)
        frames.append(DepthFrame(v, out.depth.astype(np.float32), out.rgb))
    return fuse(frames, FusionConfig())


@pytest.fixture(scope="module")
def ring():
    return make_views(SynthConfig(rig="ring", views=10, width=160, height=120, radius=2.6, elevation=25.0))


@pytest.fixture(scope="module")
def on_table(ring):
    obj = _object()
    return obj, _fused(trimesh.util.concatenate([obj, _table()]), ring)


def _near_plane_area(mesh, tol):
    return float(mesh.area_faces[np.abs(mesh.triangles_center[:, 2] - PLANE_Z) < tol].sum())


def test_object_removes_the_support_plane_keeps_the_object(on_table, ring):
    obj, fused = on_table
    voxel = float(fused.metadata["voxel_size"])
    kept = clean(fused, CleanConfig(scene="open"), cameras=ring)
    assert _near_plane_area(kept, 1.5 * voxel) > 0.5  # the table is there with --scene open (about 1.9 of ~2.5 visible)
    # hole filling (on by default) would close the cut-open bottoms with flat patches the truth lacks
    out = clean(fused, CleanConfig(scene="object", fill_holes_voxels=0), cameras=ring)
    # the plane found: normal up, at the table's height
    n = np.array([float(x) for x in out.metadata["support_normal"].split(",")])
    assert n[2] > np.cos(np.radians(1.0)), n
    assert abs(out.metadata["support_offset"] - PLANE_Z) < voxel
    cut = out.metadata["support_cut"]
    assert 2 * voxel - 1e-9 <= cut < 4 * voxel
    # nothing on or below it remains, and nothing of the table anywhere (no rim, no plate)
    assert (out.triangles_center @ n - out.metadata["support_offset"]).min() >= cut
    pts = trimesh.sample.sample_surface(out, 20_000, seed=0)[0]
    assert np.quantile(distance_to(obj, pts), 0.999) < voxel
    # the object kept within a voxel above the cut: what the plain mesh has of it (the parts the cameras saw)
    gt = trimesh.sample.sample_surface(obj, 20_000, seed=1)[0]
    gt = gt[gt[:, 2] > PLANE_Z + cut + voxel]
    seen = gt[distance_to(clean(fused, CleanConfig(scene="open", fill_holes_voxels=0), cameras=ring), gt) < voxel]
    assert len(seen) > 0.8 * len(gt)
    assert np.mean(distance_to(out, seen) < voxel) > 0.999
    assert out.metadata["support_removed_area"] > 0.5
    filled = clean(fused, CleanConfig(scene="object"), cameras=ring)  # the defaults: the table goes as well
    assert _near_plane_area(filled, 1.5 * voxel) == 0 and filled.metadata["support_cut"] == cut


def test_object_without_a_support_plane_removes_nothing(ring):
    """The object alone: its flat top has every camera on one side, but the point the cameras look at lies
    below it, not above: not a support, so nothing is removed."""
    fused = _fused(_object(), ring)
    # no filling: an object capture may fill other holes than an open scene (--fill-object-voxels)
    plain = clean(fused, CleanConfig(fill_holes_voxels=0), cameras=ring)
    out = clean(fused, CleanConfig(scene="object", fill_holes_voxels=0), cameras=ring)
    assert len(out.faces) == len(plain.faces) and "support_normal" not in out.metadata


def test_object_keeps_a_ground_seen_from_both_sides():
    """Cameras all around (a sphere rig sees the table from below too): no camera-side test passes."""
    views = make_views(SynthConfig(rig="sphere", views=12, width=160, height=120, radius=2.6))
    fused = _fused(trimesh.util.concatenate([_object(), _table()]), views)
    out = clean(fused, CleanConfig(scene="object"), cameras=views)
    assert "support_normal" not in out.metadata
    assert _near_plane_area(out, 0.05) > 0.5


def test_every_command_help_renders_and_offers_scene(capsys):
    """``--help`` of the commands that clean a mesh renders (a bare % in a setting's help crashed argparse on
    ``reconstruct --help``) and offers --scene object."""
    from photorecon.cli import main

    for cmd in ("reconstruct", "fuse"):
        with pytest.raises(SystemExit) as e:
            main([cmd, "--help"])
        assert e.value.code == 0 and "--scene {auto,object,open}" in capsys.readouterr().out


@pytest.mark.slow
def test_fuse_command_with_object_leaves_the_object(tmp_path):
    """``photorecon fuse DATA -o OUT --scene object`` on a rendered object on a table: OUT/mesh.ply has no table."""
    from photorecon.cli import main
    from photorecon.mesh import load_mesh
    from photorecon.synthetic import synthesize

    scene = trimesh.util.concatenate([_object(), _table()])
    scene.export(tmp_path / "scene.ply")
    synthesize(SynthConfig(mesh=str(tmp_path / "scene.ply"), rig="ring", views=8, width=128, height=96,
                           radius=2.6, elevation=25.0, points=500), tmp_path / "data")
    # the scene was normalised: the table top in the dataset's world frame (its corners: the largest |x|)
    gt = trimesh.load(tmp_path / "data" / "gt_mesh.ply", process=False)
    corners = gt.vertices[np.abs(gt.vertices[:, 0]) > 0.999 * np.abs(gt.vertices[:, 0]).max()]
    z_top = float(corners[:, 2].max())
    assert main(["fuse", str(tmp_path / "data"), "-o", str(tmp_path / "out"), "--scene", "object", "-q"]) == 0
    assert load_mesh(tmp_path / "out" / "mesh.ply").triangles_center[:, 2].min() > z_top
    assert main(["fuse", str(tmp_path / "data"), "-o", str(tmp_path / "plain"), "--scene", "open", "-q"]) == 0
    plain = load_mesh(tmp_path / "plain" / "mesh.ply")
    assert plain.area_faces[np.abs(plain.triangles_center[:, 2] - z_top) < 0.01].sum() > 0.5  # the table stays
    assert main(["fuse", str(tmp_path / "data"), "-o", str(tmp_path / "auto"), "-q"]) == 0  # --scene auto: removed
    assert load_mesh(tmp_path / "auto" / "mesh.ply").triangles_center[:, 2].min() > z_top


def test_report_html_says_what_object_removed(tmp_path):
    from photorecon.report import write_html_report

    mesh = {"faces": 10, "support_normal": "0.00000,0.00000,1.00000", "support_offset": -0.4, "support_cut": 0.045,
            "support_removed_faces": 1234, "support_removed_area": 2.5}
    page = write_html_report(tmp_path, {"mesh": mesh}).read_text()
    assert "support plane removed" in page and "1,234 faces, area 2.5 units²" in page
    assert "c = -0.4 units, cut 0.045 units" in page
    assert "support plane removed" not in write_html_report(tmp_path, {"mesh": {"faces": 10}}).read_text()


def test_object_keeps_a_flat_object_the_cameras_look_at(ring):
    """A flat object (a board, a painting) with the cameras looking at a point on it: it is not its own support."""
    board = trimesh.creation.box(extents=(1.2, 0.8, 0.02)).apply_translation((0, 0, -0.01))  # top at z = 0
    fused = _fused(board, ring)
    out = clean(fused, CleanConfig(scene="object"), cameras=ring)
    assert "support_normal" not in out.metadata and len(out.faces) == len(clean(fused, cameras=ring).faces)
