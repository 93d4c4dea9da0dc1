"""Stage records by content: a stage is complete while its outputs hold the bytes it wrote (a SHA-256 in its
marker), damaged outputs of photorecon's own are made again (never blamed on the input), a failed run leaves
the last complete result as it was, and every stage logs a line when it starts and one when it ends."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import photorecon.stages as stages_mod
from photorecon.cli import main
from photorecon.stages import Stages
from photorecon.testing import synth_scene


@pytest.fixture(scope="module")
def blob8(tmp_path_factory):
    """8 views of the blob at 96x72 with their cameras and depth maps: reconstruct's quickest full run."""
    return synth_scene(tmp_path_factory, "blob8", scene="blob", views=8, width=96, height=72, points=300, seed=3)


def _args(ds, out, *extra):
    return ["reconstruct", str(ds / "images"), "-o", str(out), "--poses", str(ds / "transforms.json"),
            "--depth", str(ds / "depth"), "--formats", "ply", *extra]


def _ran(out) -> list[str]:
    rep = json.loads((out / "report.json").read_text())
    return [name for name, s in rep["stages"].items() if not s.get("cached")]


def _damage(path, offset=0, n=200):
    """Zero ``n`` bytes of ``path`` at ``offset`` in place: the same size, and its time set back as it was."""
    st = path.stat()
    with open(path, "r+b") as f:
        f.seek(offset)
        f.write(bytes(n))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert path.stat().st_size == st.st_size


# --- the runner itself ---------------------------------------------------------------------------------------------

def _one_stage(folder, runs, text="x", result=False, fail=False):
    stages = Stages(folder / ".stages")

    def make():
        runs.append(text)
        (folder / "a.txt").write_text(text)
        if fail:
            raise KeyboardInterrupt

    stages.run("a", {"text": text}, make, outputs=[folder / "a.txt"], result=result)
    return stages


def test_same_size_same_time_other_bytes_reruns_the_stage(tmp_path, monkeypatch):
    runs = []
    _one_stage(tmp_path, runs)
    marker = json.loads((tmp_path / ".stages" / "a.json").read_text())
    assert marker["outputs"] == [["a.txt", 1, "2d711642b726b04401627ca9fbac32f5c8530fb1903cc4db02258717921a4881"]]
    _damage(tmp_path / "a.txt", n=1)  # "x" -> "\0", size and mtime as they were
    _one_stage(tmp_path, runs)
    assert runs == ["x", "x"] and (tmp_path / "a.txt").read_text() == "x"


def test_a_file_whose_status_vouches_for_it_is_not_read_again(tmp_path, monkeypatch):
    monkeypatch.setattr(stages_mod, "SETTLED_S", 0.0)  # no write can share the hashing's clock tick here
    reads = []
    real = stages_mod.sha256_file
    monkeypatch.setattr(stages_mod, "sha256_file", lambda p: reads.append(p) or real(p))
    runs = []
    _one_stage(tmp_path, runs)
    assert len(reads) == 1  # hashed when the stage ended
    _one_stage(tmp_path, runs)
    assert runs == ["x"] and len(reads) == 1  # reused on its recorded status, nothing read
    os.utime(tmp_path / "a.txt")  # the status changes (a copy, a touch): read again, the same bytes: reused
    _one_stage(tmp_path, runs)
    assert runs == ["x"] and len(reads) == 2
    _one_stage(tmp_path, runs)
    assert len(reads) == 2  # the marker took the new status
    _damage(tmp_path / "a.txt", n=1)
    _one_stage(tmp_path, runs)
    assert runs == ["x", "x"]


def test_a_stale_settle_window_reads_the_file_again(tmp_path, monkeypatch):
    # a file written just before it was hashed: its status does not vouch for it, its bytes are read
    reads = []
    real = stages_mod.sha256_file
    monkeypatch.setattr(stages_mod, "sha256_file", lambda p: reads.append(p) or real(p))
    monkeypatch.setattr(stages_mod, "SETTLED_S", 3600.0)
    runs = []
    _one_stage(tmp_path, runs)
    _one_stage(tmp_path, runs)
    _one_stage(tmp_path, runs)
    assert runs == ["x"] and len(reads) == 3


