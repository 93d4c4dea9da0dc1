"""The command line's edge: every numeric flag has a declared range checked at parse time (exit 2, one line),
no traceback ever (an unexpected failure is one line and exit 10), SIGTERM like Ctrl-C (exit 143, nothing
incomplete kept, a re-run completes), quality presets, the short help and settings files."""
import argparse
import dataclasses
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from photorecon import cli
from photorecon.cli.config import Ranged, config_from_args, validate
from photorecon.cli.settings import apply_settings_file
from photorecon.errors import BadArgumentError

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def parser():
    return cli.build_parser()


@pytest.fixture
def fast_main(parser, monkeypatch):
    """``cli.main`` with the parser built once (building it is the slow part of a parse error)."""
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    return cli.main


def _commands(parser):
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


def _base_argv(cmd, sp, where="NOWHERE"):
    """The command with its positionals and required options filled with a path that does not exist."""
    argv = [cmd]
    for a in sp._actions:
        if a.option_strings and a.required:
            argv += [a.option_strings[0], str(Path(where) / a.dest)]
    return argv + [str(Path(where) / a.dest) for a in sp._actions if not a.option_strings]


def _numeric_actions(sp):
    for a in sp._actions:
        if not a.option_strings:
            continue
        t = a.type
        if t in (int, float) or isinstance(t, Ranged):
            yield a
        elif callable(t) and getattr(t, "__name__", "") in ("int", "float"):
            yield a


def _error_line(err: str, cmd: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"photorecon {cmd}: error: "), err
    assert "Traceback" not in err
    return lines[0]


def test_every_numeric_flag_declares_a_range(parser):
    """No numeric flag without a declared range, and every integer count has an upper bound (a huge value is
    refused too)."""
    seen = 0
    for cmd, sp in _commands(parser).items():
        for a in _numeric_actions(sp):
            assert isinstance(a.type, Ranged), f"{cmd} {a.option_strings}: no declared range"
            if a.type.kind is int:
                assert a.type.hi is not None, f"{cmd} {a.option_strings}: integer without an upper bound"
            seen += 1
    assert seen > 150  # every stage's settings on reconstruct, mvs, fuse, sfm ... and the plain flags


OUT_OF_RANGE = ["0", "-1", "-3", "1e12", "99999999999", "abc", "nan", "inf", "-inf", "", "1.5", "0x10"]


def _refused(rng: Ranged, text: str) -> bool:
    try:
        rng(text)
    except argparse.ArgumentTypeError:
        return True
    return False


def test_out_of_range_values_exit_2_with_one_line(fast_main, parser, capsys):
    """Every numeric flag of every command, fed 0, negative, huge, wrong-type, nan and inf values: whatever its
    range refuses exits 2 with one line naming the flag, before any work."""
    tried = 0
    for cmd, sp in _commands(parser).items():
        base = _base_argv(cmd, sp)
        for a in _numeric_actions(sp):
            flag = a.option_strings[0]
            refused = [v for v in OUT_OF_RANGE if _refused(a.type, v)]
            assert {"abc", "nan", "inf"} <= set(refused), (cmd, flag)
            if a.type.hi is not None:
                assert "1e12" in refused or a.type.kind is int, (cmd, flag)
                assert "99999999999" in refused, (cmd, flag)
            for v in refused:
                extra = [flag, v, "1"] if a.nargs == 2 else [f"{flag}={v}"]
                with pytest.raises(SystemExit) as e:
                    fast_main(base + extra)
                assert e.value.code == 2, (cmd, flag, v)
                line = _error_line(capsys.readouterr().err, cmd)
                assert flag in line and "expected" in line, line
                tried += 1
    assert tried > 1000


