"""Monocular depth from a user-supplied ONNX model (MiDaS / DPT / Depth Anything exports) on onnxruntime,
made consistent with the SfM reconstruction by a robust per-image (or global) scale-and-shift fit.

No weights ship with photorecon and nothing is downloaded: the user passes the model file.

Presets (each value overridable):

| preset              | input                          | normalisation          | typical export               |
|---------------------|--------------------------------|------------------------|------------------------------|
| midas_small         | 256, multiple of 32            | ImageNet mean/std      | MiDaS v2.1 small (256x256)   |
| dpt_hybrid          | 384, multiple of 32            | mean 0.5, std 0.5      | MiDaS v3 DPT-Hybrid          |
| dpt_large           | 384, multiple of 32            | mean 0.5, std 0.5      | MiDaS v3 DPT-Large           |
| depth_anything_v2   | 518, multiple of 14            | ImageNet mean/std      | Depth Anything V2 (S/B/L)    |

A model with a fixed input size gets exactly that size; a dynamic one gets the preset size on the short
side (aspect kept) rounded to the multiple. The output (relative inverse depth by default) is resized back
to the image size.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from ..cameras import View
from ..errors import BadArgumentError, InputDataError, NoDepthError
from ..io.atomic import atomic_path, atomic_write_json
from ..io.images import write_depth
from ..results import Result
from ..tasks import IN_PROCESS, Executor, Task
from .align import Fit, fit_scale_shift
from ..fields import check_config, expect_config

log = logging.getLogger("photorecon")

IMAGENET = ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225))
PRESETS: dict[str, dict] = {
    "midas_small": {"size": 256, "multiple": 32, "mean": IMAGENET[0], "std": IMAGENET[1]},
    "dpt_hybrid": {"size": 384, "multiple": 32, "mean": (0.5, 0.5, 0.5), "std": (0.5, 0.5, 0.5)},
    "dpt_large": {"size": 384, "multiple": 32, "mean": (0.5, 0.5, 0.5), "std": (0.5, 0.5, 0.5)},
    "depth_anything_v2": {"size": 518, "multiple": 14, "mean": IMAGENET[0], "std": IMAGENET[1]},
}


@dataclass
class MonoConfig:
    """Settings of the monocular depth stage (``photorecon depth``)."""

    preset: str | None = field(default=None, metadata={"help": f"model preset: {', '.join(PRESETS)} (default: midas_small)", "metavar": "NAME"})
    size: int | None = field(default=None, metadata={"help": "input size override, pixels (dynamic models: short side)", "range": (16, 16384)})
    multiple: int | None = field(default=None, metadata={"help": "dynamic input sizes are rounded to this multiple, pixels", "range": (1, 1024)})
    mean: tuple[float, ...] | None = field(default=None, metadata={"help": "normalisation mean r,g,b override", "range": (None, None), "length": 3, "metavar": "R,G,B"})
    std: tuple[float, ...] | None = field(default=None, metadata={"help": "normalisation std r,g,b override", "range": (0.0, None), "exclusive_min": True, "length": 3, "metavar": "R,G,B"})
    output: Literal["disparity", "depth", "metric"] = field(default="disparity", metadata={"help": "what the model predicts: relative inverse depth, relative depth, or metric depth"})
    alignment: Literal["per-image", "global"] = field(default="per-image", metadata={"help": "fit scale/shift per image or one shared fit"})
    min_points: int = field(default=20, metadata={"help": "views with fewer SfM points are excluded", "range": (2, 100_000_000)})
    max_residual: float = field(default=0.05, metadata={"help": "views whose median relative residual exceeds this are excluded", "range": (0.0, 100.0), "exclusive_min": True})
    threads: int = field(default=2, metadata={"help": "onnxruntime threads", "range": (1, 4096)})
    batch: int = field(default=1, metadata={"help": "images per inference call (when the model allows a batch)", "range": (1, 4096)})

    def resolved(self) -> dict:
        name = self.preset or "midas_small"
        if name not in PRESETS:
            raise BadArgumentError(f"--preset: expected one of {sorted(PRESETS)}, got {name!r}")
        p = dict(PRESETS[name])
        for k in ("size", "multiple", "mean", "std"):
            if getattr(self, k) is not None:
                p[k] = getattr(self, k)
        if len(p["mean"]) != 3 or len(p["std"]) != 3 or min(p["std"]) <= 0:
            raise BadArgumentError(f"--mean/--std: expected 3 values each (std > 0), got {p['mean']} / {p['std']}")
        return p

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.fields)
        self.resolved()  # an unknown preset: refused when built, before any model is loaded


def check_model_file(path: str | Path) -> Path:
    """The ONNX model file ``path``, or ``InputDataError`` naming it: the one check of a model path, run by
    the pipeline before anything is written and by the model loader."""
    path = Path(path)
    if not path.is_file():
        raise InputDataError(f"depth model {path}: no such file; export the model to ONNX first (README: "
                             "Monocular depth models)")
    return path


class MonoModel:
    """An ONNX depth model on onnxruntime: input layout and size read from the model."""

    def __init__(self, path: str | Path, cfg: MonoConfig | None = None):
        import onnxruntime as ort

        self.path = check_model_file(path)
        self.cfg = cfg or MonoConfig()
        self.pre = self.cfg.resolved()
        so = ort.SessionOptions()
        so.intra_op_num_threads = max(1, int(self.cfg.threads))
        so.log_severity_level = 3
        providers = ["CPUExecutionProvider"]
        if "CUDAExecutionProvider" in ort.get_available_providers():
            providers.insert(0, "CUDAExecutionProvider")
        try:
            self.session = ort.InferenceSession(str(self.path), so, providers=providers)
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            msg = str(exc).splitlines()[0][:200]
            raise InputDataError(f"model {self.path}: not a loadable ONNX model ({msg})") from None
        self.providers = self.session.get_providers()
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        shape = list(inp.shape)
        if len(shape) != 4:
            raise InputDataError(f"model {self.path}: expected an image input of rank 4 (N, 3, H, W) or "
                                 f"(N, H, W, 3), got {inp.name} with shape {shape}")
        if shape[1] == 3:
            self.layout, hw = "NCHW", shape[2:4]
        elif shape[3] == 3:
            self.layout, hw = "NHWC", shape[1:3]
        else:
            raise InputDataError(f"model {self.path}: cannot find the 3 colour channels in input shape {shape}")
        self.fixed = tuple(hw) if all(isinstance(d, int) and d > 0 for d in hw) else None
        self.batch_fixed = shape[0] if isinstance(shape[0], int) and shape[0] > 0 else None

    def input_size(self, width: int, height: int) -> tuple[int, int]:
        """(w, h) fed to the model for an image of ``width`` x ``height``."""
        if self.fixed:
            return int(self.fixed[1]), int(self.fixed[0])
        m, size = int(self.pre["multiple"]), int(self.pre["size"])
        s = size / min(width, height)
        return max(m, int(round(width * s / m)) * m), max(m, int(round(height * s / m)) * m)

    def preprocess(self, rgb: np.ndarray) -> np.ndarray:
        H, W = rgb.shape[:2]
        w, h = self.input_size(W, H)
        x = cv2.resize(rgb.astype(np.float32) / 255.0, (w, h), interpolation=cv2.INTER_AREA if w < W else cv2.INTER_CUBIC)
        x = (x - np.array(self.pre["mean"], np.float32)) / np.array(self.pre["std"], np.float32)
        return x.transpose(2, 0, 1) if self.layout == "NCHW" else x

    def predict(self, images: list[np.ndarray], names: list[str] | None = None) -> list[np.ndarray]:
        """Raw model outputs resized back to each image's size (float32 (H, W))."""
        names = names or [f"image {i}" for i in range(len(images))]
        out = []
        bs = 1 if self.batch_fixed == 1 else max(1, int(self.cfg.batch))
        for i in range(0, len(images), bs):
            chunk = images[i:i + bs]
            sizes = {self.input_size(im.shape[1], im.shape[0]) for im in chunk}
            groups = [chunk] if len(sizes) == 1 else [[im] for im in chunk]
            k = i
            for g in groups:
                x = np.stack([self.preprocess(im) for im in g]).astype(np.float32)
                try:
                    y = self.session.run(None, {self.input_name: x})[0]
                except Exception as exc:  # onnxruntime: shape/type errors
                    raise InputDataError(f"model {self.path}: inference failed on {names[k]} "
                                         f"({str(exc).splitlines()[0][:200]})") from None
                y = np.asarray(y, np.float32)
                if y.ndim == 4:
                    y = y[:, 0]
                if y.ndim == 2:
                    y = y[None]
                if y.ndim != 3 or y.shape[0] != len(g):
                    raise InputDataError(f"model {self.path}: expected an output of shape (N, H, W) or "
                                         f"(N, 1, H, W), got {y.shape}")
                for im, pred in zip(g, y):
                    if not np.all(np.isfinite(pred)):
                        raise InputDataError(f"model {self.path}: output for {names[k]} contains NaN or inf; "
                                             "is this a depth model, with the right --preset normalisation?")
                    out.append(cv2.resize(pred, (im.shape[1], im.shape[0]), interpolation=cv2.INTER_LINEAR))
                    k += 1
        return out


