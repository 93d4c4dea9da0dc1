#!/usr/bin/env python
"""Numerical stability of the result: the defaults (``photorecon reconstruct IMAGES --poses sparse/0``, no flags)
on walnut captures under perturbations that should not change the result, and the spread of F@0.5 / F@1 mm.

Perturbations (each a whole ``reconstruct`` in its own process and output folder):

* ``baseline``: as it is;
* ``nofastmath``: every numba kernel compiled without fastmath (``PHOTORECON_FASTMATH=0``, see
  ``photorecon/jit.py``; its kernels cached in a folder of their own under --out, never mixed with the default's);
* ``threads1``: one numba thread (``NUMBA_NUM_THREADS=1``) instead of one per core;
* ``lsb``: the lowest bit of every pixel's grey (or colour) value flipped, on a copy of the images in --out (the
  alpha channel, the mask, as it is; the shared data is never written).

Each result is scored like ``tools/bench_real.py`` (``cloud_metrics`` against ``reference.ply``, result samples more
than 5 mm outside the reference's box left out). Prints one row per capture and perturbation (F@0.5mm, F@1mm,
faces, what ``--scene auto`` detected) and, per capture, the spread (max - min) of each F over the perturbations.

    python tools/bench_stability.py [--only walnut4,walnut1] [--perturb baseline,lsb] [--out bench_stability]
        [--json stability.json] [--data ../shared/data] [--refuse]

--refuse: keep each run's poses and depth maps from an earlier bench_stability run in --out and redo only the
fusion stage and what follows (the fusion and cleaning code changed, the depth did not): the same environment
per perturbation, so the fusion kernel is compiled the same way as in the full run.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "../shared/data"
SETS = {
    "walnut1": "walnuts/2016_10_24__17_43_02",
    "walnut2": "walnuts/2016_10_25__12_57_06",
    "walnut3": "walnuts/2016_10_24__17_44_40",
    "walnut4": "walnuts/2016_10_25__12_10_52",  # the dark one
}
PERTURBATIONS = ("baseline", "nofastmath", "threads1", "lsb")
TAUS = (0.0005, 0.001, 0.002)


def flip_lowest_bit(src: Path, dst: Path) -> int:
    """Copy every image of ``src`` to ``dst`` with the lowest bit of each grey / colour value flipped (an alpha
    channel, the mask, copied as it is); other files copied unchanged. Returns the number of images."""
    from PIL import Image

    dst.mkdir(parents=True, exist_ok=True)
    n = 0
    for p in sorted(src.iterdir()):
        if not p.is_file():
            continue
        try:
            im = Image.open(p)
            im.load()
        except OSError:
            shutil.copy2(p, dst / p.name)
            continue
        a = np.asarray(im)
        if a.dtype != np.uint8 or im.mode not in ("L", "LA", "RGB", "RGBA"):
            raise SystemExit(f"{p}: mode {im.mode} ({a.dtype}): only 8-bit grey or colour images can be flipped")
        a = a.copy()
        colour = a.shape[-1] - 1 if im.mode in ("LA", "RGBA") else (a.shape[-1] if a.ndim == 3 else None)
        if colour is None:
            a ^= 1
        else:
            a[..., :colour] ^= 1
        Image.fromarray(a, im.mode).save(dst / (p.stem + ".png"))
        n += 1
    return n


def environment(perturbation: str, out: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PHOTORECON_FASTMATH", "NUMBA_NUM_THREADS")}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    if perturbation == "nofastmath":
        env["PHOTORECON_FASTMATH"] = "0"
        env["NUMBA_CACHE_DIR"] = str((out / "numba-cache").resolve())  # jit.py adds /photorecon-nofastmath
    elif perturbation == "threads1":
        env["NUMBA_NUM_THREADS"] = "1"
    return env


def reconstruct(name: str, root: Path, out: Path, perturbation: str, refuse: bool) -> dict:
    """One ``reconstruct --poses`` of capture ``root`` under ``perturbation`` into ``out/name/perturbation``
    (removed first unless ``refuse``); returns its CPU seconds and report."""
    work = out / name / perturbation
    images = root / "images"
    if refuse:
        if not (work / ".stages" / "depth.json").is_file():
            raise SystemExit(f"{work}: no depth stage of an earlier run to reuse; run without --refuse first")
        for stage in ("fusion", "preview", "model"):
            (work / ".stages" / f"{stage}.json").unlink(missing_ok=True)
    elif work.exists():
        shutil.rmtree(work)
    if perturbation == "lsb":
        images = out / name / "images_lsb"
        if not images.is_dir() or not any(images.iterdir()):
            flip_lowest_bit(root / "images", images)
    cmd = [sys.executable, "-m", "photorecon", "reconstruct", str(images), "--poses", str(root / "sparse" / "0"),
           "-o", str(work), "-q", "--formats", "ply"]
    t0 = time.perf_counter()
    r0 = os.times()
    p = subprocess.run(cmd, env=environment(perturbation, out), capture_output=True, text=True)
    r1 = os.times()
    if p.returncode != 0:
        raise SystemExit(f"{name} {perturbation}: reconstruct failed (exit {p.returncode}): {p.stderr.strip()[-2000:]}")
    report = json.loads((work / "report.json").read_text()) if (work / "report.json").is_file() else {}
    return {"work": work, "wall_s": time.perf_counter() - t0,
            "cpu_s": (r1.children_user - r0.children_user) + (r1.children_system - r0.children_system),
            "report": report}


def score(name: str, perturbation: str, run: dict, reference: np.ndarray) -> dict:
    from photorecon.mesh import load_mesh
    from photorecon.metrics import cloud_metrics

    mesh = load_mesh(run["work"] / "mesh.ply")
    m = cloud_metrics(mesh, reference, TAUS, crop_margin=0.005)
    row = {"capture": name, "perturbation": perturbation, "faces": len(mesh.faces),
           "cpu_s": round(run["cpu_s"], 1), "wall_s": round(run["wall_s"], 1)}
    for s in m.thresholds:
        row[f"F@{s.tau * 1000:g}mm"] = s.fscore
        row[f"acc@{s.tau * 1000:g}mm"] = s.precision
        row[f"comp@{s.tau * 1000:g}mm"] = s.recall
    scene = (run["report"].get("mesh") or {}).get("scene") or {}  # the decision, not the --scene setting
    row["scene"] = scene.get("detected")
    row["framed"] = scene.get("framed")
    return row


def spreads(rows: list[dict]) -> list[dict]:
    out = []
    for name in dict.fromkeys(r["capture"] for r in rows):
        mine = [r for r in rows if r["capture"] == name]
        s = {"capture": name, "runs": len(mine)}
        for k in ("F@0.5mm", "F@1mm"):
            v = [r[k] for r in mine]
            s[k] = max(v) - min(v)
        out.append(s)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(SETS), help="comma-separated captures: " + ", ".join(SETS))
    ap.add_argument("--perturb", default=",".join(PERTURBATIONS),
                    help="comma-separated perturbations: " + ", ".join(PERTURBATIONS))
    ap.add_argument("--out", default="bench_stability", help="work folder (the runs, the flipped images, a numba cache)")
    ap.add_argument("--json", help="write the rows and spreads as JSON here")
    ap.add_argument("--data", default=str(DATA), help="the shared data folder (default: ../shared/data)")
    ap.add_argument("--refuse", action="store_true",
                    help="reuse each run's depth maps from an earlier run in --out; redo fusion and cleaning only")
    args = ap.parse_args()
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    perts = [p.strip() for p in args.perturb.split(",") if p.strip()]
    for n in names:
        if n not in SETS:
            ap.error(f"--only: unknown capture {n!r}; expected some of {', '.join(SETS)}")
    for p in perts:
        if p not in PERTURBATIONS:
            ap.error(f"--perturb: unknown perturbation {p!r}; expected some of {', '.join(PERTURBATIONS)}")
    from photorecon.metrics import load_reference

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in names:
        root = Path(args.data) / SETS[name]
        if not (root / "images").is_dir():
            print(f"{name}: {root} not found, skipped", file=sys.stderr)
            continue
        reference = load_reference(root / "reference.ply")
        for pert in perts:
            row = score(name, pert, reconstruct(name, root, out, pert, args.refuse), reference)
            rows.append(row)
            print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}), flush=True)
            if args.json:
                Path(args.json).write_text(json.dumps({"rows": rows, "spread": spreads(rows)}, indent=1))
    cols = ["capture", "perturbation", "F@0.5mm", "F@1mm", "faces", "scene", "cpu_s"]
    print("\n| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(f"{r[c]:.4f}" if isinstance(r.get(c), float) and c.startswith("F@") else str(r.get(c, ""))
                                for c in cols) + " |")
    print("\n| capture | runs | spread F@0.5mm | spread F@1mm |\n|---|---|---|---|")
    for s in spreads(rows):
        print(f"| {s['capture']} | {s['runs']} | {s['F@0.5mm']:.4f} | {s['F@1mm']:.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
