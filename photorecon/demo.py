"""``photorecon demo``: synthesize a textured scene, reconstruct it from its images alone (SfM poses,
weight-free MVS depth, TSDF fusion) as a real capture would be, and measure the result against the truth.

``photorecon demo --scene bunny``: the original article's experiment. The Stanford bunny (shipped in
``photorecon/data``) is rendered from a ring of cameras, and its rendered depth maps (the article took the
rasterizer's z-buffer) with the true cameras are meshed three ways side by side: the article's per-view grid
meshes concatenated, photorecon's fused surface (TSDF) and the watertight surface (screened Poisson,
``--watertight``). Each is measured against the bunny: F-score, doubled-shell fraction, watertightness and
the fraction of its area that no camera saw (invented)."""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

from .io.atomic import atomic_write_json
from .layout import Layout
from .config_checks import check_config

log = logging.getLogger("photorecon")


@dataclass
class DemoConfig:
    """Settings of ``photorecon demo``."""

    scene: str = field(default="blob", metadata={"help": "built-in scene (blob, knot, room), or 'bunny': the Stanford bunny from a ring of cameras, meshed three ways", "metavar": "NAME"})
    views: int = field(default=30, metadata={"help": "number of views", "range": (2, 10_000)})
    width: int = field(default=512, metadata={"help": "image width, pixels", "range": (64, 8192)})
    height: int = field(default=384, metadata={"help": "image height, pixels", "range": (64, 8192)})

    def __post_init__(self):
        check_config(self)  # types, choices and ranges as declared (photorecon.config_checks)




def run_demo(out: str | Path, cfg: DemoConfig | None = None, overwrite: bool = False) -> dict:
    from .io.output import output_folder

    cfg = cfg or DemoConfig()
    with output_folder(out, overwrite, command="demo") as out:
        return _run_demo(out, cfg)


def _run_demo(out: Path, cfg: DemoConfig) -> dict:
    from .metrics import evaluate_reconstruction
    from .pipeline import StageConfigs, reconstruct
    from .report import write_html_report
    from .report.numbers import format_number, format_percent
    from .synthetic import SynthConfig, synthesize

    t0 = time.perf_counter()
    data = out / "scene"
    data_layout = Layout(data)
    if not data_layout.gt_mesh.is_file():
        synthesize(SynthConfig(scene=cfg.scene, views=cfg.views, width=cfg.width, height=cfg.height), data,
                   overwrite=True)
    t_synth = time.perf_counter() - t0
    rec = out / "reconstruction"
    from .depth.mvs import MVS_PRESETS, MVSConfig

    # 512x384 synthetic images: the "fast" PatchMatch preset keeps the demo within a few minutes on 2 cores
    report = reconstruct(data_layout.images, rec, StageConfigs(mvs=MVSConfig(**MVS_PRESETS["fast"])))
    poses, m = evaluate_reconstruction(rec, data)
    total = time.perf_counter() - t0
    summary = {"scene": cfg.scene, "views": cfg.views, "size": f"{cfg.width}x{cfg.height}",
               "registered": poses["registered"], "rotation_error_mean_deg": poses["rot_mean_deg"],
               "center_error_mean_pct_spread": 100 * poses["center_mean_rel"],
               "fscore_1pct": m.fscore, "fscore_0.5pct": m.fscore_half, "chamfer_pct_diag": 100 * m.chamfer / m.diagonal,
               "precision_1pct": m.precision, "recall_1pct": m.recall,
               "seconds": {"synthesize": t_synth, **{k: v.get("seconds", 0) for k, v in report["stages"].items()},
                           "total": total}}
    atomic_write_json(out / "demo.json", summary)
    write_html_report(rec, report.to_dict(), {"F-score at 1% (vs truth)": format_number(m.fscore),
                                              "Chamfer (vs truth)": f"{format_percent(m.chamfer / m.diagonal)} of "
                                                                    "the diagonal",
                                              "rotation error (mean, vs truth)": f"{format_number(poses['rot_mean_deg'])}°"})
    return summary


