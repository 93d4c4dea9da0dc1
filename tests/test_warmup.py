"""``photorecon warmup`` reaches every numba kernel of the package, and a later process loads them all from
numba's cache instead of compiling them."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from photorecon.warmup import entry_kernels, kernels, warm_up

ROOT = Path(__file__).resolve().parents[1]


def test_kernel_listing_finds_entries_and_helpers():
    found = kernels()
    entries = entry_kernels(found)
    # kernels Python calls, and helpers only other kernels call (compiled with them)
    for name in ("photorecon.depth.methods.patchmatch.kernels.pm_pass", "photorecon.depth._filter_kernel.consistency_source",
                 "photorecon.fusion.tsdf._tsdf_weighted_kernel"):
        assert name in entries
    for name in ("photorecon.depth.methods.patchmatch.kernels._ncc",
                 "photorecon.depth.methods.patchmatch.kernels._homography"):
        assert name in found and name not in entries
    # every kernel is cached on disk (cache=True): otherwise warming it up would not outlive the process
    uncached = [k for k, d in found.items() if type(d._cache).__name__ == "NullCache"]
    assert not uncached, f"@njit without cache=True: {uncached}"


@pytest.mark.cold
def test_warmup_reaches_every_kernel_and_a_new_process_compiles_none():
    """In this process every kernel ends up compiled (or loaded) by ``warm_up``: a kernel added to the package
    and not run by it fails here. A new process then finds all of them in numba's cache."""
    r = warm_up()
    entries = entry_kernels()
    assert r["kernels"] == len(entries) >= 8
    assert r["missing"] == []
    assert all(d.signatures for d in entries.values())
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    code = "import json; from photorecon.warmup import warm_up; print(json.dumps(warm_up()))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    again = json.loads(out.stdout.strip().splitlines()[-1])
    assert again["missing"] == [], f"not reached by warm_up in a new process: {again['missing']}"
    assert again["compiled"] == [], f"compiled again in a new process: {again['compiled']}"
    assert sorted(again["cached"]) == sorted(entries)
