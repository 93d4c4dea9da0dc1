"""Monocular depth as a depth method of the whole stage (``reconstruct --depth-model FILE.onnx``): an ONNX model per
image, aligned to the SfM points (``depth.mono.run_mono``, its tasks and settings ``MonoConfig``)."""
from __future__ import annotations

SOURCE = "mono"


def selected(run) -> bool:
    return bool(run.depth_model)


def check(run) -> None:
    """The model file, before anything is written."""
    if run.depth_model:
        from ..mono import check_model_file

        check_model_file(run.depth_model)


def inputs(run, fingerprint) -> dict:
    """What the stage's key hashes: ``fingerprint`` (``stages.fingerprint``) of the model file, and the preset."""
    return {"model": fingerprint(run.depth_model), "preset": run.depth_preset}


def run_stage(dataset, run, out_dir, executor, work, factor: float = 1.0) -> dict:
    """Monocular depth maps of the dataset's views in ``out_dir`` (aligned to its sparse points: ``factor`` is
    already in them)."""
    from ..mono import MonoConfig, run_mono

    rep = run_mono(dataset, run.depth_model, out_dir, MonoConfig(preset=run.depth_preset), executor(), work)
    return {"source": SOURCE, "views": rep["views"], "excluded": rep.get("excluded", {})}
