"""What a run prints when its output is a log file (progress lines at a steady pace, no library's notes), the same
cameras whatever the output folder's history, and two runs at once in one process."""
import logging
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from photorecon import progress
from photorecon.testing import synth_scene

ROOT = Path(__file__).resolve().parents[1]


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


@pytest.fixture
def progress_on(monkeypatch):
    monkeypatch.setattr(progress, "_enabled", True)


def _lines(caplog):
    return [r.getMessage() for r in caplog.records if r.name == "photorecon"]


def test_log_bar_says_counts_elapsed_and_eta_at_most_once_per_interval(caplog):
    clock = FakeClock()
    caplog.set_level(logging.INFO, logger="photorecon")
    b = progress.LogBar(range(10), desc="mvs depth (patchmatch, 10 views)", unit="task", interval=30, clock=clock,
                        tick=False)
    for i in b:
        clock.t += 12  # 12 s per task: a line 30 s or more after the last one (36 s, 72 s, 108 s), then the end
    lines = _lines(caplog)
    assert lines == ["mvs depth (patchmatch, 10 views): 3/10 tasks, 36s elapsed, about 1m24s left",
                     "mvs depth (patchmatch, 10 views): 6/10 tasks, 1m12s elapsed, about 48s left",
                     "mvs depth (patchmatch, 10 views): 9/10 tasks, 1m48s elapsed, about 12s left",
                     "mvs depth (patchmatch, 10 views): 10/10 tasks in 2m00s"]


def test_log_bar_is_silent_for_work_shorter_than_the_interval(caplog):
    clock = FakeClock()
    caplog.set_level(logging.INFO, logger="photorecon")
    with progress.LogBar(total=5, desc="tsdf fusion", interval=30, clock=clock, tick=False) as b:
        for _ in range(5):
            clock.t += 5
            b.update(1)
    assert _lines(caplog) == []


def test_a_long_item_and_a_native_call_still_log_from_the_background(caplog, progress_on):
    """While one item (or one native call: COLMAP's extraction, matching, mapping) runs for long, the line comes
    from a background thread at the same pace; the thread ends with the work."""
    caplog.set_level(logging.INFO, logger="photorecon")
    with progress.running("SfM matching (exhaustive)", interval=0.1):
        time.sleep(0.45)
    lines = _lines(caplog)
    assert 2 <= sum(line.startswith("SfM matching (exhaustive): running, ") for line in lines) <= 5, lines
    assert lines[-1].startswith("SfM matching (exhaustive): done in ")
    caplog.clear()
    for _ in progress.LogBar([1, 2], desc="patchmatch 1/1", interval=0.1):
        time.sleep(0.25)
    lines = _lines(caplog)
    assert any(line.startswith("patchmatch 1/1: 0/2 views, ") for line in lines), lines
    assert lines[-1].startswith("patchmatch 1/1: 2/2 views in ")
    time.sleep(0.2)
    assert not [t for t in threading.enumerate() if t.name == "photorecon-progress"]


def test_bars_are_tqdm_on_a_terminal_and_log_lines_in_a_file(monkeypatch, progress_on):
    import io

    from tqdm import tqdm

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert isinstance(progress.bar(range(3), desc="x"), progress.LogBar)
    monkeypatch.setattr(sys, "stderr", Terminal())
    assert isinstance(progress.bar(range(3), desc="x"), tqdm)
    monkeypatch.setattr(progress, "_enabled", False)  # --quiet: nothing either way
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert not isinstance(progress.bar(range(3), desc="x"), progress.LogBar)
    with progress.running("x") as r:
        assert r is None


def test_faiss_note_on_the_native_stderr_is_dropped_and_other_lines_kept(capfd, caplog):
    """COLMAP's visual index (retrieval matching) trains FAISS's coarse index on its visual words; FAISS then
    prints a note for every index under 6,084 words. It is not shown; what else a library prints still is."""
    from photorecon.poses.retrieval import FAISS_NOTE, native_stderr_filtered

    caplog.set_level(logging.DEBUG, logger="photorecon")
    with native_stderr_filtered(FAISS_NOTE, "retrieval: FAISS"):
        os.write(2, b"WARNING clustering 2048 points to 90 centroids: please provide at least 3510 training points\n")
        os.write(2, b"some other native message\n")
    err = capfd.readouterr().err
    assert "clustering" not in err and "some other native message" in err
    assert any("WARNING clustering 2048 points" in m for m in _lines(caplog))  # -v still shows it


@pytest.mark.slow  # imports the whole pipeline (Open3D, numba, ...): seconds on its own
def test_a_runs_report_collects_only_its_own_threads_warnings():
    from photorecon.pipeline import _WarningCollector

    log = logging.getLogger("photorecon")
    mine: list = []
    handler = _WarningCollector(mine)
    log.addHandler(handler)
    try:
        log.warning("warning of this run")
        other = threading.Thread(target=log.warning, args=("warning of a run in another thread",))
        other.start()
        other.join()
    finally:
        log.removeHandler(handler)
    assert mine == ["warning of this run"]


def test_an_output_folder_held_by_another_thread_is_refused(tmp_path):
    from photorecon.errors import OutputError
    from photorecon.io.output import output_lock

    held, release = threading.Event(), threading.Event()

    def hold():
        with output_lock(tmp_path / "out"):
            held.set()
            release.wait(10)

    t = threading.Thread(target=hold)
    t.start()
    try:
        assert held.wait(10)
        with pytest.raises(OutputError, match=r"in use by another photorecon run in this process"):
            with output_lock(tmp_path / "out"):
                pass
    finally:
        release.set()
        t.join()
    with output_lock(tmp_path / "out"), output_lock(tmp_path / "out"):  # one thread nests, as before
        pass