def test_values_in_range_are_accepted(parser):
    """The bounds themselves and the special values parse (a range that refused its own default would fail here)."""
    for cmd, sp in _commands(parser).items():
        base = _base_argv(cmd, sp)[1:]
        for a in _numeric_actions(sp):
            r = a.type
            lo = r.lo if r.lo is not None else -1e3
            hi = r.hi if r.hi is not None else 1e6
            if r.exclusive_min:
                lo = lo + min(1e-3, (hi - lo) / 2)
            candidates = [lo, hi, *r.also]
            if r.kind is int:
                candidates = [int(c) for c in candidates if float(c).is_integer()]
                if r.odd:
                    candidates = [c if c % 2 else c - 1 for c in candidates]
            for c in candidates:
                text = ",".join([str(c)] * r.length) if r.length else str(c)
                extra = [a.option_strings[0], text, text] if a.nargs == 2 else [f"{a.option_strings[0]}={text}"]
                ns = sp.parse_args(base + extra)
                got = getattr(ns, a.dest)
                got = got[0] if isinstance(got, (list, tuple)) else got
                assert got == pytest.approx(c), (cmd, a.option_strings, c)
            default = a.default
            if default is not None and not isinstance(default, (list, tuple)):
                assert r.check(default) is None, (cmd, a.option_strings, default)


@pytest.mark.parametrize("argv, flag", [
    (["reconstruct", "I", "-o", "O", "--max-image-size", "1"], "--max-image-size"),
    (["reconstruct", "I", "-o", "O", "--max-image-size", "-5"], "--max-image-size"),
    (["sfm", "I", "-o", "O", "--max-features", "0"], "--max-features"),
    (["sfm", "I", "-o", "O", "--threads", "-2"], "--threads"),
    (["fuse", "D", "-o", "O", "--trunc-voxels", "0"], "--trunc-voxels"),
    (["mvs", "D", "--max-size", "-1"], "--max-size"),
    (["mvs", "D", "--n-sources", "-3"], "--n-sources"),
    (["reconstruct", "I", "-o", "O", "--target-faces", "-5"], "--target-faces"),
    (["texture", "D", "--target-faces", "-5"], "--target-faces"),
    (["view", "R", "--port", "70000"], "--port"),
    (["eval", "--mesh", "a.ply", "--gt", "b.ply", "--tau", "0.1,-2"], "--tau"),
    (["convert", "a", "b", "--bounds", "-1", "2"], "--bounds"),
    (["reconstruct", "I", "-o", "O", "--mvs.window", "4"], "--mvs.window"),
    (["fuse", "D", "-o", "O", "--crop", "0,0,0,1,1"], "--crop"),
    (["reconstruct", "I", "-o", "O", "--cluster", "foo"], "--cluster"),
    (["mvs", "D", "--cluster", "local:0"], "--cluster"),
])
def test_reported_bad_values_are_refused_with_the_range(fast_main, capsys, argv, flag):
    with pytest.raises(SystemExit) as e:
        fast_main(argv)
    assert e.value.code == 2
    line = _error_line(capsys.readouterr().err, argv[0])
    assert flag in line and "expected" in line


def test_special_values_keep_their_meaning(parser):
    ns = parser.parse_args(["sfm", "I", "-o", "O", "--threads", "-1"])
    assert vars(ns)["sfm.threads"] == -1  # -1 = all cores
    ns = parser.parse_args(["mvs", "D", "--max-size", "0"])
    assert vars(ns)["mvs.max_size"] == 0  # 0 = full resolution


def test_validate_checks_configs_changed_after_they_were_built():
    from photorecon.depth.mvs import MVSConfig
    from photorecon.fusion import FusionConfig
    from photorecon.mesh import CleanConfig

    validate(MVSConfig())
    for cfg, name, value in ((MVSConfig(), "max_size", -1), (MVSConfig(), "n_sources", 0),
                             (MVSConfig(), "rel_depth", float("nan")), (FusionConfig(), "trunc_voxels", 0),
                             (CleanConfig(), "crop", (0, 0, 0, 1, -1, 1)), (CleanConfig(), "crop", (1, 2))):
        setattr(cfg, name, value)
        with pytest.raises(BadArgumentError, match=f"{type(cfg).__name__}.{name} .*expected"):
            validate(cfg)


