"""The command line's surface and the Python API agree: one quality preset table for ``--quality`` and
``StageConfigs.from_preset`` / ``reconstruct(quality=...)``; every field's flag is its name; a renamed flag or
settings-file key still works with a one-line pointer to its new name; tuning settings stay out of --help-all;
the commands' modules stay small."""
import re
from pathlib import Path

import pytest

from photorecon import cli
from photorecon.errors import BadArgumentError

ROOT = Path(__file__).resolve().parents[2]


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


# --- every flag is its field's name; former names still work ----------------------------------------------


def test_every_config_flag_is_its_field_name(parser):
    import dataclasses

    from photorecon.cli.config import config_prefix
    from photorecon.pipeline import StageConfigs

    actions = parser.command_parser("reconstruct")._option_string_actions
    # the model stage sets these texturing settings itself: --model-faces, --max-atlas (their former names: aliases)
    by_model = {("texture", "texture_faces"), ("texture", "atlas_size")}
    for cfg in vars(StageConfigs()).values():
        prefix = config_prefix(type(cfg))
        for f in dataclasses.fields(cfg):
            flag = f"--{prefix}.{f.name.replace('_', '-')}"
            if (prefix, f.name) in by_model:
                assert flag not in actions, flag
                continue
            assert actions[flag].dest == f"{prefix}.{f.name}", flag
            assert not getattr(actions[flag], "renamed_to", None)


@pytest.mark.parametrize("command, old, new, value, where", [
    ("reconstruct", "--mvs", "--method", "sweep", ("mvs", "method")),
    ("reconstruct", "--mvs.mvs", "--mvs.method", "sweep", ("mvs", "method")),
    ("reconstruct", "--fusion-memory", "--memory-gb", "3.5", ("fusion", "memory_gb")),
    ("reconstruct", "--fusion.fusion-memory", "--fusion.memory-gb", "3.5", ("fusion", "memory_gb")),
    ("mvs", "--mvs", "--method", "sweep", ("mvs", "method")),
    ("fuse", "--fusion-memory", "--memory-gb", "3.5", ("fusion", "memory_gb")),
    ("reconstruct", "--texture-faces", "--model-faces", "5000", ("model", "model_faces")),
    ("reconstruct", "--atlas-size", "--max-atlas", "1024", ("model", "max_atlas")),
])
def test_a_former_flag_still_works_and_names_the_new_one(parser, caplog, command, old, new, value, where):
    import logging

    from photorecon.cli.config import config_from_args
    from photorecon.depth.mvs import MVSConfig
    from photorecon.fusion import FusionConfig

    from photorecon.mesh.model import ModelConfig

    cls = {"mvs": MVSConfig, "fusion": FusionConfig, "model": ModelConfig}[where[0]]
    positional = ["I", "-o", "O"] if command == "reconstruct" else ["D", "-o", "O"]
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        by_old = config_from_args(cls, parser.parse_args([command, *positional, old, value]))
    lines = [r.getMessage() for r in caplog.records]
    assert lines == [f"{old} is now {new} (the former name still works, for now)"]
    assert getattr(by_old, where[1]) == type(getattr(cls(), where[1]))(value) != getattr(cls(), where[1])
    caplog.clear()
    by_new = config_from_args(cls, parser.parse_args([command, *positional, new, value]))
    assert by_new == by_old and not caplog.records  # the new name: no warning
    # the former name is hidden from the help, the new one shown
    full = parser.command_parser(command).format_help(full=True)
    assert f"{old} " not in full.replace(",", " ") and new in full


