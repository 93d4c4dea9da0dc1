"""The quality presets (``--quality``, ``StageConfigs.from_preset``, ``reconstruct(..., quality=...)``): one table
that the command line and the Python API both read, so ``--quality preview`` and ``quality="preview"`` give the
same settings.

A preset names settings as ``STAGE.FIELD`` (the ``StageConfigs`` section and the config's field, which is
also the command line's ``--STAGE.FIELD`` flag). Settings given explicitly win over the preset: on the command
line a flag or a ``--config`` file, in Python the overrides of ``from_preset``. "default" changes nothing.
"""
from __future__ import annotations

import dataclasses
import typing

from .errors import BadArgumentError

QUALITY_PRESETS: dict[str, dict[str, object]] = {
    # about 1/4 of the default's depth pixels, half the sources, fewer iterations, the checkerboard window from
    # 800 px, coarser voxels, no watertight companion: a quick look (about a third of the default's CPU; grazing
    # ground is less complete)
    "preview": {"sfm.max_image_size": 1024, "sfm.max_features": 4096,
                "mvs.max_size": 800, "mvs.n_sources": 4, "mvs.filter_sources": 8, "mvs.pm_levels": 3,
                "mvs.pm_iterations": 3, "mvs.pm_final_iterations": 0, "mvs.pm_sparse_min_size": 800,
                "fusion.voxel_footprints": 2.0, "clean.closed": "off"},
    "default": {},
    # features and depth up to 2400 px, more sources and iterations, finer voxels
    "high": {"sfm.max_image_size": 2400, "sfm.max_features": 16384,
             "mvs.max_size": 2400, "mvs.n_sources": 10, "mvs.pm_iterations": 6, "mvs.pm_fine_iterations": 2,
             "fusion.voxel_footprints": 1.0},
}


def quality_values(name: str) -> dict[str, object]:
    """The settings (``STAGE.FIELD -> value``) of the quality preset ``name``; ``BadArgumentError`` naming the
    presets for an unknown one."""
    if name not in QUALITY_PRESETS:
        raise BadArgumentError(f"quality: expected one of {', '.join(QUALITY_PRESETS)}, got {name!r}")
    return dict(QUALITY_PRESETS[name])


def stage_configs(quality: str = "default", **stages: typing.Mapping[str, object]):
    """The pipeline's ``StageConfigs`` with the quality preset ``quality`` applied to its defaults, then the
    settings of ``stages`` (``mvs={"n_sources": 6}``: a section of ``StageConfigs`` -> its fields' values), which
    win over the preset as a command-line flag does. Every value is checked as its config checks it."""
    from .pipeline import StageConfigs

    base = StageConfigs()
    sections = {f.name for f in dataclasses.fields(StageConfigs)}
    values: dict[str, dict[str, object]] = {}
    for dest, value in quality_values(quality).items():
        stage, name = dest.split(".", 1)
        values.setdefault(stage, {})[name] = value
    for stage, settings in stages.items():
        if stage not in sections:
            raise BadArgumentError(f"StageConfigs.from_preset: no stage {stage!r} (the stages: "
                                   f"{', '.join(sorted(sections))})")
        if not isinstance(settings, typing.Mapping):
            raise BadArgumentError(f"StageConfigs.from_preset: {stage}= expects a dict of its settings, got "
                                   f"{type(settings).__name__}")
        values.setdefault(stage, {}).update(settings)
    built = {}
    for stage, settings in values.items():
        cfg = getattr(base, stage)
        known = {f.name for f in dataclasses.fields(cfg)}
        unknown = sorted(set(settings) - known)
        if unknown:
            raise BadArgumentError(f"StageConfigs.from_preset: {stage}: no setting {unknown[0]!r} in "
                                   f"{type(cfg).__name__}")
        built[stage] = dataclasses.replace(cfg, **settings)  # checked by the config's __post_init__
    return dataclasses.replace(base, **built)