def test_unexpected_failure_is_one_line_exit_10(fast_main, parser, monkeypatch, capsys):
    sp = _commands(parser)["convert"]

    def boom(args):
        raise RuntimeError("something broke\nwith a second line")

    monkeypatch.setitem(sp._defaults, "func", boom)
    assert fast_main(["convert", "a", "b"]) == 10
    line = _error_line(capsys.readouterr().err, "convert")
    assert "RuntimeError: something broke with a second line" in line and "run with -v for details" in line
    assert fast_main(["-v", "convert", "a", "b"]) == 10
    err = capsys.readouterr().err
    assert "Traceback" in err and err.strip().splitlines()[-1].endswith("(run with -v for details)")


def test_settings_resolve_in_order(parser, tmp_path):
    """Config default < preset < settings file < command line."""
    from photorecon.cli.options import _apply_quality
    from photorecon.presets import QUALITY_PRESETS
    from photorecon.depth.mvs import MVSConfig
    from photorecon.fusion import FusionConfig
    from photorecon.poses.sfm import SfMConfig

    sp = _commands(parser)["reconstruct"]

    def resolve(*extra, settings=None):
        args = parser.parse_args(["reconstruct", "I", "-o", "O", *extra])
        if settings is not None:
            f = tmp_path / "s.toml"
            f.write_text(settings)
            apply_settings_file(sp, args, f)
        _apply_quality(args)
        return config_from_args(MVSConfig, args), config_from_args(FusionConfig, args), config_from_args(SfMConfig, args)

    mvs, fusion, sfm = resolve()
    assert (mvs.max_size, mvs.n_sources, fusion.trunc_voxels) == (1600, 8, 3.0)  # the pipeline's TSDF truncation
    preview = QUALITY_PRESETS["preview"]
    mvs, fusion, sfm = resolve("--quality", "preview")
    assert mvs.max_size == preview["mvs.max_size"] < 1600 and mvs.n_sources == preview["mvs.n_sources"] < 8
    assert sfm.max_image_size == preview["sfm.max_image_size"] < 1600
    assert fusion.voxel_footprints == preview["fusion.voxel_footprints"] > FusionConfig().voxel_footprints
    mvs, _, _ = resolve("--quality", "high")
    assert mvs.max_size == QUALITY_PRESETS["high"]["mvs.max_size"] > 1600
    # an explicit flag (plain or prefixed) overrides the preset; the rest of the preset stays
    mvs, _, _ = resolve("--quality", "preview", "--max-size", "1200")
    assert (mvs.max_size, mvs.n_sources) == (1200, preview["mvs.n_sources"])
    mvs, _, _ = resolve("--quality", "preview", "--mvs.n-sources", "6")
    assert (mvs.max_size, mvs.n_sources) == (preview["mvs.max_size"], 6)
    # a settings file: over the preset, under the command line; its own quality counts
    mvs, fusion, _ = resolve("--quality", "preview", settings="[mvs]\nmax_size = 900\n[fusion]\ntrunc_voxels = 2.5\n")
    assert (mvs.max_size, mvs.n_sources, fusion.trunc_voxels) == (900, preview["mvs.n_sources"], 2.5)
    mvs, _, _ = resolve("--max-size", "1000", settings="quality = 'preview'\nmax_size = 900\n")
    assert (mvs.max_size, mvs.n_sources) == (1000, preview["mvs.n_sources"])
    # preview writes no watertight companion unless asked for one
    from photorecon.mesh import CleanConfig

    def clean_of(*extra):
        args = parser.parse_args(["reconstruct", "I", "-o", "O", *extra])
        _apply_quality(args)
        return config_from_args(CleanConfig, args)

    assert clean_of().closed == "auto" and clean_of("--quality", "preview").closed == "off"
    assert clean_of("--quality", "preview", "--closed", "auto").closed == "auto"


@pytest.mark.parametrize("text, what", [
    ("[mvs]\nmax_size = -1\n", "expected an integer"),
    ("[mvs]\nno_such_setting = 1\n", "no such setting"),
    ("[mvs]\nmax_size = 'big'\n", "expected an integer"),
    ("[mvs]\ngeom_consistency = 3\n", "expected true or false"),
    ("quality = 'best'\n", "expected one of"),
    ("[mvs\n", "not valid TOML"),
])
def test_bad_settings_file_is_one_line_exit_2(fast_main, parser, tmp_path, capsys, text, what):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    assert fast_main(["reconstruct", str(tmp_path / "none"), "-o", str(tmp_path / "o"), "--config", str(f)]) == 2
    line = _error_line(capsys.readouterr().err, "reconstruct")
    assert what in line and str(f) in line
    assert not (tmp_path / "o").exists()


