"""Monocular ONNX depth: an oracle model through the full path (load, preprocess, infer, resize back, align,
fuse), robust alignment, and wrong models."""
import shutil

import cv2
import numpy as np
import pytest
import trimesh

from photorecon.cli import main
from photorecon.depth.align import fit_scale_shift
from photorecon.depth.mono import MonoConfig, MonoModel, run_mono
from photorecon.errors import InputDataError
from photorecon.fusion import FusionConfig, fuse, load_frames
from photorecon.io.dataset import Dataset
from photorecon.mesh import clean
from photorecon.metrics import mesh_metrics
from photorecon.testing import conv_net, nan_model, oracle_model, rank3_model


@pytest.fixture(scope="module")
def oracle_dataset(blob_fusion, tmp_path_factory):
    """blob_fusion whose images encode disparity in the red channel (8 bit, over the scene's range)."""
    root = tmp_path_factory.mktemp("oracle") / "ds"
    shutil.copytree(blob_fusion, root)
    ds = Dataset.open(root)
    depths = {v.name: np.load(root / "depth" / f"{v.name}.npy") for v in ds.views}
    lo = min(1 / d[d > 0].max() for d in depths.values())
    hi = max(1 / d[d > 0].min() for d in depths.values())
    for v in ds.views:
        d = depths[v.name]
        red = np.where(d > 0, (1 / np.maximum(d, 1e-9) - lo) / (hi - lo), 0)
        img = np.zeros(d.shape + (3,), np.uint8)
        img[..., 2] = np.round(red * 255).astype(np.uint8)  # BGR: red is the last channel
        cv2.imwrite(str(root / "images" / f"{v.name}.png"), img)
    shutil.rmtree(root / "depth")
    return root, depths


def test_alignment_with_outliers():
    rng = np.random.default_rng(0)
    z = rng.uniform(1.0, 5.0, 500)
    s_true, t_true = 2.5, -0.1  # prediction p = (1/z - t) / s  ->  1/z = s p + t
    p = (1 / z - t_true) / s_true
    bad = rng.random(500) < 0.2
    p_noisy = p.copy()
    p_noisy[bad] = rng.uniform(p.min(), p.max(), bad.sum())  # 20% corrupted points
    fit = fit_scale_shift(p_noisy, 1 / z)
    assert fit.ok
    assert abs(fit.scale / s_true - 1) < 0.01 and abs(fit.shift - t_true) < 0.01 * abs(t_true) + 1e-3
    assert 0.75 < fit.inlier_ratio < 0.85
    few = fit_scale_shift(p[:5], 1 / z[:5])
    assert not few.ok and "points" in few.reason
    garbage = fit_scale_shift(rng.random(200), 1 / z[:200])
    assert not garbage.ok


@pytest.mark.slow
def test_oracle_model_recovers_geometry(oracle_dataset, blob_fusion, tmp_path):
    root, gt_depths = oracle_dataset
    model = oracle_model(tmp_path / "oracle.onnx")
    ds = Dataset.open(root)
    rep = run_mono(ds, model, root / "depth", MonoConfig(preset="midas_small"))
    assert rep["views"] == len(ds.views) and not rep["excluded"]
    assert rep["input_size"] == [256, 256]
    rels = []
    for v in ds.views:
        d = np.load(root / "depth" / f"{v.name}.npy")
        g = gt_depths[v.name]
        m = (g > 0) & (d > 0)
        assert m.sum() > 0.95 * (g > 0).sum()
        rels.append(np.abs(d[m] - g[m]) / g[m])
    absrel = float(np.concatenate(rels).mean())
    assert absrel <= 0.01, absrel
    frames = load_frames(ds, FusionConfig())
    mesh = clean(fuse(frames, FusionConfig(), ds.model.points))
    m = mesh_metrics(mesh, trimesh.load(blob_fusion / "gt_mesh.ply", process=False), n_samples=30_000)
    assert m.fscore_half >= 0.97 and m.chamfer <= 0.002 * m.diagonal, m


def test_global_alignment_and_cli(oracle_dataset, tmp_path):
    root, _ = oracle_dataset
    model = oracle_model(tmp_path / "oracle.onnx", scale=0.8, shift=-0.05)
    out = tmp_path / "d"
    assert main(["-q", "depth", str(root), "--model", str(model), "-o", str(out), "--alignment", "global"]) == 0
    assert len(list(out.glob("*.npy"))) == len(Dataset.open(root).views)
    assert (out / "mono_report.json").is_file()


def test_dynamic_model_keeps_aspect(tmp_path):
    m = MonoModel(conv_net(tmp_path / "dyn.onnx", widths=(4, 8), dynamic=True), MonoConfig(preset="depth_anything_v2"))
    assert m.fixed is None
    w, h = m.input_size(640, 480)
    assert h == 518 and w % 14 == 0 and abs(w / h - 640 / 480) < 0.03
    out = m.predict([np.zeros((48, 64, 3), np.uint8)])[0]
    assert out.shape == (48, 64)


def test_wrong_models(tmp_path, blob_small):
    with pytest.raises(InputDataError, match="no such file"):
        MonoModel(tmp_path / "missing.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"this is not a protobuf")
    with pytest.raises(InputDataError, match="junk.onnx: not a loadable ONNX model"):
        MonoModel(tmp_path / "junk.onnx")
    with pytest.raises(InputDataError, match="rank 4"):
        MonoModel(rank3_model(tmp_path / "r3.onnx"))
    nan = MonoModel(nan_model(tmp_path / "nan.onnx"))
    with pytest.raises(InputDataError, match="nan.onnx: output for view_000 contains NaN"):
        nan.predict([np.zeros((32, 32, 3), np.uint8)], ["view_000"])
    rc = main(["-q", "depth", str(blob_small), "--model", str(tmp_path / "junk.onnx"), "-o", str(tmp_path / "o")])
    assert rc == 3
    # a missing model is one failure class wherever it is found: the same exit from reconstruct (which checks
    # before writing anything) as from depth
    rc = main(["-q", "reconstruct", str(blob_small / "images"), "-o", str(tmp_path / "r"),
               "--depth-model", str(tmp_path / "missing.onnx")])
    assert rc == 3 and not (tmp_path / "r").exists()
    assert main(["-q", "depth", str(blob_small), "--model", str(tmp_path / "missing.onnx"), "-o", str(tmp_path / "o2")]) == 3


@pytest.mark.slow
def test_reconstruct_with_depth_model(oracle_dataset, tmp_path):
    import json

    root, _ = oracle_dataset
    model = oracle_model(tmp_path / "oracle.onnx")
    out = tmp_path / "rec"
    assert main(["-q", "reconstruct", str(root / "images"), "-o", str(out), "--poses", str(root / "sparse" / "0"),
                 "--depth-model", str(model), "--depth-preset", "midas_small"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["depth"]["source"] == "mono" and rep["depth"]["views"] == 24
    assert (out / "mesh.ply").is_file()
