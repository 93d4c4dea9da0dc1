#!/usr/bin/env python
"""Side by side in one process: PatchMatch settings (MVSConfig overrides) on the speed scene of
tools/bench_mvs.py (9 views of a textured blob ring, 8 sources each, true poses), with CPU seconds per view
(all threads of this process: what counts on a CPU shared with other work), wall seconds, per-round seconds,
fraction of the surviving depths within 1% of the truth and coverage of the true surface pixels.

    python tools/bench_pm_variants.py [--size 1600x1067] [--reps 1] [--json out.json] \
        'defaults' 'pm_final_iterations=0' 'pm_radius=4;pm_fine_refine=2'

Each variant is 'defaults' or ';'-separated NAME=VALUE settings of MVSConfig (or 'preset=NAME' for a
MVS_PRESETS entry). Variants run interleaved, ``--reps`` times, so a change in the load of a shared CPU hits
them alike; the scene is synthesized once into $TMPDIR/pm_variants_WxH.
"""
from __future__ import annotations

import argparse
import ast
import json
import sys
import tempfile
from pathlib import Path

from photorecon import progress
from photorecon.depth.mvs import MVS_PRESETS, MVSConfig
from photorecon.io.dataset import Dataset
from photorecon.synthetic import SynthConfig, synthesize

sys.path.insert(0, str(Path(__file__).parent))
from bench_mvs import run, warm_up  # noqa: E402


def scene_root(scene: str, W: int, H: int, views: int) -> Path:
    """The benchmark scene, synthesized once into $TMPDIR and reused: ``blob`` on a ring rig (the speed scene),
    or a named scene on the sphere rig (tools/bench_mvs.py's accuracy section)."""
    root = Path(tempfile.gettempdir()) / f"pm_variants_{scene}_{W}x{H}_{views}"
    if not (root / "scene.json").is_file():
        sc = (SynthConfig(scene="blob", rig="ring", views=views, width=W, height=H, elevation=15, points=4000)
              if scene == "blob" else SynthConfig(scene=scene, views=views, width=W, height=H, points=3000))
        synthesize(sc, root, overwrite=True)
    return root


def parse_variant(text: str) -> MVSConfig:
    if text == "defaults":
        return MVSConfig()
    kw: dict = {}
    for part in filter(None, text.split(";")):
        name, _, value = part.partition("=")
        name = name.strip()
        if name == "preset":
            kw.update(MVS_PRESETS[value.strip()])
            continue
        try:
            kw[name] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            kw[name] = value.strip()
    return MVSConfig(**kw)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="+")
    ap.add_argument("--size", default="1600x1067")
    ap.add_argument("--views", type=int, default=9)
    ap.add_argument("--scene", default="blob", help="blob (ring rig, the speed scene), or room / knot (sphere rig, as "
                    "tools/bench_mvs.py's accuracy section: --scene room --views 30 --size 512x384)")
    ap.add_argument("--no-masks", action="store_true", help="ignore the scene's masks (every pixel computed and kept)")
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--json")
    args = ap.parse_args()
    progress.set_enabled(False)
    W, H = (int(s) for s in args.size.split("x"))
    root = scene_root(args.scene, W, H, args.views)
    ds = Dataset.open(root)
    if args.no_masks:
        ds.masks_dir = root / "no_masks"  # an empty folder: no view has a mask
        assert ds.mask(ds.views[0]) is None
    n = len(ds.views)
    warm = warm_up()
    print(f"numba warm-up (compile, or load from the cache): {warm:.1f} s", flush=True)
    cfgs = [(v, parse_variant(v)) for v in args.variants]
    rows = []
    with tempfile.TemporaryDirectory() as t:
        for rep in range(args.reps):
            for label, cfg in cfgs:
                out = Path(t) / f"out{rep}_{len(rows)}"
                r = run(ds, root, out, cfg)
                row = {"variant": label, "rep": rep, "cpu_s_per_view": r["cpu_s_per_view"],
                       "wall_s_per_view": r["s_per_view"], "within_1pct": r["within_1pct"], "coverage": r["coverage"],
                       "round_s_per_view": r["round_s_per_view"]}
                rows.append(row)
                print(json.dumps(row), flush=True)
                if args.json:
                    Path(args.json).write_text(json.dumps({"warm_up_s": warm, "size": [W, H], "rows": rows}, indent=1))
    base = {r["rep"]: r["cpu_s_per_view"] for r in rows if r["variant"] == cfgs[0][0]}
    print(f"\n{args.scene}, {n} views {W}x{H}{', masks ignored' if args.no_masks else ''}; ratio = CPU s against the first variant of the same rep")
    print("| variant | CPU s/view | wall s/view | ratio | within 1% | coverage |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['variant']} | {r['cpu_s_per_view']:.1f} | {r['wall_s_per_view']:.1f} | "
              f"{r['cpu_s_per_view'] / base[r['rep']]:.2f} | {r['within_1pct']:.4f} | {r['coverage']:.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
