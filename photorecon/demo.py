"""``photorecon demo``: synthesize a textured scene, reconstruct it from its images alone (SfM poses,
weight-free MVS depth, TSDF fusion) as a real capture would be, and measure the result against the truth."""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

from .io.atomic import atomic_write_json
from .layout import Layout

log = logging.getLogger("photorecon")


@dataclass
class DemoConfig:
    """Settings of ``photorecon demo``."""

    scene: str = field(default="blob", metadata={"help": "built-in scene (blob, knot, room)"})
    views: int = field(default=30, metadata={"help": "number of views"})
    width: int = field(default=512, metadata={"help": "image width"})
    height: int = field(default=384, metadata={"help": "image height"})


def run_demo(out: str | Path, cfg: DemoConfig | None = None, overwrite: bool = False) -> dict:
    from .io.output import prepare_output
    from .metrics import evaluate_reconstruction
    from .pipeline import StageConfigs, reconstruct
    from .report import write_html_report
    from .synthetic import SynthConfig, synthesize

    cfg = cfg or DemoConfig()
    out = prepare_output(out, overwrite)
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
    write_html_report(rec, report, {"F-score at 1% (vs truth)": f"{m.fscore:.4f}",
                                    "Chamfer (% of diagonal)": f"{100 * m.chamfer / m.diagonal:.4f}",
                                    "rotation error (deg, mean)": f"{poses['rot_mean_deg']:.4f}"})
    return summary


def print_summary(s: dict, out: Path) -> None:
    print(f"photorecon demo: '{s['scene']}' scene, {s['views']} views at {s['size']}, reconstructed from its images alone")
    print(f"  {'registered images':32} {s['registered']} / {s['views']}")
    print(f"  {'rotation error (mean)':32} {s['rotation_error_mean_deg']:.4f} deg")
    print(f"  {'camera centre error (mean)':32} {s['center_error_mean_pct_spread']:.4f} % of camera spread")
    print(f"  {'mesh F-score at 1% / 0.5%':32} {s['fscore_1pct']:.4f} / {s['fscore_0.5pct']:.4f}")
    print(f"  {'mesh Chamfer':32} {s['chamfer_pct_diag']:.4f} % of the diagonal")
    secs = s["seconds"]
    print("  seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in secs.items()))
    print(f"  files: {out}/reconstruction/mesh.ply, preview.png, report.html")
