"""Point-cloud evaluation (DTU / ETH3D / Tanks-and-Temples style) on synthetic spheres with known answers,
and `photorecon eval` against a reference point cloud through the CLI."""
import json

import numpy as np
import pytest
import trimesh

from photorecon.cli import main
from photorecon.errors import BadArgumentError, EmptyMeshError
from photorecon.metrics import cloud_metrics, load_reference, mesh_metrics, sample_surface

TAU = 0.02  # scene units; the reference below has a median point spacing of about 0.005


def _sphere(radius=1.0):
    return trimesh.creation.icosphere(subdivisions=5, radius=radius)  # facets within 2e-4 of the sphere


def _points(mesh, n=100_000, seed=7):
    return sample_surface(mesh, n, seed)[0]


@pytest.fixture(scope="module")
def sphere():
    return _sphere()


@pytest.fixture(scope="module")
def reference(sphere):
    return _points(sphere)


def test_same_surface_scores_one(sphere, reference):
    m = cloud_metrics(sphere, reference, [TAU / 10, TAU], n_samples=50_000)
    assert m.reference_spacing < TAU / 2 and m.reference_points == len(reference)
    at = m.at(TAU)
    assert at.precision > 0.999 and at.recall > 0.999 and at.fscore > 0.999, m
    # below the reference's point spacing the nearest-point distance is no longer ~0: honest, not 1
    assert m.at(TAU / 10).precision < 0.95
    assert m.completeness_median < 1e-3 and m.accuracy_median < 0.01
    assert [s.tau for s in m.thresholds] == [TAU / 10, TAU]
    # a point-cloud result (KD-tree both ways) gives the same answer
    pm = cloud_metrics(_points(sphere, 50_000, 3), reference, TAU)
    assert pm.at(TAU).fscore > 0.99 and pm.result_samples == 50_000  # sparser than a surface: recall ~0.993


def test_offset_surface_scores_zero_at_tau_and_one_at_three_tau(sphere):
    ref = _points(_sphere(1 + 2 * TAU))
    m = cloud_metrics(sphere, ref, [TAU, 3 * TAU], n_samples=50_000)
    assert m.at(TAU).precision == 0.0 and m.at(TAU).recall == 0.0 and m.at(TAU).fscore == 0.0
    assert m.at(3 * TAU).precision > 0.999 and m.at(3 * TAU).recall > 0.999, m
    assert m.completeness_mean == pytest.approx(2 * TAU, abs=1e-3)  # reference -> surface is exact
    assert 2 * TAU <= m.accuracy_median < 2.5 * TAU


def test_half_missing_result_is_incomplete_but_accurate(sphere, reference):
    upper = sphere.copy()
    upper.update_faces(sphere.triangles_center[:, 2] > 0)
    upper.remove_unreferenced_vertices()
    m = cloud_metrics(upper, reference, TAU, n_samples=50_000).at(TAU)
    assert m.precision > 0.999
    assert m.recall == pytest.approx(0.5 + TAU / 2, abs=0.02)  # + the band within tau of the cut
    assert m.fscore == pytest.approx(2 * m.precision * m.recall / (m.precision + m.recall))


@pytest.mark.slow
def test_crop_to_reference_ignores_background_only(sphere, reference):
    floor = trimesh.creation.box(extents=[10, 10, 0.1])  # 100 m^2 of background under a 12.6 m^2 object
    floor.apply_translation([0, 0, -3])
    scene = trimesh.util.concatenate([sphere, floor])
    plain = cloud_metrics(scene, reference, TAU, n_samples=100_000)
    assert plain.at(TAU).precision < 0.2 and plain.outside_fraction > 0.8 and plain.cropped == 0
    cropped = cloud_metrics(scene, reference, TAU, n_samples=100_000, crop_margin=0.5)
    assert cropped.at(TAU).precision > 0.999 and cropped.crop_margin == 0.5
    assert cropped.cropped > 0.8 * 100_000 and cropped.result_samples + cropped.cropped == 100_000
    assert cropped.at(TAU).recall == plain.at(TAU).recall  # completeness is not cropped
    with pytest.raises(EmptyMeshError, match="bounding box"):
        cloud_metrics(floor, reference, TAU, n_samples=10_000, crop_margin=0.5)


def test_crop_plane_leaves_out_the_table_under_an_object(sphere, reference):
    """DTU-style: a table the reference lacks, touching the object, lies inside the reference's box margin; the
    crop plane (the table's, moved up to the reference's lowest point) leaves it out of accuracy only."""
    table = trimesh.creation.box(extents=[3, 3, 0.01])
    table.apply_translation([0, 0, -1.0 - 0.005 - TAU])  # its top just under the sphere's bottom
    scene = trimesh.util.concatenate([sphere, table])
    plain = cloud_metrics(scene, reference, TAU, n_samples=100_000, crop_margin=0.5)
    n = np.array([0.0, 0.0, 1.0])
    above = cloud_metrics(scene, reference, TAU, n_samples=100_000, crop_margin=0.5,
                          crop_plane=(n, float((reference @ n).min())))
    assert plain.at(TAU).precision < 0.6 and above.at(TAU).precision > 0.999, (plain, above)
    assert above.at(TAU).recall == plain.at(TAU).recall and above.cropped > plain.cropped
    with pytest.raises(BadArgumentError, match="unit normal"):
        cloud_metrics(scene, reference, TAU, n_samples=1000, crop_plane=(2 * n, 0.0))


