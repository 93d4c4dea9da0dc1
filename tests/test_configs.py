"""The stage configs check their own fields when built (Python API, presets, settings files and the command line
alike), from the same declarations the command line's flags are built from (``photorecon.config_checks``)."""
import argparse
import dataclasses
import typing

import numpy as np
import pytest

from photorecon import fields
from photorecon.errors import BadArgumentError

CONFIGS = ["photorecon.poses.sfm:SfMConfig", "photorecon.depth.mvs:MVSConfig", "photorecon.fusion:FusionConfig",
           "photorecon.mesh:CleanConfig", "photorecon.mesh.texture:TextureConfig", "photorecon.depth.mono:MonoConfig",
           "photorecon.poses.scale:ScaleConfig", "photorecon.distributed:ClusterConfig",
           "photorecon.poses.triangulate:TriangulateConfig", "photorecon.synthetic:SynthConfig",
           "photorecon.demo:DemoConfig"]


def _cls(spec):
    import importlib

    module, name = spec.split(":")
    return getattr(importlib.import_module(module), name)


def _outside(rng: fields.Ranged):
    """A value just outside the declared range (None when the range is unbounded on both sides)."""
    if rng.lo is not None:
        bad = rng.lo if rng.exclusive_min else rng.lo - 1
    elif rng.hi is not None:
        bad = rng.hi + 1
    else:
        return None
    if bad in rng.also:
        bad = (rng.hi + 1) if rng.hi is not None else None
    if bad is not None and rng.kind is int:
        bad = int(bad)
    return bad


@pytest.mark.parametrize("case", [
    ("photorecon.depth.mvs:MVSConfig", {"method": "bogus"}, "MVSConfig.method", "patchmatch, sweep", "'bogus'"),
    ("photorecon.depth.mvs:MVSConfig", {"max_size": -5}, "MVSConfig.max_size", "64..65536 or 0", "-5"),
    ("photorecon.poses.sfm:SfMConfig", {"max_features": 0}, "SfMConfig.max_features", "16..1000000", "0"),
    ("photorecon.fusion:FusionConfig", {"mesher": "voronoi"}, "FusionConfig.mesher", "tsdf, grid, poisson", "'voronoi'"),
    ("photorecon.fusion:FusionConfig", {"voxel_size": float("nan")}, "FusionConfig.voxel_size", "> 0", "nan"),
    ("photorecon.depth.mvs:MVSConfig", {"window": 8}, "MVSConfig.window", "odd", "8"),
    ("photorecon.depth.mvs:MVSConfig", {"max_size": "800"}, "MVSConfig.max_size", "an integer", "'800'"),
    ("photorecon.depth.mvs:MVSConfig", {"geom_consistency": "no"}, "MVSConfig.geom_consistency", "true or false", "'no'"),
    ("photorecon.mesh:CleanConfig", {"crop": (0, 0, 0, 1, -1, 1)}, "CleanConfig.crop", "ymin < ymax", "-1"),
    ("photorecon.mesh.texture:TextureConfig", {"atlas_size": 100}, "TextureConfig.atlas_size", "256..65536", "100"),
    ("photorecon.depth.mono:MonoConfig", {"std": (1.0, 0.0, 1.0)}, "MonoConfig.std", "> 0", "0.0"),
    ("photorecon.distributed:ClusterConfig", {"cluster": "local:0"}, "ClusterConfig.cluster", "N >= 1", "local:0"),
], ids=lambda c: f"{c[0].split(':')[1]}-{next(iter(c[1]))}")
def test_a_bad_value_fails_when_the_config_is_built_naming_field_value_and_range(case):
    spec, kwargs, name, allowed, value = case
    with pytest.raises(BadArgumentError) as exc:
        _cls(spec)(**kwargs)
    msg = str(exc.value)
    assert msg.startswith(name + " (--") and allowed in msg and value in msg.rsplit("got", 1)[1]
    assert "\n" not in msg


