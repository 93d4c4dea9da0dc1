"""Fusion, meshing, cleaning, export and metrics against synthetic ground truth (tolerances in scene units)."""
import json

import numpy as np
import pytest
import trimesh

from photorecon.cameras import Intrinsics, View
from photorecon.errors import BadArgumentError, EmptyMeshError, InputDataError, NoDepthError
from photorecon.fusion import DepthFrame, FusionConfig, fuse, grid_mesh_view, legacy_article_fuse, load_frames, prepare_depth
from photorecon.io.dataset import Dataset
from photorecon.mesh import CleanConfig, clean, export, simplify
from photorecon.metrics import doubled_shell_fraction, mesh_metrics


@pytest.fixture(scope="module")
def frames(blob_fusion):
    return load_frames(Dataset.open(blob_fusion), FusionConfig())


@pytest.fixture(scope="module")
def gt(blob_fusion):
    return trimesh.load(blob_fusion / "gt_mesh.ply", process=False)


def test_tsdf_matches_ground_truth(frames, gt, blob_fusion):
    ds = Dataset.open(blob_fusion)
    mesh = clean(fuse(frames, FusionConfig(mesher="tsdf"), ds.model.points))
    m = mesh_metrics(mesh, gt, n_samples=50_000)
    assert m.fscore_half >= 0.99, m
    assert m.chamfer <= 0.001 * m.diagonal, m
    assert m.normal_consistency > 0.97
    # colour came through
    assert mesh.visual.kind == "vertex" and np.asarray(mesh.visual.vertex_colors)[:, :3].std() > 5


def test_grid_mesher_one_surface(frames, gt):
    mesh = clean(fuse(frames, FusionConfig(mesher="grid")))
    m = mesh_metrics(mesh, gt, n_samples=50_000)
    assert m.fscore_half >= 0.97, m
    tau = 0.005 * m.diagonal
    doubled = doubled_shell_fraction(mesh, tau, 20_000)
    legacy = doubled_shell_fraction(legacy_article_fuse(frames), tau, 20_000)
    assert doubled < 0.02 and legacy > 0.5, (doubled, legacy)


def test_grid_discontinuity_test_is_scale_free(frames):
    f = frames[0]
    a = grid_mesh_view(f)
    T = f.view.cam_from_world.copy()
    T[:3, 3] *= 100.0
    b = grid_mesh_view(DepthFrame(View(f.view.name, f.view.intrinsics, T), f.depth * 100.0))
    assert len(a.faces) == len(b.faces) > 1000
    # triangles across the silhouette (object -> nothing) and across a depth step are rejected
    d = np.zeros((20, 20), np.float32)
    d[:, :10] = 2.0
    d[:, 10:] = 3.0
    step = grid_mesh_view(DepthFrame(View("step", Intrinsics(20, 20, 200.0, 200.0, 9.5, 9.5), np.eye(4)), d))
    assert len(step.faces) == 2 * 19 * 9 * 2


def test_bad_depth_inputs(frames):
    v = frames[0].view
    d = frames[0].depth.copy()
    d[5, 5] = np.nan
    with pytest.raises(BadArgumentError, match=f"view {v.name}.*NaN"):
        prepare_depth(v, d, FusionConfig())
    with pytest.raises(BadArgumentError, match=f"view {v.name}.*shape"):
        prepare_depth(v, d[:-1], FusionConfig())
    with pytest.raises(BadArgumentError, match=f"view {v.name}.*negative"):
        prepare_depth(v, -np.abs(frames[0].depth), FusionConfig())
    empty = [DepthFrame(f.view, np.zeros_like(f.depth)) for f in frames[:3]]
    for mesher in ("tsdf", "grid"):
        with pytest.raises(NoDepthError):
            fuse(empty, FusionConfig(mesher=mesher))
    with pytest.raises(ValueError, match="orthonormal"):
        T = v.cam_from_world.copy()
        T[:3, :3] *= 1.01
        View("bad", v.intrinsics, T)
    with pytest.raises(BadArgumentError, match="needs about .* GB"):
        fuse(frames[:2], FusionConfig(voxel_size=1e-5))


def test_dataset_depth_errors_name_the_view(blob_small, tmp_path):
    import shutil

    root = tmp_path / "ds"
    shutil.copytree(blob_small, root)
    np.save(root / "depth" / "view_002.npy", np.full((10, 10), 1.0, np.float32))
    with pytest.raises(InputDataError, match="view view_002.*shape"):
        load_frames(Dataset.open(root), FusionConfig())


