"""The one output guard (photorecon.io.output), walked by every command that writes: a user's folder holding
other files, another command's result, the command's own input, a folder inside a result. Every refusal
exits 8 and leaves every file that was there byte for byte as it was. Small inputs: the refusals come before
any work; the accepted cases use the cheapest settings."""
import json
import logging
import shutil
import socket
import subprocess
import sys

import pytest

from conftest import tree_hash
from photorecon.cli import main
from photorecon.io.output import LOCK, MARKER, mark


@pytest.fixture
def scene(blob_small, tmp_path):
    """In tmp_path: DS (a synth dataset with a mesh.ply, the input), R (a reconstruct result, hand-made: the
    dataset's files, a mesh, a report and reconstruct's marker), U (a user's folder) and R/my_notes (a user's
    folder inside a result)."""
    ds = tmp_path / "DS"
    shutil.copytree(blob_small, ds)
    shutil.copy(ds / "gt_mesh.ply", ds / "mesh.ply")
    r = tmp_path / "R"
    shutil.copytree(ds, r)
    (r / MARKER).unlink()
    mark(r, "reconstruct")
    (r / "report.json").write_text('{"warnings": []}\n')
    (r / "preview.png").write_bytes(b"not really a png")
    u = tmp_path / "U"
    u.mkdir()
    (u / "notes.txt").write_text("mine")
    (u / "sketch.png").write_bytes(b"\x89PNG mine")
    shutil.copytree(u, r / "my_notes")
    return ds, r, u


# argv per command; {out}: the output (a folder, or a file for the commands that write one file)
COMMANDS = {
    "reconstruct": ["reconstruct", "{DS}/images", "-o", "{out}", "--poses", "{DS}/transforms.json"],
    "sfm": ["sfm", "{DS}/images", "-o", "{out}"],
    "mvs": ["mvs", "{DS}", "-o", "{out}"],
    "depth": ["depth", "{DS}", "--model", "{DS}/model.onnx", "-o", "{out}"],
    "fuse": ["fuse", "{DS}", "-o", "{out}"],
    "texture": ["texture", "{DS}", "-o", "{out}"],
    "synth": ["synth", "--mesh", "{DS}/gt_mesh.ply", "-o", "{out}", "--views", "2", "--width", "32", "--height",
              "24", "--points", "10"],
    "convert": ["convert", "{DS}/transforms.json", "{out}"],
    "convert-file": ["convert", "{DS}/sparse/0", "{out}"],
    "eval": ["eval", "--mesh", "{DS}/mesh.ply", "--gt", "{DS}/gt_mesh.ply", "--json", "{out}"],
    "view": ["view", "{DS}", "--html", "{out}"],
}
FILE_OUTPUT = {"convert-file": "t.json", "eval": "e.json", "view": "v.html"}
OWN_INPUT = {"reconstruct": "{DS}/images", "sfm": "{DS}/images", "mvs": "{DS}", "depth": "{DS}/images",
             "fuse": "{DS}", "texture": "{DS}", "synth": "{DS}/gt_mesh.ply", "convert": "{DS}/transforms.json",
             "convert-file": "{DS}/sparse/0/cameras.txt", "eval": "{DS}/mesh.ply", "view": "{DS}/v.html"}


def _out(cmd, case, tmp_path):
    """The output path for ``case``: (a) in/at the user's folder U, (b) at another command's result R,
    (c) the command's own input, (d) in a folder inside the result R."""
    if case == "c":
        return OWN_INPUT[cmd].format(DS=tmp_path / "DS")
    if cmd in FILE_OUTPUT:  # an existing file there: the user's, the result's, one in a result's folder
        return {"a": tmp_path / "U" / "notes.txt", "b": tmp_path / "R" / "report.json",
                "d": tmp_path / "R" / "sparse" / "0" / FILE_OUTPUT[cmd]}[case]
    return {"a": tmp_path / "U", "b": tmp_path / "R", "d": tmp_path / "R" / "my_notes"}[case]


