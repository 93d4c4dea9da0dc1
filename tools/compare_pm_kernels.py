"""Compare the current PatchMatch kernels with an older _pm_kernels.py (commit 5071435's _geo(Kr, R, t, Kd)): python tools/compare_pm_kernels.py [scene] with the old file at /tmp/pm2old/old_pm_kernels.py (git show 5071435:photorecon/depth/_pm_kernels.py)."""
import sys, time, tempfile
from pathlib import Path
import numpy as np
import os
sys.path.insert(0, os.environ.get("OLD_KERNELS_DIR", "/tmp/pm2old"))  # holds old_pm_kernels.py
import old_pm_kernels as old
from photorecon.depth import patchmatch as pmm, _pm_kernels as new
from photorecon.depth.mvs import MVSConfig, run_mvs
from photorecon.io.dataset import Dataset
from photorecon.synthetic import SynthConfig, synthesize
from photorecon.metrics import depth_metrics
from photorecon import progress
progress.set_enabled(False)

stash = {}
orig_init = pmm._Geometry.__init__
orig_rep = pmm._Geometry.reprojection
def init(self, ref, sources):
    orig_init(self, ref, sources); stash["g"] = self; stash["Kd"] = np.zeros((len(sources), 3, 3))
def rep(self, Kd):
    stash["Kd"] = np.ascontiguousarray(Kd, np.float64); return orig_rep(self, Kd)
pmm._Geometry.__init__ = init
pmm._Geometry.reprojection = rep

class OldAdapter:
    def __getattr__(self, n): return getattr(old, n)
    def initial_cost(self, ref, srcs, A, b, Kinv, GP, Ge, GM, Gg, *rest):
        g = stash["g"]; return old.initial_cost(ref, srcs, A, b, g.Kr, Kinv, g.R, g.t, stash["Kd"], *rest)
    def pm_pass(self, color, it, ref, srcs, A, b, Kinv, GP, Ge, GM, Gg, *rest):
        g = stash["g"]; return old.pm_pass(color, it, ref, srcs, A, b, g.Kr, Kinv, g.R, g.t, stash["Kd"], *rest)

which = {"k": new}
pmm._kernels = lambda: which["k"]

# 1. the geometric term alone on random rays / depths
rng = np.random.default_rng(0)
S, hs, ws = 4, 120, 160
Kr = np.array([[150., 0, 80], [0, 150., 60], [0, 0, 1]]); Kd = np.stack([Kr] * S)
R = np.stack([np.linalg.qr(np.eye(3) + 0.05 * rng.standard_normal((3, 3)))[0] for _ in range(S)])
R *= np.sign(np.linalg.det(R))[:, None, None]
t = 0.3 * rng.standard_normal((S, 3))
sd = (2.0 + 0.1 * rng.random((S, hs, ws))).astype(np.float32)
class G: pass
g = G(); g.R, g.t, g.Kr = R, t, Kr
GP, Ge, GM, Gg = orig_rep(g, Kd)
Kinv = np.linalg.inv(Kr); q = np.empty((S, 3)); diffs = []
for _ in range(20000):
    x, y = rng.uniform(0, ws - 1), rng.uniform(0, hs - 1); d = rng.uniform(1.5, 2.5)
    r0, r1, r2 = Kinv @ [x, y, 1.0]
    new._geo_rays(GP, r0, r1, r2, q)
    for j in range(S):
        a = old._geo(j, d * r0, d * r1, d * r2, x, y, R, t, Kd, sd, Kr, 3.0)
        b_ = new._geo(j, d, q, Ge, GM, Gg, sd, x, y, 3.0)
        diffs.append(abs(a - b_))
diffs = np.array(diffs)
print(f"_geo old vs new, {len(diffs)} samples: max |diff| {diffs.max():.2e} px, > 1e-6: {(diffs > 1e-6).mean():.4%}")

# 2. whole run_mvs on a small scene
with tempfile.TemporaryDirectory() as tmp:
    tmp = Path(tmp)
    synthesize(SynthConfig(scene=sys.argv[1] if len(sys.argv) > 1 else "blob", views=8, width=320, height=240, points=2000), tmp / "s", overwrite=True)
    ds = Dataset.open(tmp / "s")
    res = {}
    for label, k in (("old", OldAdapter()), ("new", new), ("old2", OldAdapter()), ("new2", new)):
        which["k"] = k
        t0 = time.process_time(); t1 = time.perf_counter()
        run_mvs(ds, tmp / label, MVSConfig())
        cpu, wall = time.process_time() - t0, time.perf_counter() - t1
        ws_, cs = [], []
        maps = {}
        for v in ds.views:
            gt = np.load(tmp / "s" / "depth" / f"{v.name}.npy"); p = tmp / label / f"{v.name}.npy"
            d = np.load(p) if p.is_file() else np.zeros_like(gt); maps[v.name] = d
            m = depth_metrics(d, gt); ws_.append(m["within"]); cs.append(m["coverage"])
        res[label] = maps
        print(f"{label}: cpu {cpu:.1f} s wall {wall:.1f} s within1% {np.mean(ws_):.4f} coverage {np.mean(cs):.4f}", flush=True)
    for a, b_ in (("old", "new"), ("old", "old2"), ("new", "new2")):
        rel = []; both = 0; either = 0
        for n in res[a]:
            da, db = res[a][n], res[b_][n]
            m = (da > 0) & (db > 0); both += m.sum(); either += ((da > 0) | (db > 0)).sum()
            rel.append(np.abs(da[m] - db[m]) / da[m])
        rel = np.concatenate(rel)
        print(f"{a} vs {b_}: valid in both / either {both / either:.4f}; |rel diff| median {np.median(rel):.1e}, "
              f"> 1e-4: {(rel > 1e-4).mean():.4%}, > 1e-2: {(rel > 1e-2).mean():.4%}")
