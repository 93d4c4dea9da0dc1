"""Running out of memory: a stage whose estimated need exceeds the available memory (the free memory, or the
headroom under ``ulimit -v``) is refused before it starts, and an allocation that fails inside a stage is
caught; either way one line ``out of memory in STAGE: ...; try --quality preview or --max-size``, exit 11,
and no temporary file left behind."""
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from photorecon import resources
from photorecon.cli import main
from photorecon.errors import OutOfMemoryError

ROOT = Path(__file__).resolve().parents[1]
MB = 1 << 20


def _line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err  # one line, no traceback
    return lines[0]


def _temporaries(out: Path) -> list[Path]:
    """Files or folders a stage writes under a temporary name (``.NAME.partial``, ``.features.XXXX.db``,
    ``.upscaled*``, ``.mapper*``, ``.undistort*``)."""
    return [p for p in out.rglob(".*") if p.name not in (".photorecon", ".stages", ".photorecon.lock")
            and ".stages" not in p.parts]


def test_available_memory_is_the_headroom_under_the_address_space_limit():
    code = ("import resource; from photorecon.resources import available_bytes, _address_space; "
            "lim = _address_space() + (300 << 20); resource.setrlimit(resource.RLIMIT_AS, (lim, lim)); "
            "print(available_bytes() >> 20)")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert run.returncode == 0, run.stderr
    assert 250 <= int(run.stdout) <= 300
    assert resources.available_bytes() > 0


def test_sift_extraction_that_cannot_fit_is_refused_before_it_starts(blob_small, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(resources, "available_bytes", lambda: 1 * MB)  # 160x120 photos: about 5 MB a thread
    out = tmp_path / "out"
    assert main(["reconstruct", str(blob_small / "images"), "-o", str(out)]) == OutOfMemoryError.exit_code == 11
    line = _line(capsys.readouterr().err)
    assert line.startswith("photorecon reconstruct: error: out of memory in SfM feature extraction: needs about ")
    assert line.endswith("(1 MB available); try --quality preview or --max-size")
    assert not (out / "colmap" / "features.db").exists() and _temporaries(out) == []


def test_sift_extraction_runs_fewer_threads_where_memory_allows_fewer(monkeypatch):
    from photorecon.poses.sfm import SIFT_BYTES_PER_PIXEL, SfMConfig, sift_threads

    cams = [{"size": [1600, 1200], "images": [f"{i}.jpg" for i in range(20)]}]
    per_thread = SIFT_BYTES_PER_PIXEL * 1600 * 1200
    monkeypatch.setattr(resources, "available_bytes", lambda: int(3.5 * per_thread))
    assert sift_threads(cams, SfMConfig(threads=8)) == 3
    assert sift_threads(cams, SfMConfig(threads=2)) == 2
    # at --max-image-size 800, a quarter of the pixels: 4 times as many threads fit
    assert sift_threads(cams, SfMConfig(threads=16, max_image_size=800)) == 14
    monkeypatch.setattr(resources, "available_bytes", lambda: per_thread // 2)
    with pytest.raises(OutOfMemoryError, match=r"SfM feature extraction: needs about 0\.4 GB \(0\.2 GB available\)"):
        sift_threads(cams, SfMConfig())


def test_depth_stage_that_cannot_fit_is_refused_before_it_starts(blob_small, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(resources, "available_bytes", lambda: 1 * MB)
    out = tmp_path / "out"
    argv = ["reconstruct", str(blob_small / "images"), "--poses", str(blob_small / "sparse" / "0"), "-o", str(out)]
    assert main(argv) == 11
    line = _line(capsys.readouterr().err)
    from photorecon.pipeline import DEPTH_BYTES_PER_PIXEL, DEPTH_BYTES_PER_SOURCE_PIXEL

    need = 160 * 120 * (DEPTH_BYTES_PER_PIXEL + 8 * DEPTH_BYTES_PER_SOURCE_PIXEL)  # 8 sources by default
    assert f"out of memory in depth (MVS): needs about {round(need / MB)} MB (1 MB available); try --quality" in line
    assert not (out / "depth").exists() and _temporaries(out) == []


@pytest.mark.parametrize("failure", [MemoryError(), RuntimeError("[Open3D Error] std::bad_alloc"),
                                     RuntimeError("malloc(): failed to allocate 812345678 bytes")])
def test_an_allocation_failing_inside_a_stage_is_the_out_of_memory_line(blob_small, tmp_path, monkeypatch, capsys,
                                                                         failure):
    import photorecon.pipeline as pipeline

    def fusion_stage(*args, **kwargs):
        raise failure

    monkeypatch.setattr(pipeline, "fusion_stage", fusion_stage)
    out = tmp_path / "out"
    argv = ["reconstruct", str(blob_small / "images"), "--poses", str(blob_small / "sparse" / "0"),
            "--depth", str(blob_small / "depth"), "-o", str(out)]
    assert main(argv) == 11
    line = _line(capsys.readouterr().err)
    assert "error: out of memory in fusion: needs more than the " in line and line.endswith(
        "available; try --quality preview or --max-size")
    assert not (out / "mesh.ply").exists() and _temporaries(out) == []


def test_other_runtime_errors_stay_unexpected_errors(blob_small, tmp_path, monkeypatch, capsys):
    import photorecon.pipeline as pipeline

    def fusion_stage(*args, **kwargs):
        raise RuntimeError("index out of range")

    monkeypatch.setattr(pipeline, "fusion_stage", fusion_stage)
    argv = ["reconstruct", str(blob_small / "images"), "--poses", str(blob_small / "sparse" / "0"),
            "--depth", str(blob_small / "depth"), "-o", str(tmp_path / "out")]
    assert main(argv) == 10
    assert "RuntimeError: index out of range" in capsys.readouterr().err


def test_an_address_space_limit_too_small_for_the_libraries_fails_at_start_up(blob_small, tmp_path):
    """``ulimit -v`` 1.5 GB: the native libraries alone need more address space; one line and exit 11 before any
    work, instead of an OpenBLAS abort halfway through matching (exit 1, its temporary database left behind)."""
    limit = 1536 << 20
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run([sys.executable, "-m", "photorecon", "reconstruct", str(blob_small / "images"), "-o",
                          str(out)], capture_output=True, text=True, env=env, timeout=120, cwd=ROOT,
                         preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (limit, limit)))
    assert run.returncode == 11, run.stderr
    line = _line(run.stderr)
    assert line.startswith("photorecon reconstruct: error: out of memory in start-up: needs about 1.9 GB (1.5 GB")
    assert line.endswith("raise the limit (ulimit -v)")
    assert not out.exists()