def _help(fast_main, capsys, *argv):
    with pytest.raises(SystemExit) as e:
        fast_main(list(argv))
    assert e.value.code == 0
    return capsys.readouterr().out


def _options_listed(text: str) -> list[str]:
    return re.findall(r"^  (-[-\w.]+)", text, flags=re.M)


def test_short_help_shows_the_common_options(fast_main, parser, capsys):
    from photorecon.cli.config import config_prefix, field_flag, is_tuning
    from photorecon.pipeline import StageConfigs

    short = _help(fast_main, capsys, "reconstruct", "--help")
    listed = _options_listed(short)
    assert 12 <= len(listed) <= 25, listed
    for opt in ("-h", "-o", "--overwrite", "--quality", "--poses", "--masks", "--texture", "--help-all", "--force"):
        assert opt in listed, opt
    if "--scene" in _commands(parser)["reconstruct"]._option_string_actions:
        assert "--scene" in listed
    # one or two lines per option
    entries = re.split(r"\n(?=  -)", short.split("options:", 1)[1])
    for entry in entries:
        body = [ln for ln in entry.split("\n\n")[0].splitlines() if ln.strip() and not ln.endswith(":")]
        assert len(body) <= 3, entry  # the flags' line (when long) + at most two lines of text
    full = _help(fast_main, capsys, "reconstruct", "--help-all")
    # the model stage sets these texturing settings itself: --model-faces, --max-atlas (their former names: aliases)
    by_model = {("texture", "texture_faces"), ("texture", "atlas_size")}
    for cfg in vars(StageConfigs()).values():
        prefix = config_prefix(type(cfg))
        for f in dataclasses.fields(cfg):  # every setting a user sets; the tuning settings: docs/cli.md
            if (prefix, f.name) in by_model:
                assert f"--{prefix}.{field_flag(f)[2:]}" not in full, (prefix, f.name)
                continue
            assert (f"--{prefix}.{field_flag(f)[2:]}" in full) != is_tuning(prefix, f), (prefix, f.name)
    assert len(_options_listed(full)) > 100
    # every flag keeps working whether -h shows it or not
    ns = parser.parse_args(["reconstruct", "I", "-o", "O", "--pm-iterations", "3", "--fusion.weight-threshold", "2"])
    assert vars(ns)["mvs.pm_iterations"] == 3 and vars(ns)["fusion.weight_threshold"] == 2.0


@pytest.mark.parametrize("cmd", ["fuse", "mvs", "sfm"])
def test_other_long_commands_have_a_short_help(fast_main, capsys, cmd):
    short = _options_listed(_help(fast_main, capsys, cmd, "-h"))
    full = _options_listed(_help(fast_main, capsys, cmd, "--help-all"))
    assert len(short) <= 25 < len(full) and set(short) <= set(full)


def test_help_texts_say_what_not_what_was_measured(parser):
    """Help texts carry no measurement anecdotes: no 'a -> b' between numbers, F-scores, data set names."""
    bad = re.compile(r"\d\s*->\s*\d|F@|walnut|Strecha|entry-P10|Herz-Jesu|synthetic knot|measured|\bDTU\b|\bmm2\b", re.I)
    for cmd, sp in _commands(parser).items():
        for a in sp._actions:
            if a.help and a.help is not argparse.SUPPRESS:
                assert not bad.search(a.help), (cmd, a.option_strings, a.help)


# --- fuzz: random flag values and corrupted inputs --------------------------------------------------------------
POOL = ["0", "-1", "1", "2", "-7", "3.5", "1e9", "-1e-9", "nan", "inf", "abc", "", "1,2", "0x1f", "１", "None",
        "999999999999999999999", "-0", "1e-300", "7"]


