"""The import direction over the whole package, read from the source with ``ast`` (imports at module level and
inside functions both count; imports under ``if TYPE_CHECKING:`` do not, they never run).

The top-level modules and packages of ``photorecon`` are in layers, top to bottom; a module imports from its
own layer or below, never above (docs/design.md, "Import direction"). ``UPWARD_ALLOWED`` lists the upward imports
that are known and not yet moved, each with its reason: a new one fails the test. Among the layers under the
composition (L2-L5) no two top-level packages import each other, directly or round a loop, except where an
allowed upward import makes the loop (``CYCLES_ALLOWED``)."""
from pathlib import Path

from conftest import module_parts, photorecon_imports

import photorecon

ROOT = Path(photorecon.__file__).parent

LAYERS = [
    ["cli"],  # L0 front
    ["pipeline", "presets", "evaluate", "demo", "warmup", "testing"],  # L1 composition
    ["poses", "depth", "fusion", "report", "synthetic", "metrics"],  # L2 stages
    ["mesh", "render"],  # L3 meshes and their rendering
    ["io", "layout", "stages", "tasks", "distributed", "results"],  # L4 infrastructure
    ["errors", "_validate", "config_checks", "fields", "cameras", "conventions", "arrays", "jit", "progress",
     "resources", "transform", "_disk"],  # L5 foundation (_disk: the stdlib-only disk-space helpers of errors.py)
]
LAYER = {name: i for i, names in enumerate(LAYERS) for name in names}
# the package's own entry points, above every layer: photorecon/__init__.py (its lazy public names) and __main__
ENTRY = {"__init__", "__main__"}

# (importing module, imported top-level name): why it is allowed
UPWARD_ALLOWED = {
    # texture() writes the textured mesh's preview.png with report/preview.py, which needs only render.py (L3),
    # io.images and cameras: it can move down to L3 beside render.py, and then this entry goes
    ("photorecon.mesh.texture", "report"): "the textured mesh's preview image (report.preview.render_preview)",
}
# top-level packages allowed in one import loop, because of the allowed upward imports above
CYCLES_ALLOWED = [
    {"mesh", "report", "render"},  # mesh.texture -> report.preview -> render / mesh (see UPWARD_ALLOWED)
]


def _top_names() -> set[str]:
    return {p.stem for p in ROOT.glob("*.py")} | {p.name for p in ROOT.iterdir() if (p / "__init__.py").exists()}


def _imports(path: Path) -> list[tuple[str, int]]:
    """The top-level photorecon names ``path`` imports (``from ..io.x import y``, ``from .. import fusion``,
    ``import photorecon.mesh``), with their line numbers."""
    found = []
    for mod, names, line in photorecon_imports(path, ROOT):
        # "from photorecon import x": x's module (a name of __init__, such as __version__, counts as __init__)
        found += [(n, line) for n in ([mod[1]] if len(mod) > 1 else names)]
    return found


def _edges() -> list[tuple[str, str, str, int]]:
    """(importing module, its top-level name, the imported top-level name, line) for every import between two
    different top-level names of the package."""
    tops = _top_names()
    out = []
    for path in sorted(ROOT.rglob("*.py")):
        parts = module_parts(path, ROOT)
        src = parts[1] if len(parts) > 1 else "__init__"
        for name, line in _imports(path):
            target = name if name in tops else "__init__"
            if target != src:
                out.append((".".join(parts), src, target, line))
    return out


def test_every_module_has_a_layer():
    assert _top_names() - ENTRY - set(LAYER) == set(), "put the new top-level module in a layer of LAYERS"
    assert not set(LAYER) - _top_names(), "LAYERS names a module that is gone"


def test_no_new_upward_import():
    upward, used = [], set()
    for module, src, target, line in _edges():
        if src in ENTRY or target in ENTRY:
            continue  # photorecon/__init__ sits above every layer; "from .. import __version__" is no layer
        if LAYER[target] < LAYER[src]:
            if (module, target) in UPWARD_ALLOWED:
                used.add((module, target))
            else:
                upward.append(f"{module}:{line} imports {target} (L{LAYER[src]} -> L{LAYER[target]})")
    assert not upward, "imports pointing up a layer (move the helper down, or allow it with a reason):\n" + \
        "\n".join(upward)
    gone = set(UPWARD_ALLOWED) - used
    assert not gone, f"allowed upward imports that are gone (remove them from UPWARD_ALLOWED): {gone}"


def test_no_import_cycles_among_the_lower_packages():
    graph: dict[str, set[str]] = {}
    for _, src, target, _ in _edges():
        if LAYER.get(src, 0) >= 2 and LAYER.get(target, 0) >= 2:
            graph.setdefault(src, set()).add(target)

    def reach(a):
        seen, todo = set(), [a]
        while todo:
            for b in graph.get(todo.pop(), ()):
                if b not in seen:
                    seen.add(b)
                    todo.append(b)
        return seen

    loops = {frozenset(b for b in reach(a) if a in reach(b)) for a in graph if a in reach(a)}
    bad = [sorted(loop) for loop in loops if not any(loop <= allowed for allowed in CYCLES_ALLOWED)]
    assert not bad, f"top-level packages importing each other: {bad}"
