"""The layout of the fusion, mesh, metrics and poses packages: no import cycles among their modules
(function-level imports included; ``if TYPE_CHECKING:`` imports, which never run, left out), the foundation's
transform imported by the stages that need it, modules of at most 500 lines (the SfM modules 350), and the
public names of ``photorecon.metrics``, ``photorecon.mesh`` and ``photorecon.poses.sfm`` where users import
them. The import direction between the top-level packages: tests/test_layers.py."""
import ast
from pathlib import Path

import pytest

from conftest import module_parts, photorecon_imports

import photorecon

ROOT = Path(photorecon.__file__).parent
AREA = ["fusion", "mesh", "metrics"]
# structure from motion: run_sfm and one module per stage
SFM_MODULES = ["sfm", "_colmap", "extract", "match", "mapping", "undistort", "sfm_inputs", "retrieval"]


def _module(path: Path) -> str:
    return ".".join(module_parts(path, ROOT))


def _imports(path: Path) -> set[str]:
    """The photorecon modules ``path`` imports, anywhere in it (a function's imports too)."""
    out = set()
    for mod, names, _ in photorecon_imports(path, ROOT):
        name = ".".join(mod)
        out.add(name)
        out.update(f"{name}.{a}" for a in names)  # "from . import x": the module x
    return out


def _graph(area: list[str]) -> dict[str, set[str]]:
    files = [p for sub in area for p in (ROOT / sub).rglob("*.py")] + [ROOT / "transform.py"]
    mods = {_module(p): p for p in files}
    # a module's imports, each counted as the modules of the area it names (a package: its __init__)
    return {m: {i for i in _imports(p) if i in mods and i != m} for m, p in mods.items()}


def _assert_no_cycle(edges: dict[str, set[str]]) -> None:
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(m):
        state[m] = 1
        path.append(m)
        for d in sorted(edges.get(m, ())):
            if state.get(d) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path[path.index(d):] + [d]))
            if not state.get(d):
                visit(d)
        path.pop()
        state[m] = 2

    for m in sorted(edges):
        if not state.get(m):
            visit(m)


def test_no_import_cycles_in_fusion_mesh_metrics():
    graph = _graph(AREA)
    # a package's __init__ re-exports its modules: an edge into a package stands for its __init__ only, and an
    # __init__ importing its own modules is not a cycle with them, so leave those edges out
    edges = {m: {i for i in deps if not (m in {"photorecon.fusion", "photorecon.mesh", "photorecon.metrics"}
                                         and i.startswith(m + "."))} for m, deps in graph.items()}
    _assert_no_cycle(edges)


def test_no_import_cycles_in_poses():
    """The SfM stage modules take pycolmap from ``poses/_colmap.py``, never from ``sfm.py``, which imports them."""
    _assert_no_cycle(_graph(["poses"]))


def test_mesh_modules_do_not_import_clean_or_fusion():
    """The cleaning sits on the hole filling, never under it; mesh/ does not reach up into fusion/."""
    for p in (ROOT / "mesh").glob("*.py"):
        deps = _imports(p)
        if p.stem not in ("__init__", "clean", "texture", "model"):  # texture and model simplify the cleaned mesh
            assert "photorecon.mesh.clean" not in deps, p.name
        assert not any(d.startswith("photorecon.fusion") for d in deps), p.name


def test_scale_takes_umeyama_from_the_foundation():
    deps = _imports(ROOT / "poses" / "scale.py")
    assert "photorecon.transform" in deps and not any(d.startswith("photorecon.metrics") for d in deps)
    from photorecon import metrics, transform

    assert metrics.umeyama is transform.umeyama


@pytest.mark.parametrize("sub", AREA)
def test_modules_at_most_500_lines(sub):
    long = {p.name: n for p in (ROOT / sub).rglob("*.py") if (n := len(p.read_text().splitlines())) > 500}
    assert not long, long


# numba kernel files kept whole for numba's cache (cache=True checks only the source file of the kernel it
# loads); each one's docstring says so
WHOLE_KERNEL_FILES = {"depth/methods/patchmatch/kernels.py"}


def test_every_module_of_the_package_at_most_500_lines():
    long = {str(p.relative_to(ROOT)): n for p in ROOT.rglob("*.py") if (n := len(p.read_text().splitlines())) > 500}
    assert set(long) <= WHOLE_KERNEL_FILES, long
    for name in WHOLE_KERNEL_FILES:
        assert "numba's cache" in (ROOT / name).read_text().split('"""')[1], name


def test_sfm_modules_at_most_350_lines():
    long = {m: n for m in SFM_MODULES if (n := len((ROOT / "poses" / f"{m}.py").read_text().splitlines())) > 350}
    assert not long, long


def test_sfm_names_importable_where_they_are_imported():
    """Every name imported from ``photorecon.poses.sfm`` in the package, the tests, the tools and the docs."""
    import re

    from photorecon.poses import sfm

    names = set()
    for path in [*ROOT.rglob("*.py"), *(ROOT.parent / "tests").rglob("*.py"), *(ROOT.parent / "tools").glob("*.py")]:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("sfm") and (
                    node.module in ("photorecon.poses.sfm", "photorecon.sfm", "poses.sfm")
                    or (node.level and node.module == "sfm" and path.parent.name == "poses")):
                names.update(a.name for a in node.names)
    for doc in (ROOT.parent / "docs").rglob("*.md"):
        for found in re.findall(r"from photorecon(?:\.poses)?\.sfm import ([\w, ]+)", doc.read_text()):
            names.update(n.strip() for n in found.split(","))
    assert {"SfMConfig", "run_sfm", "extract", "match"} <= names
    missing = sorted(n for n in names if not hasattr(sfm, n))
    assert not missing, missing


def test_public_names_where_users_import_them():
    from photorecon import mesh, metrics

    for name in ("mesh_metrics", "cloud_metrics", "load_reference", "pose_metrics", "align_cameras", "depth_metrics",
                 "distance_to", "sample_surface", "covisible", "two_view_depth_scores", "disparity_scores",
                 "evaluate_reconstruction", "umeyama"):
        assert callable(getattr(metrics, name)), name
    for name in mesh.__all__:
        assert hasattr(mesh, name), name
