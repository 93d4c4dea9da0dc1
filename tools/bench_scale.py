#!/usr/bin/env python
"""Benchmark of photorecon on large unordered photo sets: per stage wall and CPU seconds, peak memory, image
pairs matched (against n(n-1)/2), photos registered and pose errors after Sim3 alignment to the reference
cameras; end to end (``--e2e``) also depth views and faces.

Sets (``--only`` picks some, comma-separated):

* ``gold_cape``: ../shared/data/gold_cape (or $PHOTORECON_DATA/gold_cape), 119 real handheld photos (unordered), reference cameras in
  ``reference/`` (COLMAP text);
* ``unorderedN`` (``unordered100``, ``unordered200``, ``unordered500``; any N): N views of the synthetic blob
  on a sphere at 640x480 (``--size``), 3 degrees of rotation jitter, saved under shuffled file names
  (``photo_NNNN.png``: file order says nothing of the capture) with no GPS; rendered once into ``--data``.

Each set runs ``photorecon sfm`` (or ``photorecon reconstruct`` with ``--e2e``) as a child process with the
defaults plus ``--args`` (e.g. ``--args="--matching exhaustive"``), output under ``--work``. ``--poses
reference`` gives ``photorecon reconstruct`` the set's reference cameras (``--poses``: no SfM; implies ``--e2e``);
``--poses FOLDER`` gives it those of a COLMAP model (with sparse points: the depth stage then triangulates nothing).

``--baseline COMMIT_OR_PATH`` then runs the same command with another version's code on the same set (output
under ``--work``/baseline) and prints per stage both CPU seconds and current/baseline, the end-to-end wall and
CPU ratios and, end to end, how much of each mesh lies near the other (``OUT/mesh.ply``: fraction of one's
surface samples within 0.5% of the baseline mesh's bounding-box diagonal of the other; from photos, each mesh is first
moved into the reference cameras' world by the Sim3 that aligns its run's cameras to them). The baseline is a folder
with ``.venv/bin/photorecon`` (a git worktree with its own venv), or a commit: its worktree
``/tmp/photorecon-baseline-SHA12`` and venv are made once and reused. Each side runs its own
``photorecon`` executable (this side: this repository's ``.venv/bin/photorecon``, else the one beside
``sys.executable``). ``tools/bench_ncc.py`` runs once first: its ns per NCC evaluation, a gauge of the CPU's
speed at the time, heads the tables.

    python tools/bench_scale.py --only unordered100,unordered200 [--args "..."] [--json out.json] [--e2e]
    python tools/bench_scale.py --only gold_cape --poses reference --baseline 0053fc9
"""
from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("PHOTORECON_DATA", ROOT / "../shared/data"))  # the shared benchmark data
GOLD_CAPE = DATA / "gold_cape"
DEFAULT_SETS = "gold_cape,unordered100,unordered200,unordered500"


def unordered_set(n: int, size: str, data: Path) -> tuple[Path, list]:
    """``n`` sphere views of the blob under shuffled names in ``data/unorderedN/photos``; the reference views
    (named like the photos)."""
    from photorecon.io.dataset import read_model
    from photorecon.synthetic import SynthConfig, synthesize

    w, h = (int(x) for x in size.lower().split("x"))
    root = data / f"unordered{n}_{w}x{h}"
    synth, photos = root / "synth", root / "photos"
    if not (root / "names.json").is_file():
        if not (synth / "sparse" / "0").is_dir():  # rendered before: kept
            synthesize(SynthConfig(scene="blob", rig="sphere", views=n, width=w, height=h, points=0, seed=3,
                                   jitter_deg=3.0), synth, overwrite=True)
        perm = np.random.default_rng(n).permutation(n)
        names = {}
        shutil.rmtree(photos, ignore_errors=True)
        photos.mkdir(parents=True)
        for v, p in zip(read_model(synth / "sparse" / "0").views, perm):
            names[v.name] = f"photo_{p:04d}"
            shutil.copyfile(synth / "images" / v.image_file, photos / f"{names[v.name]}.png")
        (root / "names.json").write_text(json.dumps(names))
    names = json.loads((root / "names.json").read_text())
    ref = read_model(synth / "sparse" / "0").views
    for v in ref:
        v.name = names[v.name]
    return photos, ref


