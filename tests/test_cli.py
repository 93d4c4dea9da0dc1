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