def _sparse_samples(model, view: View, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(prediction at the SfM points' pixels, their SfM z-depth) for ``view``."""
    if view.name not in model.observations:
        return np.zeros(0), np.zeros(0)
    uv, ids = model.observations[view.name]
    index = model.point_index()
    keep = [j for j, p in enumerate(ids) if p >= 0 and int(p) in index]
    if not keep:
        return np.zeros(0), np.zeros(0)
    P = model.points[[index[int(ids[j])] for j in keep]]
    z = (P @ view.cam_from_world[:3, :3].T + view.cam_from_world[:3, 3])[:, 2]
    uvk = uv[keep]
    H, W = pred.shape
    u = np.clip(uvk[:, 0], 0, W - 1).astype(np.float32)
    v = np.clip(uvk[:, 1], 0, H - 1).astype(np.float32)
    vals = cv2.remap(pred, u[:, None], v[:, None], cv2.INTER_LINEAR)[:, 0]
    ok = z > 0
    return vals[ok], z[ok]


def to_depth(pred: np.ndarray, fit: Fit, output: str) -> np.ndarray:
    """Aligned z-depth from a raw prediction and its fit (0 where the result is not a positive depth)."""
    a = fit.scale * pred.astype(np.float64) + fit.shift
    with np.errstate(divide="ignore", invalid="ignore"):
        d = 1.0 / a if output == "disparity" else a
    d[~np.isfinite(d) | (d <= 0)] = 0
    return d.astype(np.float32)


_NETS: dict[tuple, "MonoModel"] = {}  # per process: the model session, made once per worker


def _mono_task(ctx: tuple, name: str) -> dict:
    """One view's raw prediction to ``work/NAME.npy`` (atomically; a task whose file is there returns at once)."""
    dataset, model_path, cfg, work = ctx
    path = Path(work) / f"{name}.npy"
    if path.is_file():
        return {"seconds": 0.0, "reused": True}
    key = (str(model_path), Path(model_path).stat().st_mtime_ns, repr(cfg))
    if key not in _NETS:
        _NETS.clear()
        _NETS[key] = MonoModel(model_path, cfg)
    view = next(v for v in dataset.views if v.name == name)
    t0 = time.perf_counter()
    pred = _NETS[key].predict([dataset.image(view)], [name])[0]
    with atomic_path(path) as tmp:
        np.save(tmp, pred.astype(np.float32))
    return {"seconds": time.perf_counter() - t0}


@dataclass
class MonoResult(Result):
    """What ``run_mono`` did (also written to OUT_DIR/mono_report.json)."""

    model: str
    providers: list
    preset: str
    input_size: list | str  # [H, W] of a fixed-size model, or "dynamic"
    views: int  # depth maps written
    excluded: dict  # view name -> reason (too few SfM points, a bad fit)
    inference_ms_per_image: float
    alignment_ms_per_image: float
    fits: dict  # view name -> the scale/shift fit


def run_mono(dataset, model_path: str | Path, out_dir: str | Path | None = None, cfg: MonoConfig | None = None,
             executor: Executor | None = None, work_dir: str | Path | None = None) -> MonoResult:
    """Monocular depth for every view of a ``Dataset`` (synth layout out: NAME.npy + NAME.png). Views with too
    few SfM points or a bad fit are excluded and reported. Raises ``NoDepthError`` if none is left.

    The predictions are one task per view run by ``executor`` (default: in this process; a Dask cluster through
    ``photorecon.distributed``), each written to ``work_dir`` (default OUT_DIR/.mono_work; removed on success,
    reused by a resumed run); the alignment and the depth files follow here."""
    import hashlib
    import shutil

    cfg = expect_config(cfg, MonoConfig, "cfg")
    net = MonoModel(model_path, cfg)  # a bad model fails here, before any task
    out = Path(out_dir) if out_dir else dataset.layout.depth
    out.mkdir(parents=True, exist_ok=True)
    model = dataset.model
    samples = {}
    st = Path(model_path).stat()
    tag = hashlib.sha256(repr((str(Path(model_path).resolve()), st.st_size, st.st_mtime_ns, repr(cfg),
                               [(v.name, str(dataset.image_path(v))) for v in dataset.views])).encode()).hexdigest()[:16]
    work_root = Path(work_dir) if work_dir else out / ".mono_work"
    work = work_root / tag
    ex = executor or IN_PROCESS
    t0 = time.perf_counter()
    task_info = ex.run(_mono_task, [Task(v.name, (v.name,)) for v in dataset.views], (dataset, str(model_path), cfg, work),
                       desc="mono depth")
    t_infer = sum(r["seconds"] for r in task_info.values()) / max(len(task_info), 1)
    preds = {v.name: np.load(work / f"{v.name}.npy") for v in dataset.views}
    t0 = time.perf_counter()
    shift = cfg.output != "metric"
    fits: dict[str, Fit] = {}
    for v in dataset.views:
        x, z = _sparse_samples(model, v, preds[v.name])
        samples[v.name] = (x, z)
        target = 1.0 / z if cfg.output == "disparity" else z
        fits[v.name] = fit_scale_shift(x, target, shift=shift, min_points=cfg.min_points,
                                       max_median_residual=cfg.max_residual)
    if cfg.alignment == "global":
        xs = np.concatenate([samples[n][0] for n in samples]) if samples else np.zeros(0)
        zs = np.concatenate([samples[n][1] for n in samples]) if samples else np.zeros(0)
        g = fit_scale_shift(xs, 1.0 / zs if cfg.output == "disparity" else zs, shift=shift,
                            min_points=cfg.min_points, max_median_residual=cfg.max_residual)
        for n, (x, z) in samples.items():
            target = 1.0 / z if cfg.output == "disparity" else z
            rel = np.abs(g.scale * x + g.shift - target) / np.abs(target) if len(x) else np.array([np.inf])
            med = float(np.median(rel)) if len(x) else float("nan")
            ok = g.ok and len(x) >= cfg.min_points and med <= cfg.max_residual
            fits[n] = Fit(g.scale, g.shift, len(x), int((rel < 0.05).sum()), float((rel < 0.05).mean()) if len(x) else 0.0,
                          med, ok, "" if ok else (g.reason or f"median residual {100 * med:.1f}% under the global fit"))
    t_align = (time.perf_counter() - t0) / max(len(fits), 1)
    excluded, written = {}, 0
    for v in dataset.views:
        f = fits[v.name]
        if not f.ok:
            excluded[v.name] = f.reason
            log.warning("mono: view %s excluded: %s", v.name, f.reason)
            continue
        d = to_depth(preds[v.name], f, cfg.output)
        mask = dataset.mask(v)
        if mask is not None:
            d[~mask] = 0
        write_depth(out, v.name, d)
        written += 1
    report = MonoResult(model=str(model_path), providers=net.providers, preset=cfg.preset or "midas_small",
                        input_size=list(net.fixed) if net.fixed else "dynamic", views=written, excluded=excluded,
                        inference_ms_per_image=1000 * t_infer, alignment_ms_per_image=1000 * t_align,
                        fits={n: f.as_dict() for n, f in fits.items()})
    atomic_write_json(out / "mono_report.json", report.to_dict())
    shutil.rmtree(work, ignore_errors=True)
    try:
        work_root.rmdir()
    except OSError:
        pass
    if not written:
        raise NoDepthError("mono: every view was excluded (" + "; ".join(f"{k}: {m}" for k, m in list(excluded.items())[:3]) + ")")
    return report