def unordered_reference(photos: Path) -> Path:
    """The synthetic set's reference cameras as a COLMAP text model named like its photos (for ``--poses``):
    ``photos/../reference``, written once."""
    root = photos.parent
    ref = root / "reference"
    if not (ref / "images.txt").is_file():
        names = json.loads((root / "names.json").read_text())
        src = root / "synth" / "sparse" / "0"
        tmp = root / "reference.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        for f in ("cameras.txt", "points3D.txt"):
            shutil.copyfile(src / f, tmp / f)
        lines = []
        for line in (src / "images.txt").read_text().splitlines():
            tok = line.split()
            if not line.startswith("#") and len(tok) == 10:  # IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME
                stem, ext = os.path.splitext(tok[9])
                line = " ".join(tok[:9] + [names[stem] + ext])
            lines.append(line)
        (tmp / "images.txt").write_text("\n".join(lines) + "\n")
        shutil.rmtree(ref, ignore_errors=True)
        tmp.rename(ref)
    return ref


def gold_cape_set() -> tuple[Path, list]:
    from photorecon.io.dataset import read_model

    return GOLD_CAPE / "images", read_model(GOLD_CAPE / "reference").views


def current_exe() -> Path:
    """This repository's ``photorecon``: ``.venv/bin/photorecon``, else the one in ``sys.executable``'s venv."""
    exe = ROOT / ".venv" / "bin" / "photorecon"
    return exe if exe.is_file() else Path(sys.executable).parent / "photorecon"


def baseline_tree(spec: str) -> Path:
    """The baseline's source tree: ``spec`` itself when it is a folder with ``.venv/bin/photorecon``, else
    ``/tmp/photorecon-baseline-SHA12``, a git worktree of commit ``spec`` with its venv (made once, reused)."""
    p = Path(spec).expanduser()
    if p.is_dir():
        if (p / ".venv" / "bin" / "photorecon").is_file():
            return p.resolve()
        raise SystemExit(f"--baseline: {p} has no .venv/bin/photorecon")
    rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--verify", "--quiet", spec + "^{commit}"],
                         capture_output=True, text=True)
    if rev.returncode:
        raise SystemExit(f"--baseline: {spec!r} is neither a folder with .venv/bin/photorecon nor a commit")
    sha = rev.stdout.strip()
    tree = Path(f"/tmp/photorecon-baseline-{sha[:12]}")
    if (tree / ".venv" / "bin" / "photorecon").is_file():
        return tree
    if not tree.is_dir():
        print(f"baseline: git worktree add {tree} {sha[:12]}", flush=True)
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), sha], check=True)
    print(f"baseline: its venv in {tree}/.venv (pip install -e ., photorecon warmup)", flush=True)
    subprocess.run(["python3", "-m", "venv", ".venv"], cwd=tree, check=True)
    subprocess.run([".venv/bin/pip", "install", "-q", "-e", "."], cwd=tree, check=True)
    subprocess.run([".venv/bin/photorecon", "warmup"], cwd=tree, check=True)
    return tree


def ncc_ns() -> dict:
    """``tools/bench_ncc.py``'s ns per NCC evaluation (short setting), ``{"grid": ns, "checkerboard": ns}``."""
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "bench_ncc.py"), "--evals", "300000"],
                          capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    out = {}
    for line in proc.stdout.splitlines():
        m = re.match(r"(grid|checkerboard)\b.*?_ncc ([\d.]+) ns per evaluation", line)
        if m:
            out[m.group(1)] = float(m.group(2))
    if proc.returncode or not out:
        print(f"tools/bench_ncc.py failed: {(proc.stderr.strip().splitlines() or ['?'])[-1]}", flush=True)
    return out


def database_pairs(db: Path) -> tuple[int, int]:
    """(image pairs matched, image pairs verified) in a COLMAP database: every pair tried has a row of matches,
    empty where none were found."""
    import sqlite3

    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        matched = con.execute("SELECT COUNT(*) FROM matches").fetchone()[0]
        verified = con.execute("SELECT COUNT(*) FROM two_view_geometries WHERE rows > 0").fetchone()[0]
    finally:
        con.close()
    return matched, verified


