import subprocess
import sys

from photorecon import __version__
from photorecon.cli import main


def test_version_and_help(capsys):
    out = subprocess.run([sys.executable, "-m", "photorecon", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == f"photorecon {__version__}"
    assert __version__ != "0.0.0+unknown"
    assert main([]) == 0
    assert "COMMAND" in capsys.readouterr().out


def test_stage_configs_may_share_a_setting_name():
    """Two stage configs with the same field (``threads``) on one command: the plain flag goes to the first
    config added, ``--PREFIX.NAME`` reaches each on its own, and --help does not crash (it did with one
    shared argparse namespace)."""
    import argparse
    import dataclasses

    from photorecon.cli.config import add_config_arguments, config_from_args

    @dataclasses.dataclass
    class AlphaConfig:
        threads: int = 1
        only_alpha: float = 0.5

    @dataclasses.dataclass
    class BetaConfig:
        threads: int = 2

    p = argparse.ArgumentParser(prog="x")
    add_config_arguments(p.add_argument_group("alpha"), AlphaConfig)
    add_config_arguments(p.add_argument_group("beta"), BetaConfig)
    assert "--beta.threads" in p.format_help()
    a = p.parse_args(["--threads", "3", "--beta.threads", "7", "--alpha.only-alpha", "0.25"])
    assert config_from_args(AlphaConfig, a) == AlphaConfig(threads=3, only_alpha=0.25)
    assert config_from_args(BetaConfig, a) == BetaConfig(threads=7)
    d = p.parse_args([])
    assert (config_from_args(AlphaConfig, d).threads, config_from_args(BetaConfig, d).threads) == (1, 2)


def test_prefixed_flags_are_aliases_of_the_documented_ones():
    from photorecon.cli import build_parser

    p = build_parser()
    a = p.parse_args(["reconstruct", "IMG", "-o", "OUT", "--mvs.max-size", "800", "--fusion.trunc-voxels", "3"])
    b = p.parse_args(["reconstruct", "IMG", "-o", "OUT", "--max-size", "800", "--trunc-voxels", "3"])
    assert vars(a)["mvs.max_size"] == vars(b)["mvs.max_size"] == 800
    assert vars(a)["fusion.trunc_voxels"] == vars(b)["fusion.trunc_voxels"] == 3.0


def test_unwritable_output_is_one_line_and_exit_8(tmp_path, capsys):
    """An output folder that cannot be created (a regular file is in its path) fails with the output error's
    exit code and one line naming the folder, not a traceback."""
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a folder")
    code = main(["synth", "-o", str(blocker / "out"), "--scene", "blob", "--views", "2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 8
    assert len(err) == 1 and str(blocker / "out") in err[0] and "Traceback" not in err[0]


def test_os_errors_are_named_and_classed(tmp_path):
    import errno

    from photorecon.errors import InputDataError, OutputError, from_os_error

    e = from_os_error(PermissionError(errno.EACCES, "Permission denied", str(tmp_path / "out" / "mesh.ply")),
                      out=tmp_path / "out")
    assert isinstance(e, OutputError) and "mesh.ply" in str(e)
    e = from_os_error(FileNotFoundError(errno.ENOENT, "No such file", "/data/img.png"), out=tmp_path / "out")
    assert isinstance(e, InputDataError) and "/data/img.png" in str(e)
    assert isinstance(from_os_error(OSError(errno.ENOSPC, "No space left on device", "/tmp/x"), None), OutputError)
    # numpy's short write on a full disk (no errno, no file name): the output folder and "no space"
    e = from_os_error(OSError("7632075 requested and 5242816 written"), out=tmp_path / "out")
    assert isinstance(e, OutputError) and "no space left" in str(e) and str(tmp_path / "out") in str(e)
