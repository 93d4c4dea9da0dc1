"""Hole filling (``mesh.fill``, ``mesh.close``): small holes in a surface closed by faired patches that follow it, big ones
left open, the observed surface untouched; the watertight companion of an object. A unit sphere with holes
punched is the ground truth (scene units: its radius)."""
import numpy as np
import pytest
import trimesh

from photorecon.mesh import (CleanConfig, boundary_length, boundary_loops, clean, close_mesh, fill_loops,
                             fill_small_holes,
                             filled_area)
from photorecon.mesh.clean import fill_radius

SMALL = ((np.array([0.0, 0.0, 1.0]), 0.12), (np.array([1.0, 0.0, 0.0]), 0.2))  # (direction, chord radius)
BIG = (np.array([0.0, -1.0, 0.0]), 0.6)


def _holed(holes, subdivisions=4):
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    c = V[F].mean(1)
    drop = np.zeros(len(F), bool)
    for d, r in holes:
        drop |= np.linalg.norm(c - d, axis=1) < r
    return trimesh.Trimesh(V, F[~drop], process=False)


def _rim_length(mesh, direction):
    """The length of the rim nearest to ``direction`` (a hole punched there)."""
    V = np.asarray(mesh.vertices)
    loops = boundary_loops(mesh.faces, len(V))
    lp = min(loops, key=lambda lp: np.linalg.norm(V[lp].mean(0) - direction))
    P = V[lp]
    return float(np.linalg.norm(P - np.roll(P, -1, 0), axis=1).sum())


def test_small_holes_filled_on_the_surface_big_one_left_open():
    holed = _holed(SMALL + (BIG,))
    big_rim = _rim_length(holed, BIG[0])
    assert boundary_length(holed) > big_rim + 1.0  # the two small rims: about 0.75 + 1.25
    out, info = fill_small_holes(holed, max_radius=0.3)
    assert info["holes"] == 3 and info["filled_holes"] == 2
    # only the big hole's rim is left, exactly as it was
    assert boundary_length(out) == pytest.approx(big_rim, rel=1e-9)
    # the observed surface unchanged: its vertices (bit for bit) and faces come first
    n, f = len(holed.vertices), len(holed.faces)
    assert np.array_equal(np.asarray(out.vertices)[:n], np.asarray(holed.vertices))
    assert np.array_equal(np.asarray(out.faces)[:f], np.asarray(holed.faces))
    vf, ff = np.asarray(out.vertex_attributes["filled"]), np.asarray(out.face_attributes["filled"])
    assert not vf[:n].any() and vf[n:].all() and not ff[:f].any() and ff[f:].all()
    # the patches follow the sphere: within half of what a flat cap would sag (0.02 over the 0.2 hole)
    new = np.asarray(out.vertices)[n:]
    assert len(new) > 20
    assert np.abs(np.linalg.norm(new, axis=1) - 1.0).max() < 0.01
    # their area: the caps' (a spherical cap of chord radius r: about pi r^2 (1 + r^2 / 4))
    caps = sum(np.pi * r ** 2 for _, r in SMALL)
    assert filled_area(out) == pytest.approx(caps, rel=0.15)
    # refined like the surface around: no patch edge much longer than the sphere's
    edge = float(np.median(holed.edges_unique_length))
    pf = np.asarray(out.faces)[f:]
    pe = np.linalg.norm(np.asarray(out.vertices)[pf] - np.asarray(out.vertices)[np.roll(pf, 1, 1)], axis=2)
    assert pe.max() < 2.5 * edge


def test_hole_whose_rim_is_not_flat_is_left_open():
    """A slot through the side of the sphere: one rim, bent round it (far off any plane); the rim test keeps it
    open whatever the radius, and fills it once the test allows any shape."""
    s = trimesh.creation.icosphere(subdivisions=3)
    c = np.asarray(s.triangles_center)
    keep = ~((np.abs(c[:, 2]) < 0.15) & (c[:, 0] > 0.3))  # a slot through the side: one rim, bent round the sphere
    holed = trimesh.Trimesh(s.vertices, np.asarray(s.faces)[keep], process=False)
    out, info = fill_small_holes(holed, max_radius=2.0, max_offplane=0.1, notches=False)
    assert info["filled_holes"] == 0 and boundary_length(out) == pytest.approx(boundary_length(holed))
    out, info = fill_small_holes(holed, max_radius=2.0, max_offplane=1.0, notches=False)
    assert info["filled_holes"] == 1 and boundary_length(out) == 0.0