@pytest.mark.parametrize("text, old, new, where", [
    ("mvs = 'sweep'\n", "mvs", "method", ("mvs", "method", "sweep")),
    ("[mvs]\nmvs = 'sweep'\n", "[mvs] mvs", "[mvs] method", ("mvs", "method", "sweep")),
    ("fusion_memory = 3.5\n", "fusion_memory", "memory_gb", ("fusion", "memory_gb", 3.5)),
    ("[fusion]\nfusion_memory = 3.5\n", "[fusion] fusion_memory", "[fusion] memory_gb", ("fusion", "memory_gb", 3.5)),
])
def test_a_former_settings_file_key_still_works_and_names_the_new_one(parser, caplog, tmp_path, text, old, new,
                                                                      where):
    f, cfgs, messages = _reconstruct_with_settings_file(parser, caplog, tmp_path, text)
    assert getattr(getattr(cfgs, where[0]), where[1]) == where[2]
    assert messages == [f"--config {f}: {old} is now {new} (the former name still works, for now)"]


def _reconstruct_with_settings_file(parser, caplog, tmp_path, text: str):
    """``reconstruct I -o O --config FILE`` with ``text`` in FILE: (FILE, the configs, the warnings logged)."""
    import logging

    from photorecon.cli.settings import apply_settings_file

    f = tmp_path / "s.toml"
    f.write_text(text)
    args = parser.parse_args(["reconstruct", "I", "-o", "O"])
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        apply_settings_file(parser.command_parser("reconstruct"), args, f)
        cfgs = _configs_of(args)
    return f, cfgs, [r.getMessage() for r in caplog.records]


@pytest.mark.parametrize("command, old, new", [
    ("reconstruct", "--object", "--scene object"),
    ("reconstruct", "--clean.object", "--clean.scene object"),
    ("fuse", "--object", "--scene object"),
])
def test_the_former_object_flag_is_scene_object(parser, caplog, command, old, new):
    import logging

    from photorecon.cli.config import config_from_args
    from photorecon.mesh import CleanConfig

    positional = ["I", "-o", "O"] if command == "reconstruct" else ["D", "-o", "O"]

    def clean_cfg(*flags):
        return config_from_args(CleanConfig, parser.parse_args([command, *positional, *flags]))

    with caplog.at_level(logging.WARNING, logger="photorecon"):
        by_old = clean_cfg(old)
    assert [r.getMessage() for r in caplog.records] == [f"{old} is now {new} (the former name still works, for now)"]
    assert by_old.scene == "object" != CleanConfig().scene
    caplog.clear()
    assert clean_cfg(*new.split()) == by_old and not caplog.records  # the new name: no warning
    # as the boolean did, it wins over a --scene given too, wherever that stands
    assert clean_cfg(old, "--scene", "open").scene == clean_cfg("--scene", "open", old).scene == "object"
    with caplog.at_level(logging.WARNING, logger="photorecon"):  # --no-object: the default, nothing to set
        assert clean_cfg("--scene", "open", "--no-object").scene == "open"
    assert caplog.records[-1].getMessage() == ("--no-object is the default now and changes nothing "
                                               "(the setting is --scene)")
    full = parser.command_parser(command).format_help(full=True)
    assert f"{old} " not in full.replace(",", " ") and "--scene {auto,object,open}" in full


@pytest.mark.parametrize("text, scene, message", [
    ("object = true\n", "object", 'object = true is now scene = "object" (the former name still works, for now)'),
    ("[clean]\nobject = true\n", "object",
     '[clean] object = true is now [clean] scene = "object" (the former name still works, for now)'),
    ("object = false\n", "auto", "object = false is the default now and changes nothing (the setting is scene)"),
])
def test_the_former_object_settings_file_key_is_scene_object(parser, caplog, tmp_path, text, scene, message):
    from photorecon.cli.settings import apply_settings_file

    f, cfgs, messages = _reconstruct_with_settings_file(parser, caplog, tmp_path, text)
    assert cfgs.clean.scene == scene
    assert messages == [f"--config {f}: {message}"]
    f.write_text("object = 'yes'\n")
    with pytest.raises(BadArgumentError, match="object: expected true or false, got 'yes'"):
        apply_settings_file(parser.command_parser("reconstruct"), parser.parse_args(["reconstruct", "I", "-o", "O"]), f)


def _configs_of(args):
    from photorecon.cli.commands import stage_configs_from_args

    return stage_configs_from_args(args)


