"""Sub-command definitions: arguments come from the stage configs; the work is in the stage modules."""
from __future__ import annotations

import argparse
import logging

from .cli import add_config_arguments, command, config_from_args

log = logging.getLogger("photorecon")


def _out_args(p: argparse.ArgumentParser, required: bool = True) -> None:
    p.add_argument("-o", "--out", required=required, help="output folder")
    p.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty folder not made by photorecon")


@command
def synth(sub):
    from .synthetic import SynthConfig

    p = sub.add_parser("synth", help="render a mesh or built-in scene to images, depth, masks and cameras",
                       description="Render a synthetic dataset with ground truth (see the README for the layout).")
    _out_args(p)
    add_config_arguments(p, SynthConfig)
    p.set_defaults(func=_run_synth)


def _run_synth(args):
    from .synthetic import SynthConfig, synthesize

    cfg = config_from_args(SynthConfig, args)
    res = synthesize(cfg, args.out, overwrite=args.overwrite)
    print(f"synth: {len(res.views)} views, {res.seconds_per_view:.3f} s/view -> {res.root}")
    return 0