def test_a_failed_result_stage_puts_the_last_result_back(tmp_path):
    runs = []
    _one_stage(tmp_path, runs, "old", result=True)
    before = (tmp_path / ".stages" / "a.json").read_bytes()
    with pytest.raises(KeyboardInterrupt):
        _one_stage(tmp_path, runs, "new", result=True, fail=True)
    assert (tmp_path / "a.txt").read_text() == "old"
    assert (tmp_path / ".stages" / "a.json").read_bytes() == before and not (tmp_path / ".stages" / "last").exists()
    _one_stage(tmp_path, runs, "old", result=True)
    assert runs == ["old", "new"]  # the last result and its record, as they were: reused


def test_a_failed_intermediate_stage_keeps_what_was_there_and_removes_what_it_made(tmp_path):
    stages = Stages(tmp_path / ".stages")
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "f").write_text("last run's")

    def fail():
        (tmp_path / "new").mkdir()
        (tmp_path / "new" / "f").write_text("half")
        raise OSError(5, "Input/output error")

    with pytest.raises(OSError):
        stages.run("s", {}, fail, outputs=[tmp_path / "old", tmp_path / "new"])
    assert (tmp_path / "old" / "f").read_text() == "last run's" and not (tmp_path / "new").exists()
    assert not (tmp_path / ".stages" / "s.json").exists()


def test_a_run_killed_while_replacing_the_result_has_it_put_back_by_the_next(tmp_path):
    (tmp_path / "mesh.ply").write_text("last complete")
    (tmp_path / "report.json").write_text("{}")
    stages = Stages(tmp_path / ".stages")
    stages.set_aside([tmp_path / "mesh.ply", tmp_path / "report.json", tmp_path / "absent"])
    (tmp_path / "mesh.ply").write_text("half")  # then kill -9: no restore, no discard
    assert not (tmp_path / "report.json").exists()
    Stages(tmp_path / ".stages")
    assert (tmp_path / "mesh.ply").read_text() == "last complete" and (tmp_path / "report.json").read_text() == "{}"
    assert not (tmp_path / ".stages" / "last").exists()
    with Stages(tmp_path / ".stages").keeping_result() as st:  # a run that completes drops what it replaced
        st.set_aside([tmp_path / "mesh.ply"])
        (tmp_path / "mesh.ply").write_text("new")
    assert (tmp_path / "mesh.ply").read_text() == "new" and not (tmp_path / ".stages" / "last").exists()


def test_a_marker_without_contents_runs_the_stage_once(tmp_path):
    runs = []
    _one_stage(tmp_path, runs)
    marker = tmp_path / ".stages" / "a.json"
    data = json.loads(marker.read_text())
    data["outputs"] = [[r[0], r[1], None] for r in data["outputs"]]  # an older photorecon's record
    marker.write_text(json.dumps(data))
    _one_stage(tmp_path, runs)
    _one_stage(tmp_path, runs)
    assert runs == ["x", "x"]


# --- reconstruct ---------------------------------------------------------------------------------------------------

