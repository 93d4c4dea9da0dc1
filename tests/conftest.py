"""Shared fixtures: small synthetic datasets rendered once per test session (no ../shared data)."""
import ast
import hashlib
import os

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "2")

from photorecon.testing import synth_scene  # noqa: E402  (after the thread setting: it imports numpy)


def tree_hash(folder):
    """SHA-256 over a folder's relative paths and file bytes: 'unchanged byte for byte'."""
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        h.update(str(p.relative_to(folder)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


def module_parts(path, root):
    """The dotted name of the module at ``path`` as a list (``photorecon/io/__init__.py``: ["photorecon", "io"]);
    ``root``: the package folder (``photorecon``)."""
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    return parts[:-1] if parts[-1] == "__init__" else parts


def _runtime_nodes(tree):
    """Every node of ``tree`` except the bodies of ``if TYPE_CHECKING:`` blocks (they never run)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                stack.extend(child.orelse)
            else:
                stack.append(child)


def photorecon_imports(path, root):
    """The imports of package modules in the source file ``path``, at module level and inside functions: per
    import (the imported module as a list of names, the names a ``from`` import takes from it, line);
    relative imports resolved against ``root`` (the package folder)."""
    parts = module_parts(path, root)
    pkg = parts if path.name == "__init__.py" else parts[:-1]
    found = []
    for node in _runtime_nodes(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = pkg[:len(pkg) - node.level + 1] if node.level else []
            mod = base + (node.module.split(".") if node.module else [])
            if mod and mod[0] == root.name:
                found.append((mod, [a.name for a in node.names], node.lineno))
        elif isinstance(node, ast.Import):
            found += [(a.name.split("."), [], node.lineno) for a in node.names
                      if a.name.split(".")[0] == root.name]
    return found


def coarse_maps(renderer, views, wrong: float = 0.03, background=None, relative: bool = False,
                background_cost: float = 1.0, normals: bool = False, seed: int = 0, level: int = 2) -> dict:
    """Per view a depth map as PatchMatch's coarsest round gives it (at pyramid ``level``: a quarter of the
    resolution), view name ->
    (view at that level, depth, camera-frame normal, cost). The rendered z-depth with 0.3% noise, a fraction
    ``wrong`` of the surface's pixels at a random depth (0.5-2x; matched well all the same) at cost 0.2; off the
    surface depth 0, or uniform in ``background`` (times the view's median surface depth when ``relative``), at
    cost ``background_cost``; the true normals with ``normals``, else zero."""
    import numpy as np

    from photorecon.depth.methods.patchmatch.solver import level_view

    rng = np.random.default_rng(seed)
    maps = {}
    for v in views:
        lv = level_view(v, level)
        r = renderer.render(lv)
        d = (r.depth * (1 + 0.003 * rng.standard_normal(r.depth.shape))).astype(np.float32)
        bad = r.mask & (rng.random(r.depth.shape) < wrong)
        d[bad] = rng.uniform(0.5, 2.0, bad.sum()) * d[bad]
        if background is not None:
            scale = float(np.median(r.depth[r.mask])) if relative else 1.0
            d[~r.mask] = rng.uniform(background[0] * scale, background[1] * scale, (~r.mask).sum())
        n = (r.normal @ lv.cam_from_world[:3, :3].T).astype(np.float32) if normals else np.zeros(d.shape + (3,), np.float32)
        maps[v.name] = (lv, d, n, np.where(r.mask, 0.2, background_cost).astype(np.float32))
    return maps


@pytest.fixture(autouse=True, scope="session")
def _quiet_progress():
    from photorecon import progress

    progress.set_enabled(False)


@pytest.fixture(scope="session")
def blob_small(tmp_path_factory):
    """12 sphere views of the blob at 160x120."""
    return synth_scene(tmp_path_factory, "blob_small", scene="blob", views=12, width=160, height=120,
                       points=1500, seed=3)


@pytest.fixture(scope="session")
def blob_fusion(tmp_path_factory):
    """24 sphere views of the blob at 320x240, for fusion accuracy."""
    return synth_scene(tmp_path_factory, "blob_fusion", scene="blob", views=24, width=320, height=240,
                       points=2000, seed=1)


@pytest.fixture(scope="session")
def ring16(tmp_path_factory):
    """16 ring views of the blob at 320x240: enough overlap for SfM."""
    return synth_scene(tmp_path_factory, "ring16", scene="blob", rig="ring", views=16, width=320, height=240,
                       points=800, seed=5)


@pytest.fixture(scope="session")
def sphere30(tmp_path_factory):
    """30 sphere views of the blob at 320x240: all-round coverage for end-to-end reconstruction."""
    return synth_scene(tmp_path_factory, "sphere30", scene="blob", views=30, width=320, height=240, points=800)
