"""Options that contradict each other are refused when the configs are built: on the command line before
anything runs or is written (exit 2, one line naming both options), and by the Python API's configs
(``FusionConfig``, ``SfMConfig``, ``ReconstructConfig``, ``StageConfigs``) before ``reconstruct`` starts.
"""
from __future__ import annotations

import numpy as np
import pytest

from photorecon.errors import BadArgumentError


@pytest.fixture
def photos(tmp_path):
    from photorecon.io.images import write_image

    folder = tmp_path / "photos"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        write_image(folder / f"p{i}.png", rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    return folder


CONFLICTS = [
    (["--watertight", "--mesher", "tsdf"], "--watertight needs --mesher poisson"),
    (["--watertight", "--mesher", "grid"], "--watertight needs --mesher poisson"),
    (["--depth-model", "{model}", "--depth", "{depth}"], "both give the depth maps"),
    (["--depth-preset", "midas_small"], "--depth-preset midas_small needs --depth-model"),
    (["--depth-model", "{model}", "--depth-preset", "nonsense"], "--depth-preset: expected one of"),
    (["--intrinsics", "{K}", "--fx", "500"], "both give the intrinsics"),
    (["--fy", "500"], "--fx is required"),
    (["--poses", "{poses}", "--fx", "500"], "--poses"),
]


@pytest.mark.parametrize("flags, message", CONFLICTS)
def test_reconstruct_refuses_conflicting_options_before_any_work(photos, tmp_path, capsys, flags, message):
    from photorecon.cli import main

    (tmp_path / "depth").mkdir()
    (tmp_path / "model.onnx").write_bytes(b"not read")
    (tmp_path / "K.txt").write_text("500 0 31.5\n0 500 23.5\n0 0 1\n")
    (tmp_path / "poses").mkdir()
    names = {"model": tmp_path / "model.onnx", "depth": tmp_path / "depth", "K": tmp_path / "K.txt",
             "poses": tmp_path / "poses"}
    out = tmp_path / "out"
    code = main(["reconstruct", str(photos), "-o", str(out)] + [f.format(**names) for f in flags])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and message in err, err
    assert not out.exists()  # refused before the output folder was made, so before any stage ran


def test_fuse_refuses_watertight_without_poisson(tmp_path, capsys):
    from photorecon.cli import main

    (tmp_path / "data").mkdir()
    assert main(["fuse", str(tmp_path / "data"), "-o", str(tmp_path / "out"), "--watertight"]) == 2
    assert "--watertight needs --mesher poisson (got --mesher tsdf)" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_api_configs_refuse_conflicts_when_built(photos, tmp_path):
    """The Python API: the config raises as it is built, so ``reconstruct`` never starts with it."""
    from photorecon.fusion import FusionConfig
    from photorecon.pipeline import ReconstructConfig, StageConfigs
    from photorecon.poses.sfm import SfMConfig

    with pytest.raises(BadArgumentError, match="--watertight needs --mesher poisson"):
        FusionConfig(mesher="tsdf", watertight=True)
    with pytest.raises(BadArgumentError, match="--watertight needs --mesher poisson"):
        FusionConfig(watertight=True)
    assert FusionConfig(mesher="poisson", watertight=True).watertight
    with pytest.raises(BadArgumentError, match="both give the intrinsics"):
        SfMConfig(intrinsics="K.txt", fx=500.0)
    with pytest.raises(BadArgumentError, match="--fx is required"):
        SfMConfig(cx=10.0)
    assert SfMConfig(fx=500.0, cy=10.0).fx == 500.0
    with pytest.raises(BadArgumentError, match="both give the depth maps"):
        ReconstructConfig(depth=str(tmp_path), depth_model="m.onnx")
    with pytest.raises(BadArgumentError, match="needs --depth-model"):
        ReconstructConfig(depth_preset="midas_small")
    with pytest.raises(BadArgumentError, match="would be ignored"):
        StageConfigs(run=ReconstructConfig(poses="sparse/0"), sfm=SfMConfig(intrinsics="K.txt"))
    assert StageConfigs(run=ReconstructConfig(poses="sparse/0")).run.poses == "sparse/0"


def test_depth_refuses_an_unknown_preset_before_reading_anything(tmp_path, capsys):
    """``photorecon depth --preset`` with a name no preset has: exit 2 when the config is built (it was found
    only when the model was loaded, after the output folder was made); ``MonoConfig`` refuses it too."""
    from photorecon.cli import main
    from photorecon.depth.mono import MonoConfig

    (tmp_path / "data").mkdir()
    (tmp_path / "m.onnx").write_bytes(b"not read")
    code = main(["depth", str(tmp_path / "data"), "--model", str(tmp_path / "m.onnx"), "--preset", "nonsense",
                 "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--preset: expected one of" in err, err
    assert not (tmp_path / "out").exists()
    with pytest.raises(BadArgumentError, match="--preset: expected one of"):
        MonoConfig(preset="nonsense")
    assert MonoConfig(preset="midas_small").preset == "midas_small"