@pytest.mark.slow
def test_damaged_mesh_is_made_again_and_every_stage_logs_to_a_file(blob8, tmp_path):
    """With stderr a file (not a terminal): each stage's start and end lines; a mesh.ply zeroed in place (the
    same size and time) is made again, not reported as a result."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "photorecon", *_args(blob8, out)]

    def run(log):
        with open(log, "w") as f:
            r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=f, text=True, timeout=600)
        return r.returncode, log.read_text()

    rc, err = run(tmp_path / "first.log")
    assert rc == 0, err
    # the model stage writes model.glb and model_view.png
    for stage, n in (("poses", None), ("depth", 16), ("fusion", 1), ("preview", 2), ("model", 2)):
        assert f"\n{stage}: started (no complete earlier run)\n" in f"\n{err}", err
        done = [line for line in err.splitlines() if line.startswith(f"{stage}: done in ")]
        assert len(done) == 1 and "s, peak " in done[0] and " MB (" in done[0], err
        if n is not None:
            assert f"({n} file" in done[0], done
    assert "\r" not in err and "Traceback" not in err
    mesh = (out / "mesh.ply").read_bytes()

    _damage(out / "mesh.ply")
    rc, err = run(tmp_path / "second.log")
    assert rc == 0, err
    assert f"fusion: {out / 'mesh.ply'} changed since the stage wrote it (damaged or edited)" in err, err
    for stage in ("poses", "depth"):
        assert f"{stage}: unchanged, reused (" in err
    assert _ran(out) == ["fusion"]  # the same mesh again: the preview made from it is still complete
    assert (out / "mesh.ply").read_bytes() == mesh
    assert any("mesh.ply changed" in w for w in json.loads((out / "report.json").read_text())["warnings"])


@pytest.mark.slow
def test_damaged_cameras_and_depth_maps_are_made_again_not_blamed_on_the_input(blob8, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["-q", *_args(blob8, out)]) == 0
    cams = out / "sparse" / "0" / "cameras.txt"
    good = cams.read_bytes()
    mesh = (out / "mesh.ply").read_bytes()

    cams.write_bytes(b"\x07garbage!" * (len(good) // 9) + b"#" * (len(good) % 9))  # the same size
    assert cams.stat().st_size == len(good)
    assert main(["-q", *_args(blob8, out)]) == 0, capsys.readouterr().err
    assert cams.read_bytes() == good
    assert _ran(out) == ["poses"]  # written again with the same bytes: depth and fusion still complete

    dm = sorted((out / "depth").glob("view_*.npy"))[0]
    d = np.load(dm)
    assert d.shape[0] != d.shape[1]
    np.save(dm, np.ascontiguousarray(d.T))  # transposed: the same size, a shape no camera has
    assert main(["-q", *_args(blob8, out)]) == 0, capsys.readouterr().err
    assert np.array_equal(np.load(dm), d)
    assert _ran(out) == ["depth"] and (out / "mesh.ply").read_bytes() == mesh


@pytest.mark.slow
def test_a_failed_run_leaves_the_last_complete_result(blob8, tmp_path, monkeypatch, capsys):
    import photorecon.report.preview as preview

    out = tmp_path / "out"
    assert main(["-q", *_args(blob8, out)]) == 0
    names = ("mesh.ply", "preview.png", "preview_mesh.ply", "model.glb", "report.json", "report.html",
             ".stages/fusion.json", ".stages/preview.json", ".stages/model.json")
    before = {n: (out / n).read_bytes() for n in names}

    def fails(*a, **k):
        raise RuntimeError("the preview failed")

    monkeypatch.setattr(preview, "render_preview", fails)
    changed = _args(blob8, out, "--target-faces", "5000")  # fusion runs again, then the preview fails
    assert main(["-q", *changed]) == 10
    assert "the preview failed" in capsys.readouterr().err
    assert {n: (out / n).read_bytes() for n in names} == before
    assert not (out / ".stages" / "last").exists()

    monkeypatch.undo()
    assert main(["-q", *_args(blob8, out)]) == 0  # the last run's settings: its restored result is reused
    assert _ran(out) == [] and (out / "mesh.ply").read_bytes() == before["mesh.ply"]
    assert main(["-q", *changed]) == 0
    assert _ran(out) == ["fusion", "preview", "model"] and (out / "mesh.ply").read_bytes() != before["mesh.ply"]


def test_a_colmap_database_opened_to_read_is_unchanged_for_its_record(tmp_path):
    """pycolmap counts a change in the SQLite header of a database it opens only to read it: not a change of
    the matching stage's output (else every SfM re-run would match again); a changed page is one."""
    pycolmap = pytest.importorskip("pycolmap")
    from photorecon.stages import sha256_file

    db = tmp_path / "database.db"
    pycolmap.Database.open(str(db)).close()
    before, raw = sha256_file(db), db.read_bytes()
    pycolmap.Database.open(str(db)).close()
    assert db.read_bytes() != raw and sha256_file(db) == before
    data = bytearray(db.read_bytes())
    data[len(data) // 2] ^= 1
    db.write_bytes(bytes(data))
    assert sha256_file(db) != before