@pytest.mark.parametrize("case", ["a", "b", "c", "d"])
@pytest.mark.parametrize("cmd", list(COMMANDS))
def test_every_command_refuses_what_it_did_not_write(scene, tmp_path, capsys, cmd, case):
    """(a) a user's folder holding other files, (b) another command's result, (c) its own input, (d) a
    folder inside a result (a user's, or a part of it: R/sparse/0): exit 8 with one line, every file as it was.
    Where the rule holds even with --overwrite ((b) a name taken, (c), (d) a part of a result) that is checked
    too."""
    if cmd == "reconstruct" and case == "b":  # another command's result for reconstruct: synth's dataset
        out = tmp_path / "DS"
    else:
        out = _out(cmd, case, tmp_path)
    argv = [a.format(DS=tmp_path / "DS", out=out) for a in COMMANDS[cmd]]
    before = tree_hash(tmp_path)
    assert main(["-q", *argv]) == 8, capsys.readouterr().err
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert tree_hash(tmp_path) == before
    # refused even with --overwrite: an input, a part of a result, a name the result already holds
    forced = case == "c" or (case == "d" and cmd in FILE_OUTPUT) or \
        (case == "b" and cmd not in ("mvs", "depth", "convert"))
    if forced:
        assert main(["-q", *argv, "--overwrite"]) == 8, cmd
        assert tree_hash(tmp_path) == before


@pytest.mark.parametrize("cmd", [pytest.param("fuse", marks=pytest.mark.slow),
                                 pytest.param("texture", marks=pytest.mark.slow), "synth", "convert"])
def test_overwrite_adds_next_to_a_users_files_and_keeps_them(scene, tmp_path, cmd):
    """--overwrite on a user's folder (also one inside a result): the command's files are added, the user's
    stay byte for byte; a re-run then replaces only its own files."""
    for out in (tmp_path / "U", tmp_path / "R" / "my_notes"):
        mine = {p.name: p.read_bytes() for p in out.iterdir()}
        argv = [a.format(DS=tmp_path / "DS", out=out) for a in COMMANDS[cmd]]
        if cmd == "texture":
            argv += ["--atlas-size", "256", "--target-faces", "500"]
        assert main(["-q", *argv, "--overwrite"]) == 0
        assert {p.name: p.read_bytes() for p in out.iterdir() if p.name in mine} == mine
        assert len(list(out.iterdir())) > len(mine) + 1  # its files and its marker
        assert main(["-q", *argv]) == 0  # now also the command's folder: a re-run needs no --overwrite
        assert {p.name: p.read_bytes() for p in out.iterdir() if p.name in mine} == mine


def test_texture_into_a_users_folder_in_a_result_names_the_files(scene, tmp_path, capsys):
    """``texture RESULT -o RESULT/my_notes``: refused, counting the user's two files (not the marker)."""
    r = tmp_path / "R"
    before = tree_hash(r)
    assert main(["texture", str(r), "-o", str(r / "my_notes")]) == 8
    err = capsys.readouterr().err
    assert "notes.txt and 1 more" in err and "--overwrite" in err
    assert tree_hash(r) == before


def test_another_commands_result_is_never_half_replaced(scene, tmp_path, capsys):
    """texture and synth into reconstruct's result: refused, and with --overwrite refused naming a file the
    other command wrote (preview.png / images)."""
    ds, r, _ = scene
    before = tree_hash(r)
    for argv, taken in ((["texture", str(ds), "-o", str(r)], "preview.png"),
                        (["synth", "-o", str(r), "--views", "2", "--width", "32", "--height", "24"], "images")):
        assert main(argv) == 8
        assert "result of photorecon reconstruct" in capsys.readouterr().err
        assert main([*argv, "--overwrite"]) == 8
        assert str(r / taken) in capsys.readouterr().err
    assert tree_hash(r) == before


def test_convert_onto_its_input_is_refused_and_to_a_new_file_is_lossless(scene, tmp_path, capsys):
    ds = scene[0]
    before = tree_hash(ds)
    assert main(["convert", str(ds / "transforms.json"), str(ds / "transforms.json")]) == 8
    assert "would replace an input" in capsys.readouterr().err
    assert main(["convert", str(ds / "sparse" / "0"), str(ds / "sparse" / "0"), "--overwrite"]) == 8
    assert tree_hash(ds) == before
    out = tmp_path / "copy.json"
    assert main(["-q", "convert", str(ds / "transforms.json"), str(out)]) == 0
    assert main(["-q", "convert", str(ds / "transforms.json"), str(out)]) == 8  # exists: --overwrite replaces
    assert main(["-q", "convert", str(ds / "transforms.json"), str(out), "--overwrite"]) == 0
    assert tree_hash(ds) == before