@pytest.mark.parametrize("spec", CONFIGS)
def test_every_declared_range_and_choice_is_checked_by_the_config_and_the_parser_alike(spec):
    """For every numeric field with a range and every Literal field: a value just outside fails when the config is
    built, and the command line's parser for that field (built from the same declaration) rejects it too, in the
    same words."""
    from photorecon.cli.config import Parser, add_config_arguments

    cls = _cls(spec)
    cls()  # the defaults are valid
    hints = typing.get_type_hints(cls)
    parser = Parser(prog="t")
    add_config_arguments(parser, cls)
    actions = {a.dest.split(".", 1)[1]: a for a in parser._actions  # each field's own flag, not a former name
               if "." in a.dest and not getattr(a, "renamed_to", None)}
    checked = 0
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        choices = fields.choices(tp)
        kind, is_tuple = fields.field_kind(tp)
        if choices is not None:
            bad = "not-a-choice"
            assert actions[f.name].choices == list(choices)
        elif kind is not None and "range" in f.metadata and not is_tuple:
            rng = fields.Ranged.from_metadata(kind, f.metadata)
            bad = _outside(rng)
            if bad is None:
                continue
            with pytest.raises(argparse.ArgumentTypeError) as parse_err:
                actions[f.name].type(str(bad))
            assert rng.describe() in str(parse_err.value)
        else:
            continue
        with pytest.raises(BadArgumentError) as exc:
            cls(**{f.name: bad})
        assert f"{cls.__name__}.{f.name}" in str(exc.value) and repr(bad) in str(exc.value)
        if choices is None:
            assert rng.describe() in str(exc.value)
        checked += 1
    assert checked >= 1


def test_numpy_numbers_are_accepted_and_special_values_keep_their_meaning():
    from photorecon.depth.mvs import MVSConfig
    from photorecon.poses.sfm import SfMConfig

    cfg = MVSConfig(max_size=np.int64(800), min_confidence=np.float32(0.25), geom_consistency=np.bool_(False))
    assert (cfg.max_size, cfg.geom_consistency) == (800, False)
    assert MVSConfig(max_size=0).max_size == 0 and SfMConfig(threads=-1).threads == -1
    with pytest.raises(BadArgumentError, match=r"SfMConfig.threads .*1\.\.4096 or -1, got -2"):
        SfMConfig(threads=-2)


def test_replace_and_stage_configs_are_checked_too():
    from photorecon.depth.mvs import MVSConfig
    from photorecon.pipeline import ReconstructConfig, StageConfigs

    with pytest.raises(BadArgumentError, match="MVSConfig.n_sources"):
        dataclasses.replace(MVSConfig(), n_sources=0)
    with pytest.raises(BadArgumentError, match=r"ReconstructConfig.texture \(--texture\): expected one of on, off"):
        StageConfigs(run=ReconstructConfig(texture="yes"))
    with pytest.raises(BadArgumentError, match=r"StageConfigs.mvs: expected a .*MVSConfig .*got dict"):
        StageConfigs(mvs={"max_size": 800})


def test_reconstruct_refuses_a_dict_as_cfgs_before_any_work(blob_small, tmp_path):
    from photorecon.pipeline import reconstruct

    out = tmp_path / "out"
    with pytest.raises(BadArgumentError, match=r"cfgs: expected a .*StageConfigs .*got dict"):
        reconstruct(blob_small / "images", out, cfgs={"mvs": {"method": "sweep"}})
    assert not out.exists()


@pytest.mark.parametrize("call", ["run_sfm", "run_mvs", "fuse_dataset"])
def test_stage_functions_refuse_a_dict_as_config(blob_small, tmp_path, call):
    import photorecon

    out = tmp_path / "out"
    args = {"run_sfm": (blob_small / "images", out), "run_mvs": (blob_small, out),
            "fuse_dataset": (blob_small, out)}[call]
    with pytest.raises(BadArgumentError, match=r"cfg: expected a photorecon\..*Config .*got dict"):
        getattr(photorecon, call)(*args, {"max_size": 800})
    assert not out.exists()


def test_config_checks_module_keeps_its_former_name():
    """``photorecon.fields`` (the former name) is the same module as ``photorecon.config_checks``."""
    import photorecon.config_checks as checks
    from photorecon.fields import check_config
    import photorecon.fields as old

    assert old is checks and check_config is checks.check_config and old._HINTS is checks._HINTS