def run_set(name: str, photos: Path, ref: list, out: Path, args: list[str], e2e: bool,
            exe: Path | None = None, tree: Path = ROOT, poses: Path | None = None) -> dict:
    """One run of ``exe`` (default: this repository's ``photorecon``) from source tree ``tree`` on the set."""
    from photorecon.io.dataset import read_model
    from photorecon.metrics import pose_metrics

    shutil.rmtree(out, ignore_errors=True)
    e2e = e2e or poses is not None
    cmd = [str(exe or current_exe()), "-q", "reconstruct" if e2e else "sfm", str(photos), "-o", str(out),
           *(["--poses", str(poses)] if poses is not None else []), *args]
    # the side's own sources first: never the other side's
    inherited = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and Path(p).resolve() != ROOT]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), *inherited]))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    n = len(ref)
    row = {"set": name, "photos": n, "args": " ".join(args), "mode": "e2e" if e2e else "sfm", "rc": proc.returncode,
           "code": str(tree), "poses": str(poses) if poses is not None else None,
           "wall_s": round(wall, 1), "cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 1),
           "all_pairs": n * (n - 1) // 2}
    if proc.returncode:
        row["error"] = (proc.stderr.strip().splitlines() or ["?"])[-1]
    work = out / "colmap"
    stages = {}
    for f in sorted((work / ".stages").glob("*.json")):
        stages[f.stem] = stage_record(f)
    row["stages"] = stages
    # the pipeline's stages (end to end; "poses" holds the SfM stages above)
    row["pipeline_stages"] = {f.stem: stage_record(f) for f in sorted((out / ".stages").glob("*.json"))} if e2e else {}
    row["peak_mb"] = max((s["peak_mb"] for s in [*stages.values(), *row["pipeline_stages"].values()]
                          if s["peak_mb"] is not None), default=None)  # the largest stage's peak
    if (work / "sfm_report.json").is_file():
        rep = json.loads((work / "sfm_report.json").read_text())
        row["matching"], row["registered"] = rep["matching"], len(rep["registered"])
    if (work / "database.db").is_file():
        row["pairs_matched"], row["pairs_verified"] = database_pairs(work / "database.db")
        row["pairs_per_photo"] = round(row["pairs_matched"] / n, 1)
    if (out / "sparse" / "0").is_dir():
        m = pose_metrics(read_model(out / "sparse" / "0").views, ref)
        row.update(registered=m["registered"], rot_mean_deg=round(m["rot_mean_deg"], 3),
                   rot_max_deg=round(m["rot_max_deg"], 3), center_mean_rel_pct=round(100 * m["center_mean_rel"], 3),
                   missing=m["missing"][:10])
    if e2e and (out / "report.json").is_file():
        rep = json.loads((out / "report.json").read_text())
        row["depth_views"] = rep.get("depth", {}).get("views")
        row["faces"] = rep.get("mesh", {}).get("faces")
        row["stage_seconds"] = {k: round(v.get("seconds", 0), 1) for k, v in rep.get("stages", {}).items()
                                if isinstance(v, dict)}
    return row


def stage_record(f: Path) -> dict:
    """A stage marker's wall seconds, peak MB and CPU seconds (None where the version that wrote it did not)."""
    try:
        s = json.loads(f.read_text())
    except (OSError, ValueError):
        s = {}

    def num(key, nd):
        v = s.get(key)
        return round(v, nd) if isinstance(v, (int, float)) else None

    return {"s": num("seconds", 1), "peak_mb": num("peak_mb", 0), "cpu_s": num("cpu_seconds", 1)}


def _fmt(v, nd: int = 1) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def _ratio(a, b) -> str:
    return f"{a / b:.2f}" if isinstance(a, (int, float)) and isinstance(b, (int, float)) and b > 0 else "-"


def compare(cur: dict, base: dict) -> dict:
    """Per stage CPU seconds of both sides and their ratio; end-to-end wall and CPU ratios."""
    stages = {}
    for group, prefix in (("stages", "sfm:"), ("pipeline_stages", "")):
        for k in list(cur.get(group, {})) + [k for k in base.get(group, {}) if k not in cur.get(group, {})]:
            c, b = cur.get(group, {}).get(k, {}), base.get(group, {}).get(k, {})
            stages[prefix + k] = {"cpu_s": c.get("cpu_s"), "base_cpu_s": b.get("cpu_s"),
                                  "cpu_ratio": _ratio(c.get("cpu_s"), b.get("cpu_s")),
                                  "s": c.get("s"), "base_s": b.get("s"), "wall_ratio": _ratio(c.get("s"), b.get("s"))}
    return {"stages": stages, "wall_ratio": _ratio(cur.get("wall_s"), base.get("wall_s")),
            "cpu_ratio": _ratio(cur.get("cpu_s"), base.get("cpu_s"))}


def compare_meshes(cur_out: Path, base_out: Path, n: int = 200_000, ref: list | None = None) -> dict:
    """How much of each ``mesh.ply`` lies within 0.5% of the baseline mesh's bounding-box diagonal of the other:
    ``base_near_cur`` (fraction of the baseline's surface samples near the current mesh) and ``cur_near_base``.
    ``ref``: the set's reference cameras; each mesh is first moved into their world with the Sim3 that aligns its
    own output's cameras (``sparse/0``) to them, as two SfM runs each choose their own frame and scale."""
    import trimesh

    from photorecon.io.dataset import read_model
    from photorecon.metrics import mesh_metrics
    from photorecon.metrics.poses import align_by_cameras

    paths = [cur_out / "mesh.ply", base_out / "mesh.ply"]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        return {"error": "no " + ", ".join(missing)}
    cur, base = (trimesh.load(p, force="mesh", process=False) for p in paths)
    if ref is not None:
        cur, base = (align_by_cameras(m, read_model(out / "sparse" / "0").views, ref)[0]
                     for m, out in ((cur, cur_out), (base, base_out)))
    diag = float(np.linalg.norm(base.bounds[1] - base.bounds[0]))
    tau = 0.005 * diag
    try:
        m = mesh_metrics(cur, base, tau=tau, n_samples=n)
    except Exception as exc:  # an empty mesh: said in the table, the benchmark goes on
        return {"error": f"{type(exc).__name__}: {exc}"}
    return {"tau": round(tau, 6), "diagonal": round(diag, 6), "samples": n, "faces": len(cur.faces),
            "base_faces": len(base.faces), "base_near_cur": round(m.recall, 4), "cur_near_base": round(m.precision, 4)}


def compare_table(cur: dict, base: dict, cmp: dict) -> str:
    lines = [f"{cur['set']}: current {cur.get('code')} vs baseline {base.get('code')}",
             f"    {'stage':26}  {'cpu_s':>8}  {'base cpu_s':>10}  {'cpu ratio':>9}  {'wall_s':>8}  "
             f"{'base wall_s':>11}"]
    for k, v in cmp["stages"].items():
        lines.append(f"    {k:26}  {_fmt(v['cpu_s']):>8}  {_fmt(v['base_cpu_s']):>10}  {v['cpu_ratio']:>9}  "
                     f"{_fmt(v['s']):>8}  {_fmt(v['base_s']):>11}")
    lines.append(f"    {'end to end (child)':26}  {_fmt(cur.get('cpu_s')):>8}  {_fmt(base.get('cpu_s')):>10}  "
                 f"{cmp['cpu_ratio']:>9}  {_fmt(cur.get('wall_s')):>8}  {_fmt(base.get('wall_s')):>11}  "
                 f"(wall ratio {cmp['wall_ratio']})")
    mc = cmp.get("mesh")
    if mc:
        lines.append(f"    mesh: {mc['error']}" if "error" in mc else
                     f"    mesh: {100 * mc['base_near_cur']:.1f}% of the baseline's surface within {mc['tau']:.4g} "
                     f"(0.5% of diagonal {mc['diagonal']:.4g}) of the current mesh, {100 * mc['cur_near_base']:.1f}% "
                     f"of the current's within it of the baseline ({mc['faces']} vs {mc['base_faces']} faces)")
    return "\n".join(lines)


def table(rows: list[dict]) -> str:
    cols = [("set", 20), ("matching", 10), ("args", 22), ("photos", 6), ("registered", 10), ("pairs_matched", 13),
            ("pairs_per_photo", 15), ("rot_mean_deg", 12), ("center_mean_rel_pct", 19), ("wall_s", 8), ("cpu_s", 8),
            ("peak_mb", 8), ("depth_views", 11), ("faces", 9)]
    lines = ["  ".join(c.ljust(w) for c, w in cols)]
    for r in rows:
        r = {**r, "set": r["set"] + (" (base)" if r.get("baseline") else "")}
        lines.append("  ".join(str(r.get(c, "-") if r.get(c) is not None else "-")[:w].ljust(w) for c, w in cols))
        stages = {**r.get("stages", {}), **r.get("pipeline_stages", {})}
        lines.append("    stages: " + ", ".join(f"{k} {_fmt(v['s'])} s / {_fmt(v['cpu_s'])} CPU s / "
                                              f"{_fmt(v['peak_mb'], 0)} MB" for k, v in stages.items())
                     + (f"; error: {r['error']}" if r.get("error") else ""))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default=DEFAULT_SETS, help=f"sets, comma-separated (default: {DEFAULT_SETS})")
    ap.add_argument("--args", default="", help="extra photorecon options, one string")
    ap.add_argument("--e2e", action="store_true", help="photorecon reconstruct instead of photorecon sfm")
    ap.add_argument("--size", default="640x480", help="synthetic image size (default: 640x480)")
    ap.add_argument("--data", type=Path, default=Path("/tmp/photorecon-bench-scale/data"), help="synthetic sets, made once")
    ap.add_argument("--work", type=Path, default=Path("/tmp/photorecon-bench-scale/out"), help="outputs")
    ap.add_argument("--json", type=Path, help="also write the results here: {ncc_ns, rows, comparisons}")
    ap.add_argument("--poses", metavar="reference|FOLDER", help="reference: photorecon reconstruct --poses with the "
                    "set's reference cameras instead of SfM; FOLDER: those cameras (a COLMAP model, e.g. the reference "
                    "cameras with their triangulated points, so that neither side triangulates); implies --e2e")
    ap.add_argument("--baseline", metavar="COMMIT_OR_PATH", help="also run each set with this version's code (a "
                    "commit, or a worktree with .venv/bin/photorecon) and compare")
    a = ap.parse_args()
    args = shlex.split(a.args)
    base_tree = baseline_tree(a.baseline) if a.baseline else None
    ncc = ncc_ns()
    head = "bench_ncc: " + (", ".join(f"{k} {v:.1f} ns per evaluation" for k, v in ncc.items()) or "-")
    print(head, flush=True)
    rows, comparisons, pairs = [], [], []

    def save():
        if a.json:
            a.json.write_text(json.dumps({"ncc_ns": ncc, "rows": rows, "comparisons": comparisons}, indent=1))

    for name in a.only.split(","):
        if name == "gold_cape":
            if not GOLD_CAPE.is_dir():
                print(f"gold_cape: {GOLD_CAPE} not found, skipped")
                continue
            photos, ref = gold_cape_set()
            poses = (GOLD_CAPE / "reference" if a.poses == "reference" else Path(a.poses)) if a.poses else None
        elif name.startswith("unordered") and name[9:].isdigit():
            photos, ref = unordered_set(int(name[9:]), a.size, a.data)
            poses = (unordered_reference(photos) if a.poses == "reference" else Path(a.poses)) if a.poses else None
        else:
            raise SystemExit(f"--only: unknown set {name!r} (gold_cape or unorderedN)")
        rows.append(run_set(name, photos, ref, a.work / name, args, a.e2e, poses=poses))
        print(table(rows[-1:]), flush=True)
        save()
        if base_tree is not None:
            base = run_set(name, photos, ref, a.work / "baseline" / name, args, a.e2e,
                           exe=base_tree / ".venv" / "bin" / "photorecon", tree=base_tree, poses=poses)
            base["baseline"] = True
            rows.append(base)
            cmp = {"set": name, **compare(rows[-2], base)}
            if a.e2e or poses is not None:
                cmp["mesh"] = compare_meshes(a.work / name, a.work / "baseline" / name,
                                             ref=ref if poses is None else None)
            comparisons.append(cmp)
            pairs.append((rows[-2], base, cmp))
            print(table(rows[-1:]), flush=True)
            print(compare_table(rows[-2], base, cmp), flush=True)
            save()
    print()
    print(head)
    print(table(rows))
    for cur, base, cmp in pairs:
        print(compare_table(cur, base, cmp))


if __name__ == "__main__":
    main()