def test_closed_companion_is_watertight_and_stays_above_the_support():
    """An object cut open at its support (everything below z = -0.6 removed) and with holes: the companion is
    watertight, its support side closed above the support plane, its volume near the truncated sphere's."""
    holed = _holed(SMALL)
    keep = np.asarray(holed.triangles_center)[:, 2] > -0.6
    obj = trimesh.Trimesh(holed.vertices, np.asarray(holed.faces)[keep], process=False)
    obj.remove_unreferenced_vertices()
    assert not obj.is_watertight
    floor = (np.array([0.0, 0.0, 1.0]), -0.7)  # the plane the object stood on
    closed = close_mesh(obj, floor=floor)
    assert closed.is_watertight and closed.is_winding_consistent
    n = len(obj.vertices)
    assert np.array_equal(np.asarray(closed.vertices)[:n], np.asarray(obj.vertices))
    new = np.asarray(closed.vertices)[n:]
    assert new[:, 2].min() >= -0.7 - 1e-9
    # the truncated ball: 4/3 pi minus the cap below z = -0.6 (height 0.4)
    truth = 4 / 3 * np.pi - np.pi * 0.4 ** 2 * (3 - 0.4) / 3
    assert abs(closed.volume) == pytest.approx(truth, rel=0.05)
    # the filled area: the two small caps and the support side's opening (a disc of radius 0.8, bulged)
    assert filled_area(closed) == pytest.approx(sum(np.pi * r ** 2 for _, r in SMALL) + np.pi * 0.8 ** 2, rel=0.25)


def test_fill_radius_defaults():
    cfg = CleanConfig()
    assert fill_radius(cfg, 0.01, False) == pytest.approx(0.10)  # 10 voxels
    assert fill_radius(cfg, 0.01, True) == pytest.approx(0.10)  # objects: the same unless set apart
    assert fill_radius(CleanConfig(fill_object_voxels=30), 0.01, True) == pytest.approx(0.30)
    assert fill_radius(cfg, None, True) == 0.0  # no voxel: not a TSDF mesh, no default filling
    assert fill_radius(CleanConfig(fill_holes=0.05), None, False) == 0.05
    assert fill_radius(CleanConfig(fill_holes_voxels=0), 0.01, True) == 0.0


def test_clean_fills_a_tsdf_meshs_small_holes_only():
    """``clean`` on a mesh with a known voxel: holes up to 10 voxels filled, the big one kept, facts recorded."""
    holed = _holed(SMALL + (BIG,))
    holed.metadata["voxel_size"] = 0.03  # 10 voxels: 0.3
    out = clean(holed, CleanConfig(scene="open"))
    assert out.metadata["fill"]["filled_holes"] == 2 and out.metadata["fill"]["holes"] == 3
    assert boundary_length(out) == pytest.approx(_rim_length(holed, BIG[0]), rel=1e-6)
    assert filled_area(out) == pytest.approx(sum(np.pi * r ** 2 for _, r in SMALL), rel=0.15)


def _ply_filled(path):
    """(mesh, per-vertex filled, per-face filled) as a PLY reader sees the file."""
    m = trimesh.load(path, process=False)
    raw = m.metadata["_ply_raw"]
    return m, np.asarray(raw["vertex"]["data"]["filled"]), np.asarray(raw["face"]["data"]["filled"])


def _open_length(m):
    e, counts = np.unique(np.sort(np.asarray(m.edges), axis=1), axis=0, return_counts=True)
    e = e[counts == 1]
    return float(np.linalg.norm(m.vertices[e[:, 0]] - m.vertices[e[:, 1]], axis=1).sum())