def print_summary(s: dict, out: Path) -> None:
    from .report.numbers import format_number, format_seconds

    print(f"photorecon demo: '{s['scene']}' scene, {s['views']} views at {s['size']}, reconstructed from its images alone")
    print(f"  {'registered images':32} {s['registered']} / {s['views']}")
    print(f"  {'rotation error (mean)':32} {format_number(s['rotation_error_mean_deg'])}°")
    print(f"  {'camera centre error (mean)':32} {format_number(s['center_error_mean_pct_spread'])}% of camera spread")
    print(f"  {'mesh F-score at 1% / 0.5%':32} {format_number(s['fscore_1pct'])} / {format_number(s['fscore_0.5pct'])}")
    print(f"  {'mesh Chamfer':32} {format_number(s['chamfer_pct_diag'])}% of the diagonal")
    print("  time: " + ", ".join(f"{k} {format_seconds(v)}" for k, v in s["seconds"].items()))
    print(f"  files: {out}/reconstruction/mesh.ply, preview.png, report.html")


BUNNY = Path(__file__).resolve().parent / "data" / "bunny.ply"
BUNNY_METHODS = (("article", "article: per-view grids concatenated"), ("tsdf", "photorecon: fused (TSDF)"),
                 ("watertight", "watertight (Poisson --watertight)"))


def run_bunny_demo(out: str | Path, cfg: DemoConfig | None = None, overwrite: bool = False) -> dict:
    """The article's experiment (see the module docstring). Writes OUT/scene (the rendered dataset),
    OUT/tsdf.ply, OUT/watertight.ply, OUT/side_by_side.png and OUT/demo.json; returns the summary."""
    from .io.output import output_folder

    cfg = cfg or DemoConfig(scene="bunny")
    with output_folder(out, overwrite, command="demo") as out:
        return _run_bunny_demo(out, cfg)


def _run_bunny_demo(out: Path, cfg: DemoConfig) -> dict:
    from .fusion import FusionConfig, fuse, legacy_article_fuse, load_frames, observed_points, surface_report
    from .io.dataset import Dataset
    from .mesh import clean, export, load_mesh
    from .metrics import doubled_shell_fraction, mesh_metrics, seen_split_metrics
    from .synthetic import SynthConfig, synthesize

    t0 = time.perf_counter()
    data = out / "scene"
    # the article's rig: one ring of cameras around the bunny (y up), 20 degrees above its middle
    synthesize(SynthConfig(mesh=str(BUNNY), up="y", rig="ring", views=cfg.views, width=cfg.width,
                           height=cfg.height), data, overwrite=True)
    t_synth = time.perf_counter() - t0
    ds = Dataset.open(data)
    frames = load_frames(ds, FusionConfig())
    gt = load_mesh(Layout(data).gt_mesh)
    meshes, rows = {}, []
    observed = None
    for key, label in BUNNY_METHODS:
        t1 = time.perf_counter()
        if key == "article":
            mesh = legacy_article_fuse(frames)
        elif key == "tsdf":
            mesh = clean(fuse(frames, FusionConfig(), ds.model.points), cameras=ds.views)
        else:
            mesh = clean(fuse(frames, FusionConfig(mesher="poisson", watertight=True)), cameras=ds.views)
        secs = time.perf_counter() - t1
        m = mesh_metrics(mesh, gt, n_samples=100_000)
        surface = surface_report(mesh, frames)
        if observed is None:  # what the cameras saw (the same for every method: the same depth maps)
            observed = observed_points(frames, surface["invent_distance"] / 2)
        # the scores on what the cameras saw and on what they did not (the ring never sees the base: there a
        # closed surface can only guess)
        split = seen_split_metrics(mesh, gt, observed, surface["invent_distance"], m.tau, 100_000)
        rows.append({"method": key, "label": label, "seconds": secs, "faces": len(mesh.faces),
                     "fscore_1pct": m.fscore, "fscore_0.5pct": m.fscore_half, "precision_1pct": m.precision,
                     "recall_1pct": m.recall, "doubled_shells": doubled_shell_fraction(mesh, m.tau / 2, 30_000),
                     "seen": split["seen"], "unseen": split["unseen"], **surface})
        meshes[key] = mesh
        if key != "article":  # the article's mesh: millions of overlapping faces, only pictured
            export(mesh, out / f"{key}.ply")
    side_by_side(meshes, out / "side_by_side.png", [label for _, label in BUNNY_METHODS])
    summary = {"scene": "bunny", "views": cfg.views, "size": f"{cfg.width}x{cfg.height}", "rig": "ring",
               "depth": "rendered (the article's z-buffer depth), true cameras", "rows": rows,
               "seconds": {"synthesize": t_synth, "total": time.perf_counter() - t0}}
    atomic_write_json(out / "demo.json", summary)
    return summary