def test_mesh_metrics_shares_thresholds(sphere):
    offset = _sphere(1 + 2 * TAU)
    m = mesh_metrics(sphere, offset, tau=3 * TAU, n_samples=20_000, taus=[TAU, 3 * TAU])
    assert [(s.tau, s.fscore) for s in m.thresholds] == [(TAU, 0.0), (3 * TAU, 1.0)]
    assert m.fscore == 1.0 and m.fscore_half == 0.0  # tau/2 = 1.5 TAU < offset
    assert m.as_dict()["thresholds"][1]["recall"] == 1.0


def test_bad_thresholds_raise(sphere, reference):
    for taus in ([], [0.0], [-1.0, 0.1], [float("nan")]):
        with pytest.raises(BadArgumentError, match="tau"):
            cloud_metrics(sphere, reference, taus)


def _write_scan(path, pts):
    """An ASCII PLY like a laser scan's: x y z, normals, colours, and an empty face element."""
    nrm = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    header = ["ply", "format ascii 1.0", f"element vertex {len(pts)}"]
    header += [f"property float {c}" for c in ("x", "y", "z", "nx", "ny", "nz")]
    header += [f"property uchar {c}" for c in ("red", "green", "blue", "alpha")]
    header += ["element face 0", "property list uchar int vertex_indices", "end_header"]
    body = "\n".join(" ".join(f"{v:.7g}" for v in row) + " 5 5 5 255" for row in np.c_[pts, nrm])
    path.write_text("\n".join(header) + "\n" + body + "\n")


def test_cli_eval_against_point_cloud(tmp_path, sphere, capsys):
    scan = tmp_path / "reference.ply"
    _write_scan(scan, _points(_sphere(1 + 2 * TAU), 30_000))
    pts = load_reference(scan)
    assert isinstance(pts, np.ndarray) and pts.shape == (30_000, 3)
    mesh = tmp_path / "mesh.ply"
    sphere.export(mesh)
    rc = main(["-q", "eval", "--mesh", str(mesh), "--gt", str(scan), "--tau", f"{TAU},{3 * TAU}", "--json"])
    assert rc == 0
    rep = json.loads(capsys.readouterr().out)["mesh"]
    assert rep["reference"] == "points" and rep["reference_points"] == 30_000
    (lo, hi) = rep["thresholds"]
    assert lo["tau"] == TAU and lo["precision"] == 0.0 and lo["recall"] == 0.0
    assert hi["tau"] == 3 * TAU and hi["fscore"] > 0.99
    assert rep["completeness_mean"] == pytest.approx(2 * TAU, abs=1e-3) and rep["accuracy_median"] >= 2 * TAU
    # the text report names the thresholds; --crop-to-reference is reported
    assert main(["-q", "eval", "--mesh", str(mesh), "--gt", str(scan), "--tau", str(3 * TAU),
                 "--crop-to-reference", "0.1"]) == 0
    out = capsys.readouterr().out
    assert "reference point cloud (30000 points" in out and "left out beyond 0.1" in out and "0.06" in out


def test_cli_eval_bad_reference(tmp_path, sphere, capsys):
    mesh = tmp_path / "mesh.ply"
    sphere.export(mesh)
    empty = tmp_path / "empty.ply"
    empty.write_text("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n")
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(bytes(range(256)) * 4)
    for bad in (empty, garbage, tmp_path / "missing.ply"):
        rc = main(["-q", "eval", "--mesh", str(mesh), "--gt", str(bad), "--tau", "0.01"])
        err = capsys.readouterr().err.strip()
        assert rc == 3 and str(bad) in err and err.count("\n") == 0, err
    with pytest.raises(SystemExit) as e:
        main(["eval", "--mesh", str(mesh), "--gt", str(empty), "--tau", "0.01,-2"])
    assert e.value.code == 2


def test_seen_split_scores_the_observed_part_and_the_guess_apart():
    """Truth: a unit sphere; the result: the same sphere with its bottom (z < -0.5) flattened into a plane, as a
    closed surface guesses a base no camera saw; observed: points of the sphere's top (z > -0.4). The seen part
    scores F = 1, the unseen part (the flat cap vs the round bottom, up to 0.5 apart) far less, and the shares
    follow the areas."""
    import trimesh

    from photorecon.metrics import seen_split_metrics

    gt = trimesh.creation.icosphere(5)
    res = gt.copy()
    v = np.asarray(res.vertices).copy()
    v[v[:, 2] < -0.5, 2] = -0.5
    res = trimesh.Trimesh(v, res.faces, process=False)
    pts, _ = trimesh.sample.sample_surface(gt, 200_000, seed=3)
    observed = pts[pts[:, 2] > -0.4]
    s = seen_split_metrics(res, gt, observed, radius=0.03, n_samples=50_000)
    assert s["seen"]["fscore"] > 0.99 and s["seen"]["precision"] > 0.99, s
    assert s["unseen"]["fscore"] < 0.6, s
    # the truth's unseen area: the cap below z = -0.4 (minus the radius band), 0.3 of the sphere by Archimedes
    assert abs(s["unseen"]["share_truth"] - (1 - 0.4 - 0.03) / 2) < 0.03, s
