#!/usr/bin/env python
"""Where PatchMatch's time goes: CPU seconds per view of each kernel call, by round (pyramid level) and
iteration, and of the work around them (images, masks, saving and loading the rounds' maps, the consistency
filter), on the speed scene of tools/bench_pm_variants.py (9 views of a textured blob ring, 8 sources each).

    python tools/bench_pm_profile.py [--size 1600x1067] [--set NAME=VALUE ...] [--json out.json]

CPU seconds (``time.process_time``: all threads of this process) are what counts on a CPU shared with other
work; the numba kernels are warmed up (and their cache loaded) first, and that warm-up is reported apart.
"""
from __future__ import annotations

import argparse
import functools
import json
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from photorecon import progress
from photorecon.depth import _filter_kernel, graph, mvs, work  # noqa: E402
from photorecon.depth.methods.patchmatch import kernels as _pm_kernels, solver as patchmatch  # noqa: E402
from photorecon.io.dataset import Dataset

sys.path.insert(0, str(Path(__file__).parent))
from bench_pm_variants import parse_variant, scene_root  # noqa: E402
from bench_mvs import scores, warm_up  # noqa: E402

ACC: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0, 0])  # key -> [cpu s, wall s, calls]
STATE = {"round": "-"}


def _timed(key_fn, fn):
    @functools.wraps(fn)
    def wrapper(*a, **kw):
        c0, t0 = time.process_time(), time.perf_counter()
        try:
            return fn(*a, **kw)
        finally:
            acc = ACC[key_fn(*a, **kw)]
            acc[0] += time.process_time() - c0
            acc[1] += time.perf_counter() - t0
            acc[2] += 1
    return wrapper


def instrument() -> None:
    k = _pm_kernels
    k.pm_pass = _timed(lambda color, it, *a: f"{STATE['round']} pm_pass it{it}", k.pm_pass)
    k.initial_cost = _timed(lambda *a: f"{STATE['round']} initial_cost", k.initial_cost)
    k.init_random = _timed(lambda *a: f"{STATE['round']} init_random", k.init_random)
    k.upsample_planes = _timed(lambda *a: f"{STATE['round']} upsample_planes", k.upsample_planes)
    _filter_kernel.consistency_source = _timed(lambda *a: "filter: consistency_source", _filter_kernel.consistency_source)
    orig_round = patchmatch.pm_view_round

    def pm_view_round(job, r, *a, **kw):
        lvl = patchmatch.pm_rounds(a[2].cfg)[r][0]
        STATE["round"] = f"round {r} (level {lvl})"
        return _timed(lambda *_a, **_k: f"{STATE['round']} total", orig_round)(job, r, *a, **kw)

    patchmatch.pm_view_round = pm_view_round
    work.save = _timed(lambda *a: "io: save (np.save, atomic)", work.save)
    work.load = _timed(lambda *a: "io: load", work.load)
    work.level_image = _timed(lambda *a: "io: grey images (read, resize)", work.level_image)
    work.level_mask = _timed(lambda *a: "io: masks", work.level_mask)
    graph.write_depth = _timed(lambda *a: "io: write_depth (filter's output)", graph.write_depth)
    mvs.run_task = _timed(lambda ctx, kind, *a: f"task {kind}", mvs.run_task)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1600x1067")
    ap.add_argument("--set", default="defaults", help="a variant as in bench_pm_variants.py ('defaults' or 'a=1;b=2')")
    ap.add_argument("--json")
    args = ap.parse_args()
    progress.set_enabled(False)
    W, H = (int(s) for s in args.size.split("x"))
    root = scene_root("blob", W, H, 9)
    ds = Dataset.open(root)
    n = len(ds.views)
    warm = warm_up()
    instrument()
    cfg = parse_variant(args.set)
    with tempfile.TemporaryDirectory() as t:
        c0, t0 = time.process_time(), time.perf_counter()
        mvs.run_mvs(ds, Path(t) / "out", cfg)
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
        w, c = scores(ds, Path(t) / "out", root)
    print(f"numba warm-up {warm:.1f} s; {n} views {W}x{H}, {args.set}: {cpu / n:.2f} CPU s/view, {wall / n:.2f} wall s/view, "
          f"within 1% {w:.4f}, coverage {c:.4f}")
    print("| part | CPU s/view | share | wall s/view | calls |\n|---|---|---|---|---|")
    for key in sorted(ACC):
        cs, ws, calls = ACC[key]
        print(f"| {key} | {cs / n:.2f} | {cs / cpu:.1%} | {ws / n:.2f} | {calls} |")
    if args.json:
        Path(args.json).write_text(json.dumps({"warm_up_s": warm, "cpu_s_per_view": cpu / n, "wall_s_per_view": wall / n,
                                               "within_1pct": w, "coverage": c,
                                               "parts": {k: {"cpu_s_per_view": v[0] / n, "wall_s_per_view": v[1] / n,
                                                             "calls": v[2]} for k, v in ACC.items()}}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
