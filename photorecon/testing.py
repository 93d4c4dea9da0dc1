"""Test inputs made on the spot, shared by the test suite and the benchmarks: small ONNX models built with the
``onnx`` package (``pip install photorecon[test]``: an exact "oracle" depth model, deliberately broken models,
a random-weight network of MiDaS-small-like compute; no weights are downloaded), geotagged JPEGs, and synthetic
datasets in a test's temporary folder (``synth_scene``)."""
from __future__ import annotations

import numpy as np


def _save(graph, path, opset=17):
    import onnx
    from onnx import helper

    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
    model.ir_version = 10  # onnxruntime 1.31 accepts IR <= 13; onnx writes 14 by default
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def oracle_model(path, size=(256, 256), mean=0.485, std=0.229, scale=3.7, shift=0.25):
    """Reads the red channel (undoing the preset normalisation) and outputs ``scale * red + shift`` at the
    model's fixed input size: an exact disparity 'predictor' for images whose red channel encodes disparity."""
    from onnx import TensorProto, helper, numpy_helper

    H, W = size
    inits = [numpy_helper.from_array(np.array([0], np.int64), "starts"),
             numpy_helper.from_array(np.array([1], np.int64), "ends"),
             numpy_helper.from_array(np.array([1], np.int64), "axes"),
             numpy_helper.from_array(np.array(std, np.float32), "std"),
             numpy_helper.from_array(np.array(mean, np.float32), "mean"),
             numpy_helper.from_array(np.array(scale, np.float32), "a"),
             numpy_helper.from_array(np.array(shift, np.float32), "b"),
             numpy_helper.from_array(np.array([1], np.int64), "sq")]
    nodes = [helper.make_node("Slice", ["image", "starts", "ends", "axes"], ["red"]),
             helper.make_node("Mul", ["red", "std"], ["r1"]),
             helper.make_node("Add", ["r1", "mean"], ["r2"]),
             helper.make_node("Mul", ["r2", "a"], ["r3"]),
             helper.make_node("Add", ["r3", "b"], ["r4"]),
             helper.make_node("Squeeze", ["r4", "sq"], ["disparity"])]
    graph = helper.make_graph(nodes, "oracle", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, H, W])],
                              [helper.make_tensor_value_info("disparity", TensorProto.FLOAT, [1, H, W])], inits)
    return _save(graph, path)


def rank3_model(path):
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "rank3",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [3, 64, 64])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [3, 64, 64])])
    return _save(graph, path)


def nan_model(path, size=(64, 64)):
    """Outputs 0 / 0 = NaN everywhere."""
    from onnx import TensorProto, helper

    H, W = size
    inits = []
    nodes = [helper.make_node("Sub", ["image", "image"], ["z"]),
             helper.make_node("Div", ["z", "z"], ["n"]),
             helper.make_node("ReduceMean", ["n"], ["out"], axes=[1], keepdims=0)]
    graph = helper.make_graph(nodes, "nan", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, H, W])],
                              [helper.make_tensor_value_info("out", TensorProto.FLOAT, [1, H, W])], inits)
    return _save(graph, path)