def test_clean_and_simplify():
    big = trimesh.creation.icosphere(subdivisions=4)
    small = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    small.apply_translation((3, 0, 0))
    m = trimesh.util.concatenate([big, small])
    F = np.vstack([m.faces, m.faces[:10], [[0, 0, 1]]])  # duplicated and degenerate faces
    dirty = trimesh.Trimesh(m.vertices, F, process=False)
    out = clean(dirty, CleanConfig(min_component=0.05))
    assert len(out.faces) == len(big.faces)
    assert out.bounds[1][0] < 1.5
    dec = simplify(out, 500)
    assert 400 <= len(dec.faces) <= 500
    assert mesh_metrics(dec, big, n_samples=20_000).fscore > 0.95
    cropped = clean(out, CleanConfig(crop=(0, -2, -2, 2, 2, 2)))
    assert cropped.vertices[:, 0].min() >= -1e-9
    with pytest.raises(EmptyMeshError):
        clean(out, CleanConfig(crop=(5, 5, 5, 6, 6, 6)))
    clustered = clean(out, CleanConfig(cluster_voxel=0.2))
    assert len(clustered.faces) < len(out.faces)


def test_fill_holes():
    s = trimesh.creation.icosphere(subdivisions=3)
    holed = trimesh.Trimesh(s.vertices, s.faces[5:], process=False)
    filled = clean(holed, CleanConfig(fill_holes=1.0))
    assert len(filled.faces) > len(holed.faces)
    assert abs(filled.area - s.area) < abs(holed.area - s.area)


def test_export_formats(tmp_path):
    m = trimesh.creation.box()
    m.visual.vertex_colors = np.tile([10, 200, 30, 255], (len(m.vertices), 1))
    for suf in (".ply", ".obj", ".glb"):
        p = export(m, tmp_path / f"m{suf}")
        back = trimesh.load(p, force="mesh", process=False)
        assert len(back.faces) == 12
    assert (tmp_path / "m.ply").read_bytes()[:40].find(b"binary_little_endian") > 0
    back = trimesh.load(tmp_path / "m.ply", process=False)
    assert tuple(np.asarray(back.visual.vertex_colors)[0, :3]) == (10, 200, 30)
    with pytest.raises(EmptyMeshError):
        export(trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), int)), tmp_path / "e.ply")


def test_metrics_known_offset():
    gt = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    res = trimesh.creation.icosphere(subdivisions=5, radius=1.01)
    m = mesh_metrics(res, gt, tau=0.018, n_samples=20_000)
    assert m.accuracy_mean == pytest.approx(0.01, abs=0.0015)
    assert m.completeness_mean == pytest.approx(0.01, abs=0.0015)
    assert m.fscore == pytest.approx(1.0) and m.fscore_half < 0.01  # tau/2 = 0.009 < offset
    half = trimesh.Trimesh(gt.vertices, gt.faces[gt.triangles_center[:, 2] > 0], process=False)
    m2 = mesh_metrics(half, gt, tau=0.02, n_samples=20_000)
    assert m2.precision == pytest.approx(1.0) and m2.recall == pytest.approx(0.5, abs=0.05)


def test_cli_fuse_and_eval(blob_small, tmp_path, capsys):
    from photorecon.cli import main

    out = tmp_path / "fused"
    assert main(["-q", "fuse", str(blob_small), "-o", str(out), "--formats", "ply,glb"]) == 0
    assert (out / "mesh.ply").is_file() and (out / "mesh.glb").is_file() and (out / "preview.png").is_file()
    assert main(["-q", "eval", "--mesh", str(out / "mesh.ply"), "--gt", str(blob_small / "gt_mesh.ply"),
                 "--json", str(tmp_path / "m.json"), "--error-mesh", str(tmp_path / "err.ply")]) == 0
    rep = json.loads((tmp_path / "m.json").read_text())["mesh"]
    assert rep["fscore"] > 0.95 and (tmp_path / "err.png").is_file()
    # the input dataset is not written to; writing into it is refused
    assert main(["-q", "fuse", str(blob_small), "-o", str(blob_small / "x")]) == 8
    assert not (blob_small / "x").exists()
    # no depth -> exit code for "no usable depth"
    assert main(["-q", "fuse", str(blob_small), "-o", str(tmp_path / "n"), "--depth-dir", str(tmp_path)]) == 6
    assert main(["-q", "eval", "--mesh", str(out / "mesh.ply")]) == 2


def test_confidence_weighted_tsdf(frames, gt):
    """Weights of 1 reproduce Open3D's own integration; weights of 0 integrate nothing."""
    ones = [DepthFrame(f.view, f.depth, f.color, np.ones_like(f.depth)) for f in frames]
    native = fuse(frames, FusionConfig())
    weighted = fuse(ones, FusionConfig())
    m = mesh_metrics(weighted, native, n_samples=20_000)
    assert m.chamfer < 0.0005 * m.diagonal and m.fscore_half > 0.999, m
    assert mesh_metrics(weighted, gt, n_samples=20_000).fscore_half >= 0.99
    # colours come through the weighted path too
    assert np.asarray(weighted.visual.vertex_colors)[:, :3].std() > 5
    zeros = [DepthFrame(f.view, f.depth, f.color, np.zeros_like(f.depth)) for f in frames]
    with pytest.raises(EmptyMeshError):
        fuse(zeros, FusionConfig())
