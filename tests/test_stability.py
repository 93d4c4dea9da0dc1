"""The result does not hinge on floating-point details: the fastmath switch of the compiled kernels, and the
decisions of the cleaning that a 1-ulp change of the fused mesh must not flip."""
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_PROBE = """
import json
from photorecon import jit
from photorecon.fusion import tsdf
k = tsdf._tsdf_weighted_kernel
print(json.dumps({"fastmath": jit.FASTMATH, "kernel_fastmath": bool(k.targetoptions.get("fastmath")),
                  "cache": str(k._cache._cache_path)}))
"""


def _probe(tmp_path, **env_over):
    env = {k: v for k, v in os.environ.items() if k not in ("PHOTORECON_FASTMATH", "NUMBA_CACHE_DIR")}
    env.update(env_over)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, env=env, cwd=tmp_path,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_fastmath_switch_compiles_strict_kernels_into_a_cache_of_their_own(tmp_path):
    on = _probe(tmp_path)
    assert on["fastmath"] and on["kernel_fastmath"]
    assert "photorecon-nofastmath" not in on["cache"]
    off = _probe(tmp_path, PHOTORECON_FASTMATH="0", NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    assert not off["fastmath"] and not off["kernel_fastmath"]
    # kernels of the other setting are never read: numba's cache index does not record fastmath
    assert Path(off["cache"]).is_relative_to(tmp_path / "cache" / "photorecon-nofastmath")
    assert Path(on["cache"]) != Path(off["cache"])