@pytest.mark.slow
def test_reconstruct_reports_the_filling_and_writes_the_closed_companion_for_an_object(blob_small, tmp_path):
    import json

    from photorecon.cli import main

    args = ["-q", "reconstruct", str(blob_small / "images"), "--poses", str(blob_small / "transforms.json"),
            "--depth", str(blob_small / "depth")]
    out = tmp_path / "object"
    assert main(args + ["-o", str(out), "--scene", "object"]) == 0
    rep = json.loads((out / "report.json").read_text())["mesh"]
    m, vf, ff = _ply_filled(out / "mesh.ply")
    assert rep["boundary_length"] == pytest.approx(_open_length(m), rel=1e-6, abs=1e-9)
    assert rep["filled_area"] == pytest.approx(float(m.area_faces[ff > 0].sum()), rel=1e-6, abs=1e-12)
    assert rep["fill"]["fill_radius"] > 0 and rep["fill"]["holes"] >= rep["fill"]["filled_holes"]
    c, cvf, cff = _ply_filled(out / "mesh_closed.ply")
    assert c.is_watertight and rep["closed"]["watertight"] and rep["closed"]["file"] == "mesh_closed.ply"
    assert rep["closed"]["filled_area"] == pytest.approx(float(c.area_faces[cff > 0].sum()), rel=1e-6, abs=1e-12)
    assert rep["closed"]["filled_area"] >= rep["filled_area"] - 1e-12
    assert (out / "mesh_closed.glb").is_file()
    # the closed companion keeps the open mesh's surface: its vertices come first, unchanged
    assert np.allclose(np.asarray(c.vertices)[:len(m.vertices)], np.asarray(m.vertices), atol=1e-6)
    # the same photos as an open scene (--closed off): no companion, and none left from the run before
    assert main(args + ["-o", str(out), "--scene", "object", "--closed", "off"]) == 0
    assert json.loads((out / "report.json").read_text())["mesh"]["closed"] is None
    assert not (out / "mesh_closed.ply").exists() and not (out / "mesh_closed.glb").exists()


def test_fan_closes_a_rim_around_a_new_centre_vertex():
    """``fill_loops(fan=True)`` (the closed companion's later rounds, for rims whose ear clipping repeated an
    edge of the mesh): a box's square opening is closed by four faces around one new vertex on the opening's
    axis, marked filled, and the box is watertight again."""
    box = trimesh.creation.box()
    V, F = np.asarray(box.vertices), np.asarray(box.faces)
    top = np.flatnonzero(box.face_normals[:, 2] > 0.5)  # the two triangles of the top square
    holed = trimesh.Trimesh(V, np.delete(F, top, axis=0), process=False)
    loop = boundary_loops(holed.faces, len(holed.vertices))
    assert len(loop) == 1 and len(loop[0]) == 4
    out, nf = fill_loops(holed, loop, fan=True)
    assert nf == 4 and len(out.vertices) == len(V) + 1 and out.is_watertight
    c = np.asarray(out.vertices[-1])  # on the opening's axis, faired outwards (the sides' slope continued)
    assert np.allclose(c[:2], 0.0, atol=1e-9) and 0.5 < c[2] < 1.5
    assert np.asarray(out.vertex_attributes["filled"]).tolist() == [0] * len(V) + [1]


def test_holes_no_camera_faces_stay_open():
    """A ring of 12 cameras level with a sphere: the hole on its side faces three of them within 60 degrees
    and is filled; the hole on its top faces none (72 degrees off every camera) and stays open in the cleaned
    mesh, counted as unseen; without cameras both are filled."""
    holed = _holed(SMALL)
    az = np.radians(np.arange(12) * 30.0)
    ring = np.stack([3 * np.cos(az), 3 * np.sin(az), np.zeros(12)], 1)
    out, info = fill_small_holes(holed, max_radius=0.3, centres=ring)
    assert info["filled_holes"] == 1 and info["unseen"] == 1
    assert boundary_length(out) == pytest.approx(_rim_length(holed, SMALL[0][0]), rel=1e-6)  # the top's rim
    out, info = fill_small_holes(holed, max_radius=0.3)
    assert info["filled_holes"] == 2 and boundary_length(out) == 0.0


