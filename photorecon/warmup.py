"""``photorecon warmup``: compile every numba kernel of the package once, on tiny inputs, so that numba's cache
(``cache=True``: files in the ``__pycache__`` folder next to each module, or ``NUMBA_CACHE_DIR``) holds them and
later processes load them in well under a second instead of compiling them (tens of seconds on two cores).

The kernels run through the same code paths as a reconstruction (PatchMatch MVS with its geometric filter and
the planar prior on a tiny synthetic scene, then weighted TSDF fusion of its depth maps and the photometric
refinement of that mesh; the hole filling's kernels on a hexagon; the seam levelling's rasteriser on a triangle),
so they are compiled for the argument types a real run passes; the PatchMatch kernel only the tests call
(``ncc_at``) runs on arrays of the same types. ``kernels()`` lists every compiled function
of the package: ``tests/test_warmup.py`` checks that ``warm_up`` reaches each one.
"""
from __future__ import annotations

import importlib
import pkgutil
import tempfile
import time
from pathlib import Path

import numpy as np


def kernels() -> dict[str, object]:
    """Every numba dispatcher (``@njit`` function) defined in the package, by qualified name
    (``photorecon.fusion.tsdf._tsdf_weighted_kernel``). Modules that fail to import (an optional dependency
    missing) are skipped."""
    from numba.core.dispatcher import Dispatcher

    import photorecon

    found: dict[str, object] = {}
    for info in pkgutil.walk_packages(photorecon.__path__, "photorecon."):
        if info.name.endswith("__main__"):
            continue
        try:
            mod = importlib.import_module(info.name)
        except Exception:  # pragma: no cover - an optional dependency missing
            continue
        for name, obj in vars(mod).items():
            if isinstance(obj, Dispatcher) and getattr(obj.py_func, "__module__", None) == mod.__name__:
                found[f"{mod.__name__}.{name}"] = obj
    return found


def entry_kernels(found: dict[str, object] | None = None) -> dict[str, object]:
    """The dispatchers that Python code calls: those no other compiled function of the package calls by name
    (a helper is compiled with, or inlined into, the kernels that call it, and has no cache entry of its own
    when they come from the cache)."""
    found = kernels() if found is None else found
    called = set()
    for d in found.values():
        called.update(d.py_func.__code__.co_names)
    return {k: d for k, d in found.items() if k.rsplit(".", 1)[1] not in called}


def _tiny_pm_calls() -> None:
    """``ncc_at`` (the tests' entry to the NCC) with the argument types of its callers."""
    from .depth.methods.patchmatch import kernels as K

    rng = np.random.default_rng(0)
    ref = rng.random((12, 14)).astype(np.float32)
    src = rng.random((12, 14)).astype(np.float32)
    sdy, sdx, sspat = K.window_samples(5, 2, 3.0)
    K.ncc_at(ref, src, 6, 6, np.eye(3).ravel(), sdy, sdx, sspat, 0.1, 1e-5)


def _tiny_hole_calls() -> None:
    """The hole filling's kernels (``mesh.patch``'s ear clipping, ``mesh.boundary``'s choice of notches) with the
    argument types of their callers."""
    from .mesh import boundary, patch

    t = np.linspace(0.0, 2 * np.pi, 7)[:-1]
    xy = np.stack([np.cos(t), np.sin(t)], 1)
    P = np.ascontiguousarray(np.hstack([xy, np.zeros((6, 1))]))
    patch._ear_clip(xy, P, np.zeros(0, np.int64))
    nrm = np.ascontiguousarray(np.tile([0.0, 0.0, 1.0], (6, 1)))
    boundary._pick_notches(P, nrm, np.array([0], np.int64), np.array([3], np.int64), 2.0, 0.5, 0.0)


def _tiny_texture_calls() -> None:
    """The seam levelling's rasteriser (``mesh.seams._raster``) with the argument types of its caller."""
    from .mesh import seams

    tri = np.array([[[0.0, 0.0], [3.0, 0.0], [0.0, 3.0]]])
    seams._raster(tri, np.ones((1, 3, 3), np.float32), 4, 4, np.zeros((4, 4, 3), np.float32), np.zeros((4, 4), bool))


def warm_up() -> dict:
    """Compile (or load from numba's cache) every kernel of the package. Returns the seconds, and the entry
    kernels (``entry_kernels``) compiled in this call and those loaded from the cache."""
    import logging

    from . import progress
    from .depth.mvs import MVS_PRESETS, MVSConfig, run_mvs
    from .fusion import FusionConfig, fuse, load_frames
    from .io.dataset import Dataset
    from .mesh.refine import RefineConfig, refine_dataset
    from .synthetic import SynthConfig, synthesize

    entries = entry_kernels()
    before = {k: len(d.signatures) for k, d in entries.items()}
    t0 = time.perf_counter()
    was = progress._enabled
    progress.set_enabled(False)
    level = logging.getLogger("photorecon").level
    logging.getLogger("photorecon").setLevel(logging.ERROR)
    try:
        with tempfile.TemporaryDirectory() as t:
            synthesize(SynthConfig(scene="blob", views=5, width=64, height=48, points=300), t, overwrite=True)
            ds = Dataset.open(t)
            # the demo's preset (geometric rounds, the multi-view filter), then the planar prior
            run_mvs(ds, Path(t) / "d", MVSConfig(**{**MVS_PRESETS["fast"], "n_sources": 2, "pm_iterations": 1}))
            run_mvs(ds, Path(t) / "p", MVSConfig(n_sources=2, pm_levels=2, pm_iterations=1, pm_fine_iterations=1,
                                                  pm_final_iterations=1, planar_prior=True, min_consistent=1))
            dsd = Dataset.open(t, depth_dir=Path(t) / "d")
            cfg = FusionConfig(voxels_across=64)
            mesh = fuse(load_frames(dsd, cfg), cfg, dsd.model.points)
            # the photometric refinement (--refine) of that mesh against the photos
            refine_dataset(mesh, ds, RefineConfig(refine=True, refine_levels=1, refine_iterations=2))
        _tiny_pm_calls()
        _tiny_hole_calls()
        _tiny_texture_calls()
    finally:
        logging.getLogger("photorecon").setLevel(level)
        progress.set_enabled(was)
    seconds = time.perf_counter() - t0
    compiled, cached = [], []
    for k, d in entries.items():
        hits = sum(d.stats.cache_hits.values()) if getattr(d, "_cache", None) is not None else 0
        misses = sum(d.stats.cache_misses.values()) if getattr(d, "_cache", None) is not None else 0
        new = len(d.signatures) > before[k]
        (cached if new and hits and not misses else compiled if new else cached).append(k)
    missing = [k for k, d in entries.items() if not d.signatures]
    return {"seconds": seconds, "kernels": len(entries), "compiled": sorted(compiled), "cached": sorted(cached),
            "missing": missing}