def test_a_former_flag_on_the_command_line_warns_in_one_line(tmp_path):
    """The command line: one line on stderr, before the command's own error (here: no image folder, exit 4);
    -q leaves it out."""
    import subprocess
    import sys

    argv = [sys.executable, "-m", "photorecon", "reconstruct", str(tmp_path / "none"), "-o", str(tmp_path / "o"),
            "--mvs", "sweep"]
    res = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    err = res.stderr.strip().splitlines()
    assert res.returncode == 4 and err[0] == "--mvs is now --method (the former name still works, for now)"
    assert len(err) == 2 and err[1].startswith("photorecon reconstruct: error:")
    res = subprocess.run(argv + ["-q"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 4 and len(res.stderr.strip().splitlines()) == 1


# --- tuning settings --------------------------------------------------------------------------------------

# the settings only benchmarks change (MVSConfig marks them metadata={"tuning": True})
TUNING = ("pm_reuse_cost", "pm_same_depth", "pm_same_normal_deg", "pm_carry_views", "pm_final_own_round",
          "pm_sigma_color", "geom_weight", "consistency_confidence", "textured_min_confidence", "pm_skip_consistent",
          "pm_fine_views", "pm_fine_refine")


def test_the_tuning_settings_are_the_marked_ones():
    import dataclasses

    from photorecon.depth.mvs import MVSConfig

    assert {f.name for f in dataclasses.fields(MVSConfig) if f.metadata.get("tuning")} == set(TUNING)


def test_tuning_settings_are_left_out_of_help_all_and_still_set(parser, tmp_path):
    from photorecon.cli.settings import apply_settings_file

    sp = parser.command_parser("reconstruct")
    full = sp.format_help(full=True)
    assert f"{len(TUNING)} tuning settings" in full and "docs/cli.md" in full
    for name in TUNING:
        assert f"--{name.replace('_', '-')}" not in full and f"--mvs.{name.replace('_', '-')} " not in full, name
    assert "--pm-iterations" in full and "--method" in full  # what a user sets stays
    # still set by a flag and by a settings file
    cfgs = _configs_of(parser.parse_args(["reconstruct", "I", "-o", "O", "--pm-sigma-color", "0.3"]))
    assert cfgs.mvs.pm_sigma_color == 0.3
    f = tmp_path / "s.toml"
    f.write_text("[mvs]\ngeom_weight = 0.5\npm_fine_views = 'current'\n")
    args = parser.parse_args(["reconstruct", "I", "-o", "O"])
    apply_settings_file(sp, args, f)
    cfgs = _configs_of(args)
    assert (cfgs.mvs.geom_weight, cfgs.mvs.pm_fine_views) == (0.5, "current")


def test_tuning_settings_are_documented_in_their_own_section():
    doc = (ROOT / "docs" / "cli.md").read_text()
    section = doc.split("## photorecon reconstruct\n", 1)[1].split("\n## ", 1)[0].split("### Tuning settings", 1)
    assert len(section) == 2, "no Tuning settings section for reconstruct"
    before, tuning = section
    for name in TUNING:
        listed = re.compile(rf"`--{name.replace('_', '-')}[ ,`]")
        assert listed.search(tuning) and not listed.search(before), name


def test_evaluation_is_callable_without_the_command_line():
    from photorecon.evaluate import EvalRequest, evaluate, format_report

    for req, what in ((EvalRequest(), "give --mesh and --gt"), (EvalRequest(mesh="m.ply"), "--mesh and --gt go"),
                      (EvalRequest(ref="r"), "--poses and --ref go together")):
        with pytest.raises(BadArgumentError, match=what):
            evaluate(req)
    text = format_report({"poses": {"registered": 3, "reference_count": 4, "rot_mean_deg": 0.1, "rot_median_deg": 0.1,
                                    "rot_max_deg": 0.2, "center_mean": 0.01, "center_median": 0.01,
                                    "center_max": 0.02, "center_mean_rel": 0.001}})
    assert text.splitlines()[0] == "poses: 3 of 4 reference images matched" and len(text.splitlines()) == 3