def conv_net(path, size=256, widths=(32, 64, 128, 256), seed=0, dynamic=False):
    """A random-weight encoder-decoder of 3x3 convolutions, roughly the compute of MiDaS v2.1 small
    (for timing only: its output is meaningless)."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    nodes, inits = [], []
    x, c_in = "image", 3
    for i, c in enumerate(widths):  # encoder: two convs per level, stride 2 on the first
        for j in range(2):
            w = rng.normal(0, np.sqrt(2 / (9 * c_in)), (c, c_in, 3, 3)).astype(np.float32)
            inits.append(numpy_helper.from_array(w, f"we{i}{j}"))
            nodes.append(helper.make_node("Conv", [x, f"we{i}{j}"], [f"e{i}{j}"], pads=[1, 1, 1, 1],
                                          strides=[2, 2] if j == 0 else [1, 1]))
            nodes.append(helper.make_node("Relu", [f"e{i}{j}"], [f"r{i}{j}"]))
            x, c_in = f"r{i}{j}", c
    for i, c in enumerate(reversed(widths[:-1])):  # decoder: upsample x2 + conv
        inits.append(numpy_helper.from_array(np.array([1, 1, 2, 2], np.float32), f"sc{i}"))
        nodes.append(helper.make_node("Resize", [x, "", f"sc{i}"], [f"u{i}"], mode="linear"))
        w = rng.normal(0, np.sqrt(2 / (9 * c_in)), (c, c_in, 3, 3)).astype(np.float32)
        inits.append(numpy_helper.from_array(w, f"wd{i}"))
        nodes.append(helper.make_node("Conv", [f"u{i}", f"wd{i}"], [f"d{i}"], pads=[1, 1, 1, 1]))
        nodes.append(helper.make_node("Relu", [f"d{i}"], [f"rd{i}"]))
        x, c_in = f"rd{i}", c
    inits.append(numpy_helper.from_array(np.array([1, 1, 2, 2], np.float32), "scf"))
    nodes.append(helper.make_node("Resize", [x, "", "scf"], ["uf"], mode="linear"))
    w = rng.normal(0, np.sqrt(2 / (9 * c_in)), (1, c_in, 3, 3)).astype(np.float32)
    inits.append(numpy_helper.from_array(w, "wf"))
    nodes.append(helper.make_node("Conv", ["uf", "wf"], ["head"], pads=[1, 1, 1, 1]))
    nodes.append(helper.make_node("Relu", ["head"], ["out4"]))
    inits.append(numpy_helper.from_array(np.array([1], np.int64), "sq"))
    nodes.append(helper.make_node("Squeeze", ["out4", "sq"], ["depth"]))
    hw = ["h", "w"] if dynamic else [size, size]
    graph = helper.make_graph(nodes, "convnet", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, *hw])],
                              [helper.make_tensor_value_info("depth", TensorProto.FLOAT, [1, *hw])], inits)
    return _save(graph, path)


def write_gps_jpeg(path, lla, image=None, quality: int = 95):
    """A JPEG at ``path`` with EXIF GPS tags for ``lla`` = (latitude, longitude in degrees, altitude in metres),
    as a phone writes them (degrees / minutes / seconds rationals, N/S, E/W, above / below sea level); its
    pixels are ``image`` (an RGB uint8 array) or a flat grey 32x24."""
    from PIL import Image, TiffImagePlugin

    def rational(x: float, den: int = 10**6):
        return TiffImagePlugin.IFDRational(int(round(x * den)), den)

    def dms(a):
        a = abs(a)
        d = int(a)
        m = int((a - d) * 60)
        return (rational(d, 1), rational(m, 1), rational((a - d - m / 60) * 3600))

    lat, lon, alt = lla
    exif = Image.Exif()
    gps = exif.get_ifd(0x8825)
    gps[1], gps[2] = ("N" if lat >= 0 else "S"), dms(lat)
    gps[3], gps[4] = ("E" if lon >= 0 else "W"), dms(lon)
    gps[5], gps[6] = (0 if alt >= 0 else 1), rational(abs(alt), 1000)
    im = Image.new("RGB", (32, 24), (90, 90, 90)) if image is None else Image.fromarray(np.asarray(image, np.uint8))
    im.save(path, "JPEG", exif=exif, quality=quality)
    return path


def synth_scene(tmp_path_factory, name: str, **cfg):
    """A synthetic dataset (``SynthConfig(**cfg)``, rendered with ground truth) in a new temporary folder
    ``name`` of pytest's ``tmp_path_factory``: the scene fixtures of the test suite. Returns its path."""
    from .synthetic import SynthConfig, synthesize

    out = tmp_path_factory.mktemp(name)
    synthesize(SynthConfig(**cfg), out, overwrite=True)
    return out


def depth_scores(dataset, out, root) -> tuple[float, float, float]:
    """Depth maps written to ``out`` (``NAME.npy``; a missing one counts as empty) against the synthetic truth in
    ``root/depth``: (mean fraction of the kept depths within 1% of the truth, mean coverage of the true surface
    pixels, share of all kept depths that lie where the truth has no surface)."""
    from pathlib import Path

    from .metrics import depth_metrics

    within, cover, background, kept = [], [], 0, 0
    for v in dataset.views:
        gt = np.load(Path(root) / "depth" / f"{v.name}.npy")
        p = Path(out) / f"{v.name}.npy"
        d = np.load(p) if p.is_file() else np.zeros_like(gt)
        m = depth_metrics(d, gt)
        within.append(m["within"])
        cover.append(m["coverage"])
        background += int(((d > 0) & (gt <= 0)).sum())
        kept += int((d > 0).sum())
    return float(np.mean(within)), float(np.mean(cover)), background / max(kept, 1)


def multiscale_texture(n: int, scales: tuple[int, ...], seed: int = 0) -> np.ndarray:
    """An (n, n) float image around grey 0.5 (std 0.15): random blocks of each size in ``scales`` summed, the
    larger ones weighted more; a texture PatchMatch can match at every pyramid level."""
    rng = np.random.default_rng(seed)
    tex = np.zeros((n, n), np.float32)
    for s in scales:
        tex += np.kron(rng.random((n // s, n // s)), np.ones((s, s))).astype(np.float32) * (s / max(scales))
    return 0.5 + 0.15 * (tex - tex.mean()) / tex.std()


def textured_plane(path, image: np.ndarray, half: float = 2.0):
    """Write the square z = 0, ``half`` on each side of the origin, textured with the grey uint8 ``image``, as a
    GLB at ``path`` (a mesh for ``SynthConfig(mesh=...)``). Returns ``path``."""
    import trimesh
    from PIL import Image

    h = half
    mesh = trimesh.Trimesh([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1], [0, 1]],
                                                image=Image.fromarray(np.stack([image] * 3, -1)))
    mesh.export(path)
    return path
