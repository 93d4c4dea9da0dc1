#!/usr/bin/env python
"""PatchMatch's work counted, not timed: NCC evaluations per computed pixel, per round (pyramid level) and
iteration, on the real captures of tools/bench_real.py (or the speed scene of tools/bench_mvs.py), beside the
depth stage's CPU seconds per view and per megapixel-source and, with --score, the fused mesh's scores.

    python tools/bench_pm_counts.py [--only walnut1,herz,speed] [--set NAME=VALUE ...] [--score] [--json out.json]

Counts do not depend on the load of a shared machine; with the cost of one evaluation (``--ncc-ns``, measured
by ``tools/bench_ncc.py``) they give the CPU seconds the evaluations alone need on one core.
"""
from __future__ import annotations

import argparse
import ast
import json
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from photorecon import progress  # noqa: E402
from photorecon.depth import mvs  # noqa: E402
from photorecon.depth.methods.patchmatch import solver as patchmatch  # noqa: E402
from photorecon.depth.mvs import MVSConfig  # noqa: E402
from photorecon.io.dataset import Dataset  # noqa: E402

ROUNDS: dict = defaultdict(lambda: {"calls": 0, "initial": 0, "iterations": []})
STATE = {"round": None}


def instrument() -> None:
    """Count every ``patchmatch_view`` call's work, keyed by (round, level, size)."""
    orig_view, orig_round = patchmatch.patchmatch_view, patchmatch.pm_view_round

    def pm_view_round(job, r, by_name, image, params, *a, **kw):
        lvl = patchmatch.pm_rounds(params.cfg)[r][0]
        STATE["round"] = (r, lvl)
        return orig_round(job, r, by_name, image, params, *a, **kw)

    def patchmatch_view(ref_img, *a, **kw):
        c: dict = {}
        out = orig_view(ref_img, *a, counts=c, **kw)
        r, lvl = STATE["round"]
        acc = ROUNDS[(r, lvl, f"{ref_img.shape[1]}x{ref_img.shape[0]}")]
        acc["calls"] += 1
        acc["initial"] += c.get("initial", 0)
        for i, w in enumerate(c.get("iterations", [])):
            if len(acc["iterations"]) <= i:
                acc["iterations"].append(defaultdict(int))
            for k, v in w.items():
                acc["iterations"][i][k] += v
        return out

    patchmatch.pm_view_round = pm_view_round
    patchmatch.patchmatch_view = patchmatch_view


def table(n_sources: int, ncc_ns: float | None) -> tuple[list[dict], int]:
    rows, total = [], 0
    for (r, lvl, size), acc in sorted(ROUNDS.items()):
        for i, w in enumerate(acc["iterations"]):
            px = max(w["pixels"], 1)
            ev = w["candidate_evals"] + w["refine_evals"]
            total += ev
            rows.append({"round": r, "level": lvl, "size": size, "iteration": i, "pixels_per_view": w["pixels"] // acc["calls"],
                         "skipped": round(w["skipped"] / px, 3),
                         "candidate_evals_per_px": round(w["candidate_evals"] / px, 1),
                         "refine_evals_per_px": round(w["refine_evals"] / px, 1),
                         "evals_per_px": round(ev / px, 1), "evals_per_px_source": round(ev / px / n_sources, 2),
                         "evals_per_view_M": round(ev / acc["calls"] / 1e6, 2)})
        total += acc["initial"]
    return rows, total


