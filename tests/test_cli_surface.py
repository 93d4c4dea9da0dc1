"""The command line's surface and the Python API agree: one quality preset table for ``--quality`` and
``StageConfigs.from_preset`` / ``reconstruct(quality=...)``; every field's flag is its name; a renamed flag or
settings-file key still works with a one-line pointer to its new name; tuning settings stay out of --help-all;
the commands' modules stay small."""
import argparse
from pathlib import Path

import pytest

from photorecon import cli
from photorecon.errors import BadArgumentError

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def parser():
    return cli.build_parser()


def _configs(parser, *extra):
    from photorecon.cli.commands import stage_configs_from_args

    return stage_configs_from_args(parser.parse_args(["reconstruct", "I", "-o", "O", *extra]))


# --- presets ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("quality", ["preview", "default", "high"])
def test_quality_flag_and_python_preset_give_the_same_configs(parser, quality):
    from photorecon.pipeline import StageConfigs

    from_cli = _configs(parser, "--quality", quality)
    from_api = StageConfigs.from_preset(quality)
    assert from_cli == from_api
    if quality == "preview":  # the preset did change something (not two sets of defaults)
        assert from_api.mvs.max_size == 800 and from_api.clean.closed == "off" != StageConfigs().clean.closed
        assert from_api.fusion.trunc_voxels == StageConfigs().fusion.trunc_voxels == 3.0  # the pipeline's default


def test_settings_over_a_preset_match_flags_over_it(parser):
    from photorecon.pipeline import StageConfigs

    assert (_configs(parser, "--quality", "preview", "--n-sources", "6", "--closed", "auto")
            == StageConfigs.from_preset("preview", mvs={"n_sources": 6}, clean={"closed": "auto"}))
    assert StageConfigs.from_preset("preview", mvs={"n_sources": 6}).mvs.max_size == 800  # the rest stays


@pytest.mark.parametrize("kwargs, what", [
    ({"quality": "best"}, "expected one of preview, default, high, got 'best'"),
    ({"mvs_settings": {"n_sources": 6}}, "no stage 'mvs_settings'"),
    ({"mvs": {"n_source": 6}}, "no setting 'n_source' in MVSConfig"),
    ({"mvs": {"n_sources": 0}}, "MVSConfig.n_sources"),
])
def test_bad_preset_requests_are_refused_by_name(kwargs, what):
    from photorecon.pipeline import StageConfigs

    quality = kwargs.pop("quality", "preview")
    with pytest.raises(BadArgumentError, match=what):
        StageConfigs.from_preset(quality, **kwargs)


def test_reconstruct_quality_runs_with_the_preset(tmp_path, monkeypatch):
    from photorecon import pipeline
    from photorecon.pipeline import StageConfigs

    images = tmp_path / "images"
    images.mkdir()
    seen = {}
    monkeypatch.setattr(pipeline, "_reconstruct", lambda images, out, cfgs, *a, **k: seen.setdefault("cfgs", cfgs))
    pipeline.reconstruct(images, tmp_path / "out", quality="preview")
    assert seen["cfgs"] == StageConfigs.from_preset("preview")
    with pytest.raises(BadArgumentError, match="not both"):
        pipeline.reconstruct(images, tmp_path / "out2", StageConfigs(), quality="preview")
    with pytest.raises(BadArgumentError, match="expected one of"):
        pipeline.reconstruct(images, tmp_path / "out3", quality="fast")
    assert not (tmp_path / "out2").exists() and not (tmp_path / "out3").exists()


def test_commands_modules_stay_small():
    for path in (ROOT / "photorecon" / "cli").glob("*.py"):
        assert len(path.read_text().splitlines()) <= 500, path.name