def test_fuzz_flag_values_never_give_a_traceback(fast_main, parser, tmp_path, capsys):
    """Random numeric flags with random values on every command that needs an input (the inputs do not exist):
    each run fails at parse time or at the missing input, with one line and a nonzero code, never a traceback
    or an internal error."""
    rng = random.Random(24)
    cmds = {c: sp for c, sp in _commands(parser).items() if c not in ("synth", "demo", "warmup")}  # these need no input
    for i in range(300):
        cmd = rng.choice(sorted(cmds))
        sp = cmds[cmd]
        argv = _base_argv(cmd, sp, tmp_path / "missing")
        argv[1:] = [a.replace("/out", f"/out{i}") for a in argv[1:]]
        acts = list(_numeric_actions(sp))
        for a in rng.sample(acts, k=min(len(acts), rng.randint(1, 4))):
            v = rng.choice(POOL) if rng.random() < 0.6 else repr(rng.uniform(-10, 10) * 10 ** rng.randint(-3, 6))
            argv += [a.option_strings[-1], v, v] if a.nargs == 2 else [f"{a.option_strings[-1]}={v}"]
        try:
            code = fast_main(["-q"] + argv)
        except SystemExit as e:
            code = e.code
        err = capsys.readouterr().err
        assert code not in (0, None, 10), (argv, code, err)
        _error_line(err, cmd)
    assert not (tmp_path / "missing").exists()  # no output folder made for an input that is not there


def _run(*argv, timeout=120):
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="2")
    return subprocess.run([sys.executable, "-m", "photorecon", "-q", *map(str, argv)], capture_output=True,
                          text=True, timeout=timeout, env=env)


def _assert_clean_failure(res, cmd):
    """Nonzero, one line, no traceback, no native stack. (Exit 10, an unexpected failure, is one line too.)"""
    assert "Traceback" not in res.stderr and "*** " not in res.stderr and "@ 0x" not in res.stderr, res.stderr
    assert 0 < res.returncode < 128, (res.returncode, res.stderr)
    _error_line(res.stderr, cmd)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    from photorecon.synthetic import SynthConfig, synthesize

    root = tmp_path_factory.mktemp("tiny")
    synthesize(SynthConfig(scene="blob", views=4, width=64, height=48, points=300), root / "ds", overwrite=True)
    return root / "ds"