def side_by_side(meshes: dict, path: Path, labels: list[str], size: int = 320) -> Path:
    """One picture: a column per mesh (labelled), seen from the side (as the ring cameras) and from below
    (what the ring never saw), framed alike."""
    import cv2
    import numpy as np

    from .cameras import Intrinsics, View, look_at
    from .io.images import write_image
    from .report.preview import bulk_frame
    from .render import Renderer

    ref = next(iter(meshes.values()))
    center, radius = bulk_frame(meshes.get("tsdf", ref))
    dist = radius / np.sin(np.radians(50.0 / 2)) * 1.1
    intr = Intrinsics.from_fov(size, size, 50.0)
    poses = [look_at(center + dist * np.array([0.8, 0.35, 0.5]), center, up=(0, 1, 0)),
             look_at(center + dist * np.array([0.3, -0.9, 0.3]), center, up=(0, 1, 0))]
    cols = []
    for mesh, label in zip(meshes.values(), labels):
        r = Renderer(mesh, plain=True, background_color=(1.0, 1.0, 1.0))
        tiles = [r.render(View("side_by_side", intr, T)).rgb for T in poses]
        col = np.concatenate(tiles, axis=0).copy()
        cv2.putText(col, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (20, 20, 20), 1, cv2.LINE_AA)
        cv2.putText(col, "from below", (6, size + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (90, 90, 90), 1, cv2.LINE_AA)
        cols.append(col)
    return write_image(path, np.concatenate(cols, axis=1))


def print_bunny_summary(s: dict, out: Path) -> None:
    print(f"photorecon demo: the article's experiment, the Stanford bunny from a ring of {s['views']} cameras at "
          f"{s['size']}, {s['depth']}")
    print(f"  {'method':38} {'F@1%':>6} {'F@0.5%':>6} {'seen':>6} {'unseen':>6} {'doubled':>7} {'watertight':>10} "
          f"{'boundary':>8} {'invented':>8} {'faces':>9} {'s':>6}")
    for r in s["rows"]:
        print(f"  {r['label']:38} {r['fscore_1pct']:6.3f} {r['fscore_0.5pct']:6.3f} {r['seen']['fscore']:6.3f} "
              f"{r['unseen']['fscore']:6.3f} {r['doubled_shells']:7.3f} "
              f"{'yes' if r['watertight'] else 'no':>10} {r['boundary_edges']:8d} {100 * r['invented_fraction']:7.1f}% "
              f"{r['faces']:9d} {r['seconds']:6.1f}")
    print("  seen / unseen: F@1% on the parts of both surfaces within two cells of an observed point / the rest "
          "(what no camera saw); doubled: fraction of the surface with a second sheet of the same mesh within 0.5% "
          "of the diagonal; invented: area farther than two cells from every observed point")
    from .report.numbers import format_seconds

    print(f"  time: synthesize {format_seconds(s['seconds']['synthesize'])}, total {format_seconds(s['seconds']['total'])}")
    print(f"  files: {out}/side_by_side.png, tsdf.ply, watertight.ply, demo.json")
