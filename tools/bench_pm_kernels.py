#!/usr/bin/env python
"""Side by side, CPU seconds of one PatchMatch iteration (red + black pm_pass) of kernel variants on the same
inputs: a 9-view blob ring (synthesized once into $TMPDIR/pm_bench_scene), reference view 0 with 4 sources,
the true depth +1% noise as hypotheses, the sources' true depth for the geometric term; with/without the
geometric term and refinement, and the fraction of pixels within 1% after the pass.

    cp photorecon/depth/methods/patchmatch/kernels.py /tmp/k/k0.py; (edit a copy as /tmp/k/k1.py)
    python tools/bench_pm_kernels.py 800 534 /tmp/k/k0.py /tmp/k/k1.py
"""
import sys, time, importlib.util
from pathlib import Path
import numpy as np
from photorecon.io.dataset import Dataset
from photorecon.synthetic import SynthConfig, synthesize
from photorecon.depth.methods.patchmatch import solver as pmm
from photorecon.depth.mvs import MVSConfig
from photorecon.io.images import *  # noqa
import cv2

import tempfile
root = Path(tempfile.gettempdir()) / "pm_bench_scene"
W, H = int(sys.argv[1]), int(sys.argv[2])
if not (root / "scene.json").is_file():
    synthesize(SynthConfig(scene="blob", rig="ring", views=9, width=W, height=H, elevation=15, points=4000), root, overwrite=True)
ds = Dataset.open(root)
views = ds.views
def grey(v):
    im = ds.image(v).astype(np.float32)
    if im.ndim == 3: im = im.mean(2)
    return np.ascontiguousarray(im / (255.0 if im.max() > 1.5 else 1.0), np.float32)
ref, srcv = views[0], views[1:5]
gts = [np.load(root / "depth" / f"{v.name}.npy").astype(np.float32) for v in views]
cfg = MVSConfig(); params = pmm.PatchMatchParams(cfg)
g = pmm._Geometry(ref, srcv)
GP, Ge, GM, Gg = g.reprojection(np.stack([pmm._pinhole_K(v) for v in srcv]))
rimg = grey(ref); srcs = pmm._stack([grey(v) for v in srcv]); sdepth = pmm._stack(gts[1:5])
rng = np.random.default_rng(0)
d0 = gts[0].copy(); d0[d0 <= 0] = 0
d0 *= (1 + 0.01 * rng.standard_normal(d0.shape)).astype(np.float32)
n0 = np.zeros(d0.shape + (3,), np.float32); n0[..., 2] = -1
valid = gts[0][gts[0] > 0]; dmin, dmax = float(valid.min() * 0.8), float(valid.max() * 1.2)

mods = []
for i, f in enumerate(sys.argv[3:]):
    sys.path.insert(0, str(Path(f).parent)); m = importlib.import_module(Path(f).stem); mods.append((f, m))

def run(m, use_geo, n_refine, reps=1):
    depth, normal = d0.copy(), n0.copy()
    m.init_random(depth, normal, g.Kinv, dmin, dmax, 0, True)
    cost = np.empty(depth.shape, np.float32)
    m.initial_cost(rimg, srcs, g.A, g.b, g.Kinv, GP, Ge, GM, Gg, sdepth, use_geo, 0.2, 3.0, params.sdy, params.sdx, params.sspat, params.sigma_c, params.min_var, 2, depth, normal, cost)
    t0 = time.process_time(); w0 = time.perf_counter()
    for it in range(reps):
        for color in (0, 1):
            m.pm_pass(color, it, rimg, srcs, g.A, g.b, g.Kinv, GP, Ge, GM, Gg, sdepth, use_geo, 0.2, 3.0,
                      params.sdy, params.sdx, params.sspat, params.sigma_c, params.min_var, params.rdy, params.rdx, params.rn,
                      dmin, dmax, 0.8, 1.2, 2, 3, 0.3, 0.02, 0, n_refine, 1e-3, float(np.cos(np.radians(1.5))), 1.0, 0, False, depth, normal, cost,
                      np.zeros((depth.shape[0], m.N_COUNTS), np.int64), np.zeros((1, 1), np.int32), False)
    return time.process_time() - t0, time.perf_counter() - w0, depth

gtm = gts[0] > 0
for f, m in mods: run(m, True, 3)  # compile / load
for rep in range(2):
    for cfgs in ((True, 3), (False, 3), (True, 0)):
        for f, m in mods:
            cpu, wall, d = run(m, *cfgs)
            ok = gtm & (d > 0); within = (np.abs(d[ok] - gts[0][ok]) / gts[0][ok] < 0.01).sum() / gtm.sum()
            print(f"rep{rep} geo={cfgs[0]} refine={cfgs[1]} {Path(f).name}: cpu {cpu:.2f} s wall {wall:.2f} s within1% {within:.4f}", flush=True)