def test_pinholes_filled_whatever_the_views():
    """With ``pinhole`` 1 every hole up to the fill radius counts as a pinhole: the top hole no camera faces is
    filled as well, and none is counted as unseen."""
    holed = _holed(SMALL)
    az = np.radians(np.arange(12) * 30.0)
    ring = np.stack([3 * np.cos(az), 3 * np.sin(az), np.zeros(12)], 1)
    out, info = fill_small_holes(holed, max_radius=0.3, centres=ring, pinhole=1.0)
    assert info["filled_holes"] == 2 and info["unseen"] == 0 and boundary_length(out) == 0.0


def _directed_repeats(mesh):
    """Edges run the same way by two faces: a face whose back shows beside its neighbour."""
    F = np.asarray(mesh.faces, np.int64)
    d = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    _, c = np.unique(d[:, 0] * len(mesh.vertices) + d[:, 1], return_counts=True)
    return int((c > 1).sum())


@pytest.mark.parametrize("seed", [0, 1])
def test_swiss_cheese_closed_and_filled_facing_one_way(seed):
    """A sphere with a third of its faces removed at random (rims that touch at vertices, diagonals that are
    already edges of the mesh): the closed companion is watertight with every face wound the same way round
    (outwards: its volume is the ball's), and the small-hole filling leaves no patch face back to front; the
    observed faces stay, first and unchanged."""
    rng = np.random.default_rng(seed)
    s = trimesh.creation.icosphere(subdivisions=3)
    F = np.asarray(s.faces)
    holed = trimesh.Trimesh(s.vertices, F[rng.random(len(F)) >= 0.35], process=False)
    closed = close_mesh(holed)
    assert closed.is_watertight and closed.is_winding_consistent and _directed_repeats(closed) == 0
    assert closed.volume == pytest.approx(4 / 3 * np.pi, rel=0.05)
    assert np.array_equal(np.asarray(closed.faces)[:len(holed.faces)], np.asarray(holed.faces))
    filled, info = fill_small_holes(holed, max_radius=0.3, max_angle=90.0, max_offplane=1.0)
    assert info["filled_faces"] > 0 and _directed_repeats(filled) == 0
    assert np.array_equal(np.asarray(filled.faces)[:len(holed.faces)], np.asarray(holed.faces))


def test_object_in_pieces_closed_as_one_surface():
    """An object whose surface came out in pieces (a sphere cut by two bands into three, and open at its support):
    closing each piece would give closed crumbs; the companion is one watertight surface of about the ball's
    volume, above the support plane, with the bands marked filled and the observed pieces not."""
    from photorecon.mesh.close import closed_companion, main_share

    s = trimesh.creation.icosphere(subdivisions=5)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    z = V[F].mean(1)[:, 2]
    keep = (np.abs(z - 0.35) > 0.15) & (np.abs(z + 0.35) > 0.15) & (z > -0.8)
    pieces = trimesh.Trimesh(V, F[keep], process=False)
    pieces.remove_unreferenced_vertices()
    assert main_share(pieces) < 0.6
    pieces.metadata.update({"support_normal": "0,0,1", "support_offset": -0.85, "support_cut": 0.0})
    closed, info = closed_companion(pieces)
    assert info["method"] == "poisson" and info["watertight"] and closed.is_winding_consistent
    assert main_share(closed) == pytest.approx(1.0)
    X = np.asarray(closed.vertices)
    assert X[:, 2].min() >= -0.85 - 1e-9
    truth = 4 / 3 * np.pi - np.pi * 0.15 ** 2 * (3 - 0.15) / 3  # the ball less its cap below the support
    assert closed.volume == pytest.approx(truth, rel=0.08)
    # within a few cells of the unit sphere where it was seen; the bands' area marked as filled
    seen = (np.asarray(closed.vertex_attributes["filled"]) == 0) & (X[:, 2] > -0.75)  # the support side aside
    assert seen.sum() > 0.5 * len(X)
    assert np.abs(np.linalg.norm(X[seen], axis=1) - 1).max() < 0.03
    band_area = 2 * np.pi * 0.3 * 2  # two bands of height 0.3 on the unit sphere (their edges: within a cell)
    assert 0.4 * band_area < info["filled_area"] < 1.2 * band_area
