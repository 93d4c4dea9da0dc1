"""Camera formats come from one registry (``photorecon.io.cameras.FORMATS``): the dataset reader, ``convert`` and
its ``--to`` choices all read it, so a new format is one module and one registry line. A toy format, defined in
a few lines here, is read as a dataset and converted to and from end to end."""
from __future__ import annotations

import types

import cv2
import numpy as np
import pytest

from photorecon.cameras import Intrinsics, View, look_at
from photorecon.cli import main
from photorecon.errors import BadArgumentError, InputDataError
from photorecon.io import cameras
from photorecon.io.cameras import SparseModel
from photorecon.io.colmap_text import write_colmap_text
from photorecon.io.convert import convert_cameras, formats, output_format
from photorecon.io.dataset import Dataset, read_model


def _toy_format():
    """``cameras.toy``: one line per image, ``FILE W H fx fy cx cy`` and the 16 numbers of cam_from_world."""
    toy = types.ModuleType("toy")
    toy.NAME, toy.SUFFIX, toy.LOOKS_FOR = "toy", ".toy", "cameras.toy (toy)"

    def detect(path):
        return path if path.suffix == ".toy" else (path / "cameras.toy" if (path / "cameras.toy").is_file() else None)

    def read(path, **options):
        views = []
        for ln in path.read_text().splitlines():
            f, *x = ln.split()
            intr = Intrinsics(int(x[0]), int(x[1]), *map(float, x[2:6]))
            views.append(View(f.rsplit(".", 1)[0], intr, np.array(x[6:], float).reshape(4, 4), image_file=f))
        return SparseModel(views)

    def write(model, path, **options):
        path.write_text("".join(f"{v.image_file} {v.intrinsics.width} {v.intrinsics.height} {v.intrinsics.fx!r} "
                                f"{v.intrinsics.fy!r} {v.intrinsics.cx!r} {v.intrinsics.cy!r} "
                                + " ".join(map(repr, v.cam_from_world.ravel().tolist())) + "\n" for v in model.views))
        return path

    toy.detect, toy.read, toy.write = detect, read, write
    toy.auto_output = lambda path: path.suffix == ".toy"
    return toy


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setattr(cameras, "FORMATS", list(cameras.FORMATS))  # the registry as it was, after the test
    return cameras.register(_toy_format())


def _dataset(folder, n=3, w=16, h=12):
    intr = Intrinsics(w, h, 14.0, 15.0, 7.25, 5.5)
    views = [View(f"v{i}", intr, look_at(np.array([np.cos(i), np.sin(i), 0.3]) * 3, np.zeros(3)),
                  image_file=f"v{i}.png") for i in range(n)]
    write_colmap_text(SparseModel(views), folder / "sparse" / "0")
    (folder / "images").mkdir(parents=True)
    for v in views:
        cv2.imwrite(str(folder / "images" / v.image_file), np.full((h, w, 3), 90, np.uint8))
    return views


def _same(views, expected):
    assert [v.name for v in views] == [v.name for v in expected]
    for v, e in zip(views, expected):
        assert v.intrinsics.size == e.intrinsics.size
        assert np.allclose([v.intrinsics.fx, v.intrinsics.fy, v.intrinsics.cx, v.intrinsics.cy],
                           [e.intrinsics.fx, e.intrinsics.fy, e.intrinsics.cx, e.intrinsics.cy])
        assert np.allclose(v.cam_from_world, e.cam_from_world, atol=1e-9)


def test_a_registered_format_is_read_as_a_dataset_and_converted_both_ways(toy, tmp_path, capsys):
    src = tmp_path / "src"
    truth = _dataset(src)
    scene = tmp_path / "scene"
    (scene / "images").mkdir(parents=True)
    for v in truth:
        (scene / "images" / v.image_file).write_bytes((src / "images" / v.image_file).read_bytes())
    assert "toy" in formats() and output_format(scene / "cameras.toy") == "toy"
    # to the toy format through the command line: --to's choices and "auto" both come from the registry
    assert main(["-q", "convert", str(src), str(scene / "cameras.toy"), "--to", "toy"]) == 0
    assert main(["-q", "convert", str(src), str(tmp_path / "auto.toy")]) == 0
    assert (tmp_path / "auto.toy").read_text() == (scene / "cameras.toy").read_text()
    # a dataset folder holding it is found by the dataset reader
    ds = Dataset.open(scene)
    _same(ds.views, truth)
    assert ds.image(ds.views[0]).shape[:2] == (12, 16)
    # from the toy format to another
    out = convert_cameras(scene, tmp_path / "back" / "transforms.json")
    _same(read_model(out).views, truth)
    assert main(["-q", "convert", str(scene / "cameras.toy"), str(tmp_path / "colmap")]) == 0
    _same(read_model(tmp_path / "colmap").views, truth)


def test_an_unregistered_format_is_neither_read_nor_offered(tmp_path, capsys):
    (tmp_path / "cameras.toy").write_text("")
    assert "toy" not in formats()
    with pytest.raises(InputDataError, match="no cameras found; expected sparse/0/ .COLMAP., transforms.json"):
        read_model(tmp_path)
    with pytest.raises(SystemExit) as exc:  # not a choice: a command-line parse error
        main(["-q", "convert", str(tmp_path), str(tmp_path / "x.toy"), "--to", "toy"])
    assert exc.value.code == 2
    assert "invalid choice: 'toy'" in capsys.readouterr().err


def test_the_registry_names_every_format_once_in_detection_order():
    names = [f.NAME for f in cameras.FORMATS]
    assert names == ["colmap-text", "colmap-bin", "transforms", "blender", "neus", "llff", "strecha", "pytorch3d"]
    assert formats() == ("auto", "colmap-text", "colmap-bin", "transforms", "blender", "neus", "llff", "pytorch3d")
    for f in cameras.FORMATS:
        assert hasattr(f, "read") == hasattr(f, "detect") and (hasattr(f, "read") or hasattr(f, "write")), f.NAME
    with pytest.raises(BadArgumentError, match="registered already"):
        cameras.register(cameras.FORMATS[0])


def test_old_import_paths_are_the_same_functions():
    from photorecon.io import colmap, colmap_text, formats as old_formats, nerf, strecha
    from photorecon.io.cameras import blender, colmap_bin, llff, neus, transforms

    assert nerf.read_transforms is transforms.read_transforms and nerf.write_blender is blender.write_blender
    assert old_formats.read_llff is llff.read_llff and old_formats.read_neus is neus.read_neus
    assert colmap.read_colmap_binary is colmap_bin.read_colmap_binary
    assert colmap_text.SparseModel is SparseModel and strecha.read_strecha is cameras.strecha.read_strecha
