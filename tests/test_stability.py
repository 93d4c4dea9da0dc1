"""The result does not hinge on floating-point details: the fastmath switch of the compiled kernels, and the
decisions of the cleaning that a 1-ulp change of the fused mesh must not flip."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

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


def _square(x0, y0, w, h, n=8):
    """A flat w x h rectangle at (x0, y0), z = 0, triangulated on an n x n grid: (vertices, faces)."""
    import numpy as np

    xs, ys = np.meshgrid(np.linspace(x0, x0 + w, n + 1), np.linspace(y0, y0 + h, n + 1))
    V = np.c_[xs.ravel(), ys.ravel(), np.zeros(xs.size)]
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    F = np.concatenate([np.c_[i.ravel(), i.ravel() + 1, i.ravel() + n + 2],
                        np.c_[i.ravel(), i.ravel() + n + 2, i.ravel() + n + 1]])
    return V, F


def _mesh(parts):
    import numpy as np
    import trimesh

    Vs, Fs, k = [], [], 0
    for V, F in parts:
        Vs.append(V)
        Fs.append(F + k)
        k += len(V)
    return trimesh.Trimesh(np.concatenate(Vs), np.concatenate(Fs), process=False)


def test_debris_and_main_surface_do_not_hinge_on_a_thin_bridge_between_two_big_pieces():
    """The object's surface fused as two big halves, and small pieces along it of 0.3% of a half's area.
    Whether a one-voxel bridge joins the halves (a 1-ulp change of the fused grid can make or break one) must not
    change what the small pieces are measured against: with the largest piece's whole area they all turned into
    debris with the bridge and stayed without it."""
    import numpy as np

    from photorecon.mesh import floater_mask, to_open3d

    half_a, half_b = _square(0.0, 0.0, 1.0, 1.0, 20), _square(1.002, 0.0, 1.0, 1.0, 20)
    small = [_square(0.05 + 0.19 * (i % 10), 1.01 + 0.06 * (i // 10), 0.055, 0.055, 2) for i in range(30)]

    def kept_small(with_bridge: bool) -> float:
        parts = [half_a, half_b, *small]
        mesh = _mesh(parts)
        if with_bridge:  # two triangles sharing the halves' own edge vertices: one piece
            n = 21
            a_right = [k * n + 20 for k in (10, 11)]  # half_a's vertices at x = 1 (rows 10, 11)
            b_left = [len(half_a[0]) + k * n for k in (10, 11)]  # half_b's at x = 1.002
            faces = np.vstack([mesh.faces, [[a_right[0], b_left[0], b_left[1]], [a_right[0], b_left[1], a_right[1]]]])
            mesh = type(mesh)(mesh.vertices, faces, process=False)
        drop = floater_mask(to_open3d(mesh), 0.05, 0.05, 0.002)
        n_big = len(half_a[1]) + len(half_b[1])
        return float(np.mean(~drop[n_big:n_big + sum(len(f) for _, f in small)]))

    assert kept_small(False) == kept_small(True)


def test_a_wide_join_is_one_piece_and_small_pieces_are_measured_against_all_of_it():
    """Two halves joined along their whole edge are one surface, not two bridged halves: the same small pieces
    (0.15% of it) are debris, as they are against the largest piece's area."""
    import numpy as np

    from photorecon.mesh import floater_mask, to_open3d
    from photorecon.mesh.clean import largest_area
    from photorecon.mesh.geometry import triangle_components

    whole = _square(0.0, 0.0, 2.0, 1.0, 40)
    small = [_square(0.05 + 0.19 * (i % 10), 1.01 + 0.06 * (i // 10), 0.055, 0.055, 2) for i in range(30)]
    mesh = _mesh([whole, *small])
    labels, areas = triangle_components(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    assert largest_area(np.asarray(mesh.vertices), np.asarray(mesh.faces), labels, areas) == pytest.approx(2.0)
    drop = floater_mask(to_open3d(mesh), 0.05, 0.05, 0.002)
    assert drop[len(whole[1]):].all() and not drop[:len(whole[1])].any()


def test_largest_area_is_a_half_whether_or_not_a_thin_bridge_joins_the_halves():
    import numpy as np

    from photorecon.mesh.clean import largest_area
    from photorecon.mesh.geometry import triangle_components

    half_a, half_b = _square(0.0, 0.0, 1.0, 1.0, 20), _square(1.002, 0.0, 1.0, 1.0, 20)
    mesh = _mesh([half_a, half_b])
    n = 21
    bridge = [[10 * n + 20, len(half_a[0]) + 10 * n, len(half_a[0]) + 11 * n],
              [10 * n + 20, len(half_a[0]) + 11 * n, 11 * n + 20]]
    for faces in (mesh.faces, np.vstack([mesh.faces, bridge])):
        labels, areas = triangle_components(np.asarray(mesh.vertices), faces)
        assert largest_area(np.asarray(mesh.vertices), faces, labels, areas) == pytest.approx(1.0, rel=1e-3)