def main() -> int:
    from bench_real import DATA, SETS, run_one, warm_up

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="walnut1,herz", help="comma-separated: speed, " + ", ".join(SETS))
    ap.add_argument("--data", default=str(DATA))
    ap.add_argument("--out", default=str(Path(tempfile.gettempdir()) / "bench_pm_counts"))
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="an MVSConfig setting (repeatable)")
    ap.add_argument("--score", action="store_true", help="fuse, clean and score the result (bench_real.run_one)")
    ap.add_argument("--ncc-ns", type=float, default=None, help="one NCC evaluation's cost, ns (tools/bench_ncc.py)")
    ap.add_argument("--profile", action="store_true",
                    help="also CPU seconds per view of each kernel call and of the work around them (tools/bench_pm_profile.py)")
    ap.add_argument("--json")
    args = ap.parse_args()
    progress.set_enabled(False)
    over = {}
    for item in args.set:
        name, _, value = item.partition("=")
        try:
            over[name.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):  # a word: a choice such as pm_fine_views=current
            over[name.strip()] = value.strip()
    cfg = MVSConfig(**over)
    warm = warm_up()
    if args.profile:
        import bench_pm_profile

        bench_pm_profile.instrument()
    instrument()
    results = []
    for name in args.only.split(","):
        ROUNDS.clear()
        if args.profile:
            bench_pm_profile.ACC.clear()
        if name == "speed":
            from bench_pm_variants import scene_root

            root = scene_root("blob", 1600, 1067, 9)
        else:
            root = Path(args.data) / SETS[name]
        c0 = time.process_time()
        row: dict = {}
        if args.score and name != "speed":
            import bench_real

            spent = {}
            orig = bench_real.run_mvs

            def timed_mvs(*a, **kw):
                t = time.process_time()
                try:
                    return orig(*a, **kw)
                finally:
                    spent["cpu"] = time.process_time() - t

            bench_real.run_mvs = timed_mvs
            row = run_one(name, root, Path(args.out), cfg)
            bench_real.run_mvs = orig
            depth_cpu = spent["cpu"]
        else:
            ds = Dataset.open(root)
            rep = mvs.run_mvs(ds, Path(args.out) / name / "depth", cfg)
            depth_cpu = time.process_time() - c0
            row = {"views": rep["views"], "size": rep["per_view"][next(iter(rep["per_view"]))]["size"],
                   "triangulation_s": rep.get("triangulation_seconds"),
                   "report_cpu_s_per_view": rep.get("cpu_seconds_per_view"),
                   "report_cpu_s_per_mp_source": rep.get("cpu_seconds_per_mp_source")}
            if name == "speed":
                from bench_mvs import scores

                row["within_1pct"], row["coverage"] = scores(ds, Path(args.out) / name / "depth", root)
        cpu = time.process_time() - c0
        rows, total = table(cfg.n_sources, args.ncc_ns)
        views = row.get("views") or row.get("depth_maps")
        size = row["size"]
        w, h = size if isinstance(size, (list, tuple)) else (int(s) for s in str(size).split("x"))
        mps = views * cfg.n_sources * w * h / 1e6
        res = {"dataset": name, "config": over, "cpu_s": round(cpu, 1),
               "depth_cpu_s": None if depth_cpu is None else round(depth_cpu, 1),
               "depth_cpu_s_per_view": None if depth_cpu is None else round(depth_cpu / views, 2),
               "depth_cpu_s_per_mp_source": None if depth_cpu is None else round(depth_cpu / mps, 3),
               "ncc_evals_M": round(total / 1e6, 1), "ncc_evals_per_mp_source_M": round(total / mps / 1e6, 2),
               "warm_up_s": round(warm, 1), **{k: v for k, v in row.items() if not isinstance(v, (dict, list))}, "rounds": rows}
        if args.ncc_ns:
            res["ncc_floor_cpu_s"] = round(total * args.ncc_ns * 1e-9, 1)
        if args.profile:
            res["profile_cpu_s_per_view"] = {k: round(v[0] / views, 3) for k, v in sorted(bench_pm_profile.ACC.items())}
        results.append(res)
        print(json.dumps({k: v for k, v in res.items() if k != "rounds"}), flush=True)
        cols = list(rows[0]) if rows else []
        print("| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
        for r in rows:
            print("| " + " | ".join(str(r[c]) for c in cols) + " |")
        if args.profile:
            print("| part | CPU s per view | share of the depth stage |\n|---|---|---|")
            for k, v in res["profile_cpu_s_per_view"].items():
                print(f"| {k} | {v:.2f} | {v * views / max(depth_cpu, 1e-9):.1%} |")
        if args.json:
            Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