@pytest.mark.slow
def test_mvs_never_replaces_depth_maps_it_did_not_write(scene, tmp_path, capsys):
    """A dataset whose depth/ holds rendered ground truth: ``mvs DATASET`` refuses (even with --overwrite),
    saying -o; with -o a new folder in the dataset it writes there, says so, and the truth is unchanged."""
    ds = scene[0]
    truth = tree_hash(ds / "depth")
    for extra in ([], ["--overwrite"]):
        assert main(["mvs", str(ds), *extra]) == 8
        err = capsys.readouterr().err
        assert f"{ds / 'depth'}" in err and "synth" in err and "-o" in err
    out = ds / "mvs_depth"
    assert main(["mvs", str(ds), "-o", str(out), "--max-size", "80", "--n-sources", "3"]) == 0
    assert f"-> {out}" in capsys.readouterr().out
    assert len(list(out.glob("view_*[0-9].npy"))) >= 6 and tree_hash(ds / "depth") == truth
    assert main(["-q", "mvs", str(ds), "-o", str(out), "--max-size", "80", "--n-sources", "3"]) == 0  # its own


@pytest.mark.slow
def test_a_stale_lock_taken_over_is_listed_in_the_report(scene, tmp_path):
    ds = scene[0]
    out = tmp_path / "out"
    out.mkdir()
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    (out / LOCK).write_text(json.dumps({"pid": p.pid, "host": socket.gethostname(), "started": "yesterday"}))
    assert main(["-q", "reconstruct", str(ds / "images"), "-o", str(out), "--poses", str(ds / "transforms.json"),
                 "--depth", str(ds / "depth")]) == 0
    warnings = json.loads((out / "report.json").read_text())["warnings"]
    assert any(f"process {p.pid}" in w and "no longer running" in w for w in warnings), warnings


def test_a_failed_run_leaves_no_partial_result(scene, tmp_path, monkeypatch, caplog):
    """synth failing after 5 images: nothing of it is left (a new folder is removed); reconstruct failing in the
    poses stage after copying 5 images: no images/, no stage marker, no report; a stage that completed keeps
    its output."""
    from photorecon import synthetic
    from photorecon.poses import ingest
    from photorecon.stages import Stages

    calls = []
    real = synthetic.write_image

    def failing(path, img):
        calls.append(path)
        if len(calls) > 5:
            raise OSError(5, "Input/output error")
        return real(path, img)

    monkeypatch.setattr(synthetic, "write_image", failing)
    out = tmp_path / "s"
    assert main(["-q", "synth", "-o", str(out), "--views", "8", "--width", "32", "--height", "24"]) != 0
    assert not out.exists()
    monkeypatch.undo()

    ds = scene[0]
    real_undistort = ingest.ingest_given

    def half(model, images, dst, masks=None):
        (dst / "images").mkdir(parents=True, exist_ok=True)
        for p in sorted(images.iterdir())[:5]:
            shutil.copy(p, dst / "images" / p.name)
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(ingest, "ingest_given", half)
    rec = tmp_path / "rec"
    argv = ["-q", "reconstruct", str(ds / "images"), "-o", str(rec), "--poses", str(ds / "transforms.json"),
            "--depth", str(ds / "depth")]
    assert main(argv) != 0
    assert not (rec / "images").exists() and not (rec / ".stages" / "poses.json").exists()
    assert not (rec / "report.json").exists()
    monkeypatch.setattr(ingest, "ingest_given", real_undistort)
    assert real_undistort is not half

    stages = Stages(tmp_path / "st" / ".stages")
    a, b = tmp_path / "st" / "a", tmp_path / "st" / "b"
    stages.run("first", {}, lambda: a.mkdir() or (a / "x").write_text("x"), outputs=[a])

    def partial():
        b.mkdir()
        (b / "y").write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        stages.run("second", {}, partial, outputs=[a, b])
    assert (a / "x").read_text() == "x" and not b.exists()
