"""The package layout: short module paths reach the same module objects as the stage packages, the public API
resolves from ``photorecon`` without loading the stages up front, and no module imports itself in a cycle."""
import importlib
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import photorecon

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("short, real", sorted(photorecon._ALIASES.items()))
def test_short_module_path_is_the_same_module(short, real, monkeypatch):
    alias = importlib.import_module(short)
    module = importlib.import_module(real)
    assert alias is module and alias.__name__ == real
    assert sys.modules[short] is module
    # a monkeypatch through the short path is seen through the real one
    name = next(n for n, v in vars(module).items() if callable(v) and getattr(v, "__module__", "") == real)
    marker = object()
    monkeypatch.setattr(f"{short}.{name}", marker)
    assert getattr(module, name) is marker


def test_from_photorecon_import_short_name():
    from photorecon import sfm, texture  # noqa: F401  (what an older script writes)

    assert sfm.__name__ == "photorecon.poses.sfm" and texture.__name__ == "photorecon.mesh.texture"


def test_public_api_attributes_resolve():
    for name, module in photorecon._LAZY.items():
        value = getattr(photorecon, name)
        owner = importlib.import_module(module)
        assert value is (owner if module.endswith("." + name) else getattr(owner, name)), name
    assert set(photorecon._LAZY) <= set(dir(photorecon))
    with pytest.raises(AttributeError):
        photorecon.no_such_name  # noqa: B018


def test_import_photorecon_loads_no_stage():
    """``import photorecon`` loads the camera model only: the stages and their heavy dependencies come with the
    first attribute that needs them."""
    code = ("import sys, photorecon; heavy = [m for m in ('photorecon.pipeline', 'photorecon.fusion', "
            "'photorecon.poses.sfm', 'open3d', 'trimesh', 'numba') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "[]", out.stdout


@pytest.mark.slow
def test_every_module_imports_alone():
    """Each module imported first in a fresh process: an import cycle between modules fails here."""
    names = [m.name for m in pkgutil.walk_packages(photorecon.__path__, "photorecon.")
             if not m.name.endswith("__main__")]
    code = ("import importlib, sys\nbad = []\nfor n in sys.argv[1:]:\n"
            "    for k in [k for k in sys.modules if k.startswith('photorecon')]: del sys.modules[k]\n"
            "    try: importlib.import_module(n)\n"
            "    except ImportError as e: bad.append(f'{n}: {e}')\nprint(bad)")
    out = subprocess.run([sys.executable, "-c", code, *names], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "[]", out.stdout
    assert len(names) > 40


def test_viewer_script_is_package_data():
    """The viewer is ``report/viewer.js``, read as package data and embedded whole into each page."""
    from importlib import resources

    from photorecon.report import viewer_html

    js = resources.files("photorecon.report").joinpath("viewer.js").read_text(encoding="utf-8")
    assert "getContext('webgl2'" in js and "prv-canvas" in js
    meta = {"faces": 1, "faces_full": 1, "cameras": 0}
    page = viewer_html({"meta": meta, "data": ""})
    assert f"<script>{js}</script>" in page