def _copy(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


@pytest.mark.slow
def test_fuzz_corrupted_inputs_fail_in_one_line(tiny, tmp_path):
    """Corrupted files (random bytes in an image and a mesh, a truncated transforms.json, garbage in
    cameras.txt and images.txt, a depth map of the wrong shape, garbage .npz / .npy camera files) fed to fuse,
    mvs, eval and convert: exit 3 (bad input data) with one line, no traceback and no native stack."""
    rnd = random.Random(25)
    garbage = lambda n: bytes(rnd.randrange(256) for _ in range(n))  # noqa: E731
    cases = []

    d = _copy(tiny, tmp_path / "png")
    next(iter(sorted((d / "images").glob("*.png")))).write_bytes(garbage(3000))
    cases.append(("mvs", [d, "-o", tmp_path / "o1", "--max-size", "64"]))

    d = _copy(tiny, tmp_path / "tjson")
    import shutil

    shutil.rmtree(d / "sparse")
    text = (d / "transforms.json").read_text()
    (d / "transforms.json").write_text(text[: len(text) // 2])
    cases += [("fuse", [d, "-o", tmp_path / "o2"]), ("convert", [d / "transforms.json", tmp_path / "c2"])]

    d = _copy(tiny, tmp_path / "cams")
    (d / "sparse" / "0" / "cameras.txt").write_bytes(b"# c\n1 PINHOLE 64 x 7 7\n" + garbage(200))
    (d / "transforms.json").unlink()
    cases += [("fuse", [d, "-o", tmp_path / "o3"]), ("mvs", [d]), ("convert", [d / "sparse" / "0", tmp_path / "c3.json"])]

    d = _copy(tiny, tmp_path / "imgs")
    p = d / "sparse" / "0" / "images.txt"
    p.write_text("\n".join(ln if i % 3 else ln.replace(" ", " x", 2) for i, ln in enumerate(p.read_text().splitlines())))
    (d / "transforms.json").unlink()
    cases.append(("fuse", [d, "-o", tmp_path / "o4"]))

    d = _copy(tiny, tmp_path / "depth")
    import numpy as np

    for f in (d / "depth").glob("*.npy"):
        if not f.name.count(".") > 1:
            np.save(f, np.ones((5, 7), np.float32))
    cases.append(("fuse", [d, "-o", tmp_path / "o5"]))

    bad_ply = tmp_path / "bad.ply"
    bad_ply.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n" + garbage(500))
    cases += [("eval", ["--mesh", bad_ply, "--gt", tiny / "gt_mesh.ply"]), ("eval", ["--mesh", tiny / "gt_mesh.ply", "--gt", bad_ply])]
    bad_npz, bad_npy = tmp_path / "cameras_sphere.npz", tmp_path / "poses_bounds.npy"
    bad_npz.write_bytes(garbage(400))
    bad_npy.write_bytes(b"\x93NUMPY" + garbage(300))
    cases += [("convert", [bad_npz, tmp_path / "c6"]), ("convert", [bad_npy, tmp_path / "c7"])]

    for cmd, argv in cases:
        res = _run(cmd, *argv)
        if os.environ.get("PHOTORECON_SHOW_FUZZ"):
            print(cmd, [str(a).replace(str(tmp_path), "") for a in argv], res.returncode, res.stderr.strip())
        _assert_clean_failure(res, cmd)
        assert res.returncode == 3, (cmd, res.stderr)  # an input file's fault, not an unexpected failure (10)
    assert not list(tmp_path.rglob("*.partial"))


@pytest.mark.slow
def test_sigterm_is_like_ctrl_c_and_the_run_resumes(blob_small, tmp_path):
    """``kill -TERM`` during the depth stage: the interrupted line, exit 143, no native stack, no partial folder
    left; the same command again completes."""
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "photorecon", "-q", "reconstruct", str(blob_small / "images"), "-o", str(out),
            "--poses", str(blob_small / "transforms.json"), "--n-sources", "4", "--min-consistent", "1"]
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="2")
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 120
    while not (out / ".depth.partial").exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before the depth stage started"
    time.sleep(1.0)  # well inside the depth work
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert err.strip().splitlines() == ["photorecon reconstruct: interrupted; incomplete outputs were not kept"], err
    assert not list(out.rglob("*.partial")) and not list(out.rglob(".*.partial"))
    assert not (out / ".stages" / "depth.json").exists()
    res = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr
    assert (out / "mesh.ply").is_file()


@pytest.mark.slow
def test_stdout_closed_by_its_reader_is_a_quiet_exit_141(tiny):
    """``photorecon eval ... | head -1``: the reader goes away before the report is printed; no error line
    about a broken pipe, exit 141 (as a shell reports a process ended by SIGPIPE)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="2")
    gt = str(tiny / "gt_mesh.ply")
    proc = subprocess.Popen([sys.executable, "-m", "photorecon", "eval", "--mesh", gt, "--gt", gt],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    proc.stdout.close()  # before the metrics are computed and printed
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141, err
    assert err.strip() == "", err


@pytest.mark.slow
def test_quiet_success_writes_nothing_to_stderr(blob_small, tmp_path):
    """``-q`` means errors only: a fresh process that runs PatchMatch, and another that fuses its depth maps
    (their normals make the tangent-plane test the first parallel kernel), print their one summary line on
    stdout and nothing on stderr (no library's notes either)."""
    depth = tmp_path / "depth"
    fuse = ("fuse", blob_small, "--depth-dir", depth, "-o", tmp_path / "fused")
    for argv in (("mvs", blob_small, "-o", depth), fuse):
        res = _run(*argv, timeout=300)
        assert res.returncode == 0, res.stderr
        assert res.stderr == "", (argv[0], res.stderr)
        assert res.stdout.startswith(argv[0] + ":"), res.stdout
    assert any(depth.glob("*.normal.npy"))