@pytest.fixture(scope="module")
def ring(tmp_path_factory):
    """16 ring views of the blob at 240x180: SfM in a few seconds."""
    return synth_scene(tmp_path_factory, "ring_logs", scene="blob", rig="ring", views=16, width=240, height=180,
                       points=300, seed=5)


@pytest.mark.slow
def test_reconstruct_into_a_log_file_shows_progress_and_no_library_notes(ring, tmp_path):
    """``photorecon reconstruct ... 2> log`` (retrieval matching, whose visual index made FAISS print its note):
    progress lines in the log, one per line (no bar redrawn with carriage returns), and no library's note. The
    pace is 1 s here instead of 30 s, so that a small run shows it."""
    log_file = tmp_path / "log"
    code = ("import sys; import photorecon.progress as p; p.INTERVAL = 1.0\n"
            "from photorecon.cli import main\n"
            f"sys.exit(main({['reconstruct', str(ring / 'images'), '-o', str(tmp_path / 'out'), '--quality', 'preview', '--matching', 'retrieval']!r}))")
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with open(log_file, "w") as err:
        proc = subprocess.run([sys.executable, "-c", code], stderr=err, stdout=subprocess.DEVNULL, env=env,
                              cwd=tmp_path, timeout=600)
    text = log_file.read_text()
    assert proc.returncode == 0, text[-2000:]
    assert "\r" not in text
    assert "clustering" not in text and "centroids" not in text
    lines = text.splitlines()
    assert any(line.startswith("SfM feature extraction (16 photos): ") for line in lines), text
    assert any(line.startswith("mvs depth (") and " elapsed" in line for line in lines), text


@pytest.mark.slow
def test_the_retrieval_index_is_the_same_run_after_run(ring, tmp_path):
    """Retrieval matching's visual index (and so its pairs) from the same features: the same bytes every time.
    COLMAP's random projection was unseeded and its threads varied the index: 111, 112 or 113 pairs."""
    from photorecon.poses.retrieval import build_index, retrieval_pairs
    from photorecon.poses.sfm import SfMConfig, extract

    names = sorted(p.name for p in (ring / "images").iterdir())
    db = extract(ring / "images", tmp_path / "features.db",
                 [{"model": "SIMPLE_RADIAL", "params": "", "size": [240, 180], "images": names}], SfMConfig())
    a, b = (build_index(db, tmp_path / f"{n}.bin") for n in ("a", "b"))
    assert a.read_bytes() == b.read_bytes()
    assert retrieval_pairs(db, a, 6) == retrieval_pairs(db, b, 6)


def _poses(out):
    from photorecon.io.colmap_text import read_colmap_text

    return {v.name: v.cam_from_world for v in read_colmap_text(out / "sparse" / "0").views}


def test_incremental_mapping_runs_on_one_thread_whatever_threads():
    """Bundle adjustment's threads sum in the order they finish: on two threads 48 synthetic ring views gave 3
    different models in 3 runs from the same database, on one the same bytes."""
    import pycolmap

    from photorecon.poses.sfm import RELAXED_MAPPING, SfMConfig, _incremental_options

    for relaxed in (None, *RELAXED_MAPPING):
        assert _incremental_options(pycolmap, SfMConfig(threads=8), False, relaxed).num_threads == 1


@pytest.mark.slow
def test_the_same_photos_give_the_same_cameras_whatever_the_folders_history(ring, tmp_path):
    """One photo replaced, then removed, then put back: the last run's cameras are those of a fresh run on the
    same photos (every core for extraction and matching; the mapper on one thread)."""
    from PIL import Image

    from photorecon.poses.sfm import SfMConfig, run_sfm

    fresh = tmp_path / "fresh"
    run_sfm(ring / "images", fresh, SfMConfig())
    photos = tmp_path / "photos"
    shutil.copytree(ring / "images", photos)
    target = photos / "view_003.png"
    original = target.read_bytes()
    out = tmp_path / "out"
    im = np.asarray(Image.open(target).convert("RGB"))
    Image.fromarray((im * 0.8).astype(np.uint8)).save(target)  # replaced: another exposure
    run_sfm(photos, out, SfMConfig())
    target.unlink()  # removed
    run_sfm(photos, out, SfMConfig())
    target.write_bytes(original)  # put back: the folder is the original again
    res = run_sfm(photos, out, SfMConfig())
    assert len(res.registered) == 16
    a, b = _poses(fresh), _poses(out)
    assert sorted(a) == sorted(b)
    for name in a:
        assert np.allclose(a[name], b[name], rtol=0, atol=1e-9), name


@pytest.mark.slow
def test_two_reconstructs_in_two_threads_both_finish(blob_small, tmp_path):
    """Two runs at once from Python threads of one process, into different folders: both finish with their mesh
    and report (the locks, the report's warnings and the progress are per run)."""
    import json

    from photorecon.cli import main

    def argv(out):
        return ["-q", "reconstruct", str(blob_small / "images"), "-o", str(out), "--poses",
                str(blob_small / "transforms.json"), "--n-sources", "4", "--min-consistent", "1"]

    codes = {}

    def run(name):
        codes[name] = main(argv(tmp_path / name))

    threads = [threading.Thread(target=run, args=(n,)) for n in ("a", "b")]
    for t in threads:
        t.start()
    for t in threads:
        t.join(600)
    assert codes == {"a": 0, "b": 0}
    for name in ("a", "b"):
        out = tmp_path / name
        assert (out / "mesh.ply").stat().st_size > 1000
        report = json.loads((out / "report.json").read_text())
        assert not any(str(tmp_path / ("b" if name == "a" else "a")) in w for w in report.get("warnings", []))
