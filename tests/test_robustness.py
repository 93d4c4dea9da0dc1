"""Robustness under the inputs people really have: outputs that hold their inputs, two runs on one output,
damaged and unusual image files, a full disk, rounded camera files, results in another frame than the truth.
Small synthetic inputs; every refusal is checked to leave the inputs byte for byte as they were."""
import json
import logging
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import tree_hash
from photorecon.cli import main
from photorecon.errors import BadArgumentError, OutputError

ROOT = Path(__file__).resolve().parents[1]


def _cli(*args, timeout=120):
    """photorecon in a fresh process (its own PID, signals, exit code)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-m", "photorecon", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=timeout, cwd=ROOT)


@pytest.fixture
def ds(blob_small, tmp_path):
    """A private copy of the small synthetic dataset (a photorecon output: synth wrote it)."""
    dst = tmp_path / "DS"
    shutil.copytree(blob_small, dst)
    return dst


def _error_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert lines, "no error message"
    return lines[-1]


# --- an output never writes into, replaces or deletes an input -----------------------------------------------------
@pytest.mark.parametrize("argv", [
    ["reconstruct", "{DS}/images", "-o", "{DS}"],
    ["reconstruct", "{DS}/images", "-o", "{DS}", "--overwrite"],
    ["sfm", "{DS}/images", "-o", "{DS}"],
    ["reconstruct", "{DS}/images", "-o", "{DS}/..", "--overwrite"],
    ["fuse", "{DS}", "-o", "{DS}/.."],
    ["reconstruct", "{DS}/images", "-o", "{tmp}/out", "--depth", "{tmp}/out/depth_in"],
])
def test_output_holding_an_input_is_refused_and_input_unchanged(ds, tmp_path, capsys, argv):
    (tmp_path / "out" / "depth_in").mkdir(parents=True)
    argv = [a.format(DS=ds, tmp=tmp_path) for a in argv]
    before = tree_hash(tmp_path)
    assert main(argv) == OutputError.exit_code
    msg = capsys.readouterr().err.strip()
    assert len(msg.splitlines()) == 1 and "input" in msg and "outside" in msg, msg
    assert tree_hash(tmp_path) == before


def test_user_folder_with_images_and_overwrite_is_refused(tmp_path, blob_small, capsys):
    """A user's project folder (not written by photorecon) holding the photos in images/: ``-o proj
    --overwrite`` would replace them by undistorted copies."""
    proj = tmp_path / "proj"
    shutil.copytree(blob_small / "images", proj / "images")
    (proj / "notes.txt").write_text("mine")
    before = tree_hash(proj)
    assert main(["reconstruct", str(proj / "images"), "-o", str(proj), "--overwrite"]) == 8
    assert "outside" in capsys.readouterr().err
    assert tree_hash(proj) == before


@pytest.mark.slow
def test_overwrite_never_replaces_a_file_photorecon_did_not_write(ds, tmp_path, capsys):
    """--overwrite on a folder photorecon did not write: refused when a path photorecon would write is there
    (named in the message), allowed next to unrelated files, which stay as they were."""
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "mesh.ply").write_text("my own mesh")
    (foreign / "notes.txt").write_text("mine")
    before = tree_hash(foreign)
    assert main(["fuse", str(ds), "-o", str(foreign), "--overwrite"]) == 8
    err = capsys.readouterr().err
    assert "mesh.ply" in err and "--overwrite never replaces" in err
    assert tree_hash(foreign) == before
    (foreign / "mesh.ply").unlink()
    assert main(["-q", "fuse", str(ds), "-o", str(foreign), "--overwrite"]) == 0
    assert (foreign / "notes.txt").read_text() == "mine" and (foreign / "mesh.ply").stat().st_size > 1000


@pytest.mark.parametrize("cmd,out", [("mvs", "images"), ("mvs", "."), ("mvs", ".."), ("mvs", "masks"),
                                     ("texture", "images"), ("texture", "sparse/0")])
def test_dataset_commands_refuse_an_output_over_the_dataset_inputs(ds, cmd, out, capsys):
    before = tree_hash(ds.parent)
    assert main([cmd, str(ds), "-o", str(ds / out)]) == 8
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert tree_hash(ds.parent) == before


def test_mvs_output_never_replaces_files_photorecon_did_not_write(ds, tmp_path, capsys):
    """``mvs -o DIR`` writes NAME.png previews: a folder of the user's own PNGs with those names is refused."""
    photos = tmp_path / "photos"
    photos.mkdir()
    shutil.copy(ds / "images" / "view_000.png", photos / "view_000.png")
    before = tree_hash(photos)
    assert main(["mvs", str(ds), "-o", str(photos)]) == 8
    assert "view_000.png" in capsys.readouterr().err
    assert tree_hash(photos) == before


def test_eval_refuses_to_write_over_its_inputs(ds, capsys):
    before = tree_hash(ds)
    gt = str(ds / "gt_mesh.ply")
    for extra in (["--error-mesh", gt], ["--json", gt]):
        assert main(["eval", "--mesh", gt, "--gt", gt, *extra]) == 8
        assert "would replace an input" in capsys.readouterr().err
    assert tree_hash(ds) == before


# --- one run per output folder; a stage is complete only with all its outputs --------------------------------------
@pytest.mark.slow
def test_second_run_on_a_locked_output_names_the_holder_and_exits_8(tmp_path):
    """Two runs on one output: the second stops at once, naming the process that holds the folder, and
    writes nothing; the first's lock is untouched."""
    from photorecon.io.output import LOCK, output_lock

    out = tmp_path / "out"
    out.mkdir()
    with output_lock(out):
        info = json.loads((out / LOCK).read_text())
        assert info["pid"] == os.getpid() and info["host"] == socket.gethostname()
        r = _cli("synth", "-o", out, "--views", "2", "--width", "32", "--height", "24", "--points", "10")
        assert r.returncode == 8, r.stderr
        line = _error_line(r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
        assert f"process {os.getpid()}" in line and "in use" in line
        assert sorted(p.name for p in out.iterdir()) == [LOCK]
    assert not (out / LOCK).exists()  # released


@pytest.mark.slow
def test_two_concurrent_runs_on_one_output_the_second_exits_8(tmp_path, blob_small):
    """A run started on an output while another writes it (here sfm while synth renders): it exits 8 naming
    the first's process id and writes nothing; the first completes its output and removes the lock."""
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    second_args = ["sfm", str(blob_small / "images"), "-o", str(out)]
    # the second process imports photorecon first, then starts as soon as the first holds the lock
    second = subprocess.Popen(
        [sys.executable, "-c", "import sys, time, pathlib; from photorecon.cli import build_parser, main\n"
         "build_parser()\n"  # every command's imports done before the wait
         f"lock = pathlib.Path({str(out / '.photorecon.lock')!r})\n"
         "t = time.time()\nwhile not lock.exists() and time.time() - t < 60: time.sleep(0.005)\n"
         f"sys.exit(main({second_args!r}))"], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
        env=env, cwd=ROOT)
    first = subprocess.Popen([sys.executable, "-m", "photorecon", "synth", "-o", str(out), "--views", "16",
                              "--width", "320", "--height", "240", "--points", "50"],
                             stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, env=env, cwd=ROOT)
    (c1, e1), (c2, e2) = [(p.wait(timeout=120), p.stderr.read()) for p in (first, second)]
    assert c1 == 0, e1
    assert c2 == 8, e2
    assert f"in use by another photorecon run (process {first.pid} on" in e2
    assert len(list((out / "images").glob("*.png"))) == 16 and not (out / ".photorecon.lock").exists()
    assert not (out / "colmap").exists()


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_lock_of_a_dead_process_is_taken_over(tmp_path, caplog):
    from photorecon.io.output import LOCK

    out = tmp_path / "out"
    out.mkdir()
    pid = _dead_pid()
    (out / LOCK).write_text(json.dumps({"pid": pid, "host": socket.gethostname(), "started": "yesterday"}))
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        assert main(["-q", "synth", "-o", str(out), "--views", "2", "--width", "32", "--height", "24",
                     "--points", "10"]) == 0
    assert any(f"process {pid}" in r.getMessage() and "no longer running" in r.getMessage() for r in caplog.records)
    assert len(list((out / "images").glob("*.png"))) == 2
    assert not (out / LOCK).exists()


def test_lock_without_flock_decides_by_process_id(tmp_path, monkeypatch):
    """On a file system without flock the process id decides: a live one holds the folder, a dead one's lock
    (or one without a process id) is taken over."""
    from photorecon.io import output

    monkeypatch.setattr(output, "fcntl", None)
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / output.LOCK).write_text(json.dumps({"pid": holder.pid, "host": socket.gethostname()}))
        with pytest.raises(OutputError, match=f"process {holder.pid} on"):
            with output.output_lock(out):
                pass
    finally:
        holder.kill()
        holder.wait()
    for stale in ({"pid": holder.pid, "host": socket.gethostname()}, {}):
        (out / output.LOCK).write_text(json.dumps(stale))
        with output.output_lock(out):
            assert json.loads((out / output.LOCK).read_text())["pid"] == os.getpid()
        assert not (out / output.LOCK).exists()


@pytest.mark.slow
def test_lock_is_released_on_error_and_interrupt(tmp_path):
    from photorecon.io.output import LOCK, output_folder

    out = tmp_path / "out"
    for exc in (KeyboardInterrupt(), OutputError("boom")):
        with pytest.raises(type(exc)):
            with output_folder(out):
                assert (out / LOCK).exists()
                raise exc
        assert not (out / LOCK).exists()
    r = _cli("synth", "-o", out, "--views", "2", "--width", "32", "--height", "24", "--points", "10")
    assert r.returncode == 0, r.stderr


def test_stage_without_its_outputs_is_not_marked_complete(tmp_path):
    from photorecon.stages import Stages

    stages = Stages(tmp_path / ".stages")
    (tmp_path / "empty").mkdir()
    with pytest.raises(OutputError, match="empty"):
        stages.run("s", {}, lambda: None, outputs=[tmp_path / "empty"])
    assert not (tmp_path / ".stages" / "s.json").exists()
    # an optional output may be missing; a required one present completes the stage
    (tmp_path / "a.txt").write_text("x")
    stages.run("s", {}, lambda: None, outputs=[tmp_path / "a.txt", tmp_path / "masks"], optional=[tmp_path / "masks"])
    assert (tmp_path / ".stages" / "s.json").exists()


def test_depth_stage_needs_every_view_it_reports(tmp_path):
    from photorecon.layout import Layout
    from photorecon.pipeline import _check_depth_written

    layout = Layout(tmp_path)
    layout.depth.mkdir()
    np.save(layout.depth_map("a"), np.ones((2, 2), np.float32))
    np.save(layout.depth / "b.conf.npy", np.ones((2, 2), np.float32))
    _check_depth_written(layout, 1, ["a"])
    with pytest.raises(OutputError, match="b.npy"):
        _check_depth_written(layout, 2, ["a", "b"])
    with pytest.raises(OutputError, match="2 depth maps"):
        _check_depth_written(layout, 2)


# --- rounded rotations in camera files -----------------------------------------------------------------------------
def _blender_file(tmp_path, matrices):
    from PIL import Image

    (tmp_path / "train").mkdir(parents=True)
    frames = []
    for i, M in enumerate(matrices):
        Image.new("RGB", (40, 30)).save(tmp_path / "train" / f"r_{i}.png")
        frames.append({"file_path": f"./train/r_{i}", "transform_matrix": np.asarray(M).tolist()})
    path = tmp_path / "transforms_train.json"
    path.write_text(json.dumps({"camera_angle_x": 0.69, "frames": frames}))
    return path


def test_float32_rounded_rotations_are_accepted_and_snapped(tmp_path):
    """NeRF-synthetic's transforms_train.json holds rotations computed in float32 (Blender lego: deviations up
    to ~1e-5): read as the nearest rotation; a scaled matrix (1 %) is still refused, naming the frame."""
    from scipy.spatial.transform import Rotation

    from photorecon.errors import InputDataError
    from photorecon.io.dataset import read_model

    rng = np.random.default_rng(0)
    exact = []
    for k in range(3):
        M = np.eye(4)
        M[:3, :3] = Rotation.random(random_state=k).as_matrix()
        M[:3, 3] = rng.normal(size=3) * 4
        exact.append(M)
    rounded = [M.astype(np.float32).astype(np.float64) for M in exact]
    rounded[1][:3, :3] += rng.normal(scale=2e-5, size=(3, 3))  # a few-digit export: deviation ~1e-5 .. 1e-4
    dev = max(np.abs(M[:3, :3].T @ M[:3, :3] - np.eye(3)).max() for M in rounded)
    assert 1e-6 < dev < 1e-3
    views = read_model(_blender_file(tmp_path / "ok", rounded)).views
    for k, (v, M) in enumerate(zip(views, exact)):
        R = v.cam_from_world[:3, :3]
        # float32 rounding alone (~1e-7) is within ORTHO_TOL and kept; the larger deviation is snapped
        assert np.abs(R.T @ R - np.eye(3)).max() < (1e-12 if k == 1 else 1e-6) and np.linalg.det(R) > 0
        c2w_gl = np.linalg.inv(v.cam_from_world)  # camera centre back in the file's world
        assert np.allclose(c2w_gl[:3, 3], M[:3, 3], atol=1e-5)
    scaled = [M.copy() for M in exact]
    scaled[2][:3, :3] *= 1.01
    with pytest.raises(InputDataError, match="frame 2.*orthonormal.*scale or shear"):
        read_model(_blender_file(tmp_path / "bad", scaled))


def test_rotation_snapping_keeps_exact_rotations_and_refuses_reflections():
    from photorecon._validate import as_rigid, as_rotation

    R = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert as_rotation(R) is not None and np.array_equal(as_rotation(R), R)
    T = np.eye(4)
    T[:3, :3] = R + 3e-5
    S = as_rigid(T)
    assert np.abs(S[:3, :3] - R).max() < 1e-4 and np.abs(S[:3, :3].T @ S[:3, :3] - np.eye(3)).max() < 1e-12
    assert np.array_equal(T[:3, :3], R + 3e-5)  # the caller's array is left as it was
    with pytest.raises(BadArgumentError, match="det"):
        as_rotation(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(BadArgumentError, match="scale or shear"):
        as_rotation(np.array([[1.0, 0.01, 0], [0, 1, 0], [0, 0, 1]]))


# --- truncated photos ----------------------------------------------------------------------------------------------
def _jpeg_folder(src, dst, n=None):
    import cv2

    dst.mkdir(parents=True)
    for p in sorted(src.glob("*.png"))[:n]:
        cv2.imwrite(str(dst / f"{p.stem}.jpg"), cv2.imread(str(p)), [cv2.IMWRITE_JPEG_QUALITY, 95])
    return dst


def _truncate(path, fraction=0.5):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])


def test_truncated_jpeg_is_skipped_at_ingest_with_a_warning(blob_small, tmp_path, caplog):
    """OpenCV decodes a JPEG cut in half without an error (grey rows from the cut on): ingest finds it with a
    full decode and skips it, naming it in one warning line; a cut PNG the same way."""
    import cv2

    from photorecon.ingest import ingest_folder

    photos = _jpeg_folder(blob_small / "images", tmp_path / "photos", 4)
    shutil.copy(blob_small / "images" / "view_005.png", photos / "view_005.png")
    _truncate(photos / "view_001.jpg")
    _truncate(photos / "view_005.png", 0.6)
    assert cv2.imread(str(photos / "view_001.jpg")) is not None  # what the check exists for
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        ing = ingest_folder(photos, tmp_path / "work")
    assert [im.name for im in ing.images] == ["view_000.jpg", "view_002.jpg", "view_003.jpg"]
    warn = [r.getMessage() for r in caplog.records if "truncated" in r.getMessage()]
    assert len(warn) == 1 and "view_001.jpg" in warn[0] and "view_005.png" in warn[0] and "\n" not in warn[0]
    assert sorted(p.name for p in (tmp_path / "work").iterdir()) == ["view_000.jpg", "view_002.jpg", "view_003.jpg"]


def test_too_few_complete_photos_is_the_usual_error(blob_small, tmp_path):
    from photorecon.errors import NoImagesError
    from photorecon.ingest import ingest_folder

    photos = _jpeg_folder(blob_small / "images", tmp_path / "photos", 3)
    for p in list(photos.iterdir())[:2]:
        _truncate(p)
    with pytest.raises(NoImagesError, match="1 readable image"):
        ingest_folder(photos, tmp_path / "work", min_images=2)


def test_photos_in_subfolders_are_named_in_the_error_and_in_a_warning(blob_small, tmp_path, caplog):
    """A project folder (photos in images/, next to masks/) or a camera card (DCIM/100CANON, DCIM/101CANON):
    the error says which folder to pass; photos beside subfolders of photos are used, with one warning that
    names what is not read."""
    from photorecon.cli import main
    from photorecon.errors import NoImagesError
    from photorecon.ingest import ingest_folder

    with pytest.raises(NoImagesError, match=r"its subfolder images/ holds 12 image\(s\): pass .*images$"):
        ingest_folder(blob_small, tmp_path / "work")  # images/, masks/ and depth/ previews: images/ is meant
    card = tmp_path / "DCIM"
    _jpeg_folder(blob_small / "images", card / "100CANON", 3)
    _jpeg_folder(blob_small / "images", card / "101CANON", 2)
    with pytest.raises(NoImagesError, match=r"its subfolders 100CANON/ \(3\), 101CANON/ \(2\) hold images"):
        ingest_folder(card, tmp_path / "work2")
    assert main(["-q", "reconstruct", str(card), "-o", str(tmp_path / "out")]) == 4
    assert not (tmp_path / "out").exists()
    for p in list((card / "101CANON").iterdir()):
        shutil.move(p, card / p.name)
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        ing = ingest_folder(card, tmp_path / "work3")
    assert len(ing.images) == 2
    warn = [r.getMessage() for r in caplog.records if "subfolders" in r.getMessage()]
    assert len(warn) == 1 and "100CANON/: 3" in warn[0] and "only the 2 photo(s)" in warn[0], warn


def test_given_poses_skip_a_truncated_photo_naming_it(blob_small, tmp_path, caplog):
    from photorecon.errors import InputDataError
    from photorecon.io.dataset import read_model
    from photorecon.poses.ingest import ingest_given

    photos = _jpeg_folder(blob_small / "images", tmp_path / "photos")
    _truncate(photos / "view_004.jpg")
    model = read_model(blob_small / "sparse" / "0")
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        out = ingest_given(model, photos, tmp_path / "out")
    assert [v.name for v in out.views] == [v.name for v in model.views if v.name != "view_004"]
    assert any("view_004.jpg" in r.getMessage() and "truncated" in r.getMessage() for r in caplog.records)
    assert not (tmp_path / "out" / "images" / "view_004.png").exists()
    for p in list(photos.iterdir()):
        if p.name != "view_000.jpg":
            _truncate(p)
    with pytest.raises(InputDataError, match="1 usable image.*truncated or damaged"):
        ingest_given(model, photos, tmp_path / "out2")


def test_given_poses_name_every_missing_photo_in_one_line_and_write_nothing(blob_small, tmp_path):
    from photorecon.errors import InputDataError
    from photorecon.io.dataset import read_model
    from photorecon.poses.ingest import ingest_given

    photos = _jpeg_folder(blob_small / "images", tmp_path / "photos", 9)  # views 9, 10 and 11 have no photo
    model = read_model(blob_small / "sparse" / "0")
    with pytest.raises(InputDataError) as exc:
        ingest_given(model, photos, tmp_path / "out")
    msg = str(exc.value)
    assert msg.startswith("view view_009: image view_009")
    assert "3 of the 12 views' images are not there: view_009, view_010, view_011" in msg
    assert "pass the folder that holds the photos" in msg and "\n" not in msg
    assert not (tmp_path / "out").exists()


# --- every listed image format works end to end --------------------------------------------------------------------
def test_webp_photos_are_ingested_as_png_copies(blob_small, tmp_path):
    """COLMAP's reader cannot decode WebP: ingest writes a PNG copy (NAME.png, or NAME.webp.png when a photo
    is already named NAME.png), pixels and alpha as decoded, and records the photo's name."""
    import cv2
    from PIL import Image

    from photorecon.ingest import ingest_folder

    photos = tmp_path / "photos"
    photos.mkdir()
    rgb = cv2.imread(str(blob_small / "images" / "view_000.png"))[..., ::-1]
    Image.fromarray(rgb).save(photos / "a.webp", lossless=True)
    Image.fromarray(rgb).save(photos / "b.webp", lossless=True)
    shutil.copy(blob_small / "images" / "view_001.png", photos / "b.png")
    alpha = np.zeros(rgb.shape[:2], np.uint8)
    alpha[20:80, 30:120] = 255
    Image.fromarray(np.dstack([rgb, alpha])).save(photos / "c.webp", lossless=True)
    ing = ingest_folder(photos, tmp_path / "work")
    assert sorted(im.name for im in ing.images) == ["a.png", "b.png", "b.webp.png", "c.png"]
    assert ing.renamed == {"a.png": "a.webp", "b.webp.png": "b.webp", "c.png": "c.webp"}
    work = tmp_path / "work"
    assert np.array_equal(cv2.imread(str(work / "a.png"))[..., ::-1], rgb)
    assert np.array_equal(cv2.imread(str(work / "b.png")), cv2.imread(str(photos / "b.png")))  # the PNG as it was
    assert np.array_equal(cv2.imread(str(work / "c.png"), cv2.IMREAD_UNCHANGED)[..., 3], alpha)


def test_heic_photos_are_ingested_upright_as_png_copies_with_their_focal_length(blob_small, tmp_path):
    """An iPhone's HEIC photos: decoded (pillow-heif), turned upright by their EXIF orientation, written as PNG
    copies for COLMAP, with the focal length prior from their EXIF; given cameras read them too."""
    import cv2
    from PIL import Image

    from photorecon.io.dataset import read_model
    from photorecon.io.images import register_heif
    from photorecon.ingest import ingest_folder
    from photorecon.poses.ingest import ingest_given

    assert register_heif()
    photos = tmp_path / "photos"
    photos.mkdir()
    rgb = cv2.imread(str(blob_small / "images" / "view_000.png"))[..., ::-1]  # 160x120
    exif = Image.Exif()
    exif[0x8769] = {0xA405: 28}  # 28 mm equivalent focal length
    Image.fromarray(rgb).save(photos / "IMG_0001.HEIC", quality=95, exif=exif.tobytes())
    exif[0x0112] = 6  # stored lying on its side; shown rotated 90 degrees clockwise
    Image.fromarray(np.rot90(rgb)).save(photos / "IMG_0002.heic", quality=95, exif=exif.tobytes())
    ing = ingest_folder(photos, tmp_path / "work")
    assert [im.name for im in ing.images] == ["IMG_0001.png", "IMG_0002.png"]
    assert ing.renamed == {"IMG_0001.png": "IMG_0001.HEIC", "IMG_0002.png": "IMG_0002.heic"}
    for im in ing.images:
        got = cv2.imread(str(tmp_path / "work" / im.name))[..., ::-1].astype(float)
        assert got.shape == rgb.shape and (im.width, im.height) == (160, 120)
        err, turned = np.abs(got - rgb).mean(), np.abs(got - rgb[::-1, ::-1]).mean()
        assert err < 8 and err < turned / 3, (err, turned)  # lossy, but this picture, this way up
        assert im.focal_prior_px == pytest.approx(28 / 36 * 160, rel=1e-6)
    # given cameras whose photos are HEIC
    given = tmp_path / "given"
    given.mkdir()
    model = read_model(blob_small / "sparse" / "0")
    for v in model.views[:3]:
        img = cv2.imread(str(blob_small / "images" / f"{v.name}.png"))[..., ::-1]
        Image.fromarray(img).save(given / f"{v.name}.heic", quality=95)
    model.views = model.views[:3]
    out = ingest_given(model, given, tmp_path / "out")
    first = cv2.imread(str(tmp_path / "out" / "images" / "view_000.png"))[..., ::-1].astype(float)
    assert len(out.views) == 3 and np.abs(first - rgb).mean() < 8


def test_gps_of_heic_photos_is_read_for_metric_scale(tmp_path):
    """An iPhone's HEIC photos carry its GPS fix: ``read_gps`` reads it as it does a JPEG's."""
    from PIL import Image

    from photorecon.io.images import register_heif
    from photorecon.poses.scale import read_gps

    assert register_heif()
    exif = Image.Exif()
    exif[0x8825] = {1: "N", 2: (48.0, 8.0, 24.0), 3: "E", 4: (11.0, 34.0, 12.0), 5: 0, 6: 520.5}
    Image.new("RGB", (64, 48), (90, 120, 60)).save(tmp_path / "IMG_0001.HEIC", quality=90, exif=exif.tobytes())
    lat, lon, alt = read_gps(tmp_path / "IMG_0001.HEIC")
    assert lat == pytest.approx(48.14) and lon == pytest.approx(11.57) and alt == pytest.approx(520.5)


@pytest.mark.slow
def test_sfm_registers_webp_photos_among_pngs(ring16, tmp_path):
    """Half the photos WebP (lossless), half PNG: every photo registers, with poses as accurate as the PNGs'."""
    from PIL import Image

    from photorecon.io.dataset import read_model
    from photorecon.metrics import pose_metrics
    from photorecon.sfm import run_sfm

    photos = tmp_path / "photos"
    photos.mkdir()
    for k, p in enumerate(sorted((ring16 / "images").glob("*.png"))):
        if k % 2:
            Image.open(p).save(photos / f"{p.stem}.webp", lossless=True)
        else:
            shutil.copy(p, photos / p.name)
    before = tree_hash(photos)
    res = run_sfm(photos, tmp_path / "out")
    assert len(res.registered) == 16 and not res.unregistered
    est = read_model(tmp_path / "out" / "sparse" / "0")
    assert sorted(v.image_file for v in est.views) == sorted(f"view_{k:03d}.png" for k in range(16))
    m = pose_metrics(est.views, read_model(ring16 / "sparse" / "0").views)
    assert m["registered"] == 16 and m["rot_mean_deg"] < 0.3, m
    assert tree_hash(photos) == before


# --- a full disk ---------------------------------------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    """``small_disk(size)``: a fresh tmpfs of ``size`` (e.g. "2500k") mounted in the test's folder; skipped
    where mounting is not permitted (not root, or in a container without the capability)."""
    mounted = []

    def make(size):
        if os.geteuid() != 0 or not shutil.which("mount"):
            pytest.skip("mounting a small tmpfs needs root")
        mnt = tmp_path / f"disk_{size}"
        mnt.mkdir()
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], capture_output=True,
                           text=True)
        if r.returncode:
            pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
        mounted.append(mnt)
        return mnt

    yield make
    for m in mounted:
        subprocess.run(["umount", "-l", str(m)], capture_output=True)


def _hidden_files(folder):
    return [p for p in folder.rglob(".*") if p.is_file() and p.name not in (".photorecon",)
            and ".stages" not in p.parts and ".mvs_work" not in p.parts]


def test_full_disk_before_sfm_features_is_one_line_and_exit_8(blob_small, small_disk, capsys):
    """SfM on a disk too small for the feature database: refused before COLMAP's SQLite writer (which aborts
    the process on a full disk) starts, one line naming the file and the device; the temporary databases an
    aborted run left are removed."""
    disk = small_disk("2500k")
    out = disk / "out"
    (out / "colmap").mkdir(parents=True)
    (out / ".photorecon").write_text("written by photorecon\n")
    for name in (".features.abc123.db", ".features.abc123.db-journal", ".database.x.db-wal",
                 ".features_upsampled.k2.db-wal", ".database_upsampled.k3.db", ".upscaledq1/0/images/v.png",
                 ".sparse_upsampled.partial/images.bin"):
        (out / "colmap" / name).parent.mkdir(parents=True, exist_ok=True)
        (out / "colmap" / name).write_bytes(b"\0" * 1000)  # what an aborted run leaves
    assert main(["-q", "sfm", str(blob_small / "images"), "-o", str(out)]) == 8
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "features.db: no space left on device" in err and str(disk) in err and "tmpfs" in err
    assert not (out / "colmap" / "features.db").exists() and _hidden_files(out) == []


@pytest.mark.slow
def test_space_check_of_upsampled_sift_covers_the_copies_and_the_features(blob_small, tmp_path, monkeypatch):
    """The second SIFT pass (small photos, 2x upsampled copies) writes the copies and about twice the features:
    the space checked before COLMAP's writer starts (it aborts the process on a full disk) covers both."""
    from photorecon.poses import extract as extraction  # the module where extract looks up what is patched
    from photorecon.poses.sfm import SfMConfig

    names = sorted(p.name for p in (blob_small / "images").iterdir())
    checked, copies = [], []
    monkeypatch.setattr(extraction, "check_space", lambda path, need: checked.append(need))
    upscaled = extraction._upscaled_copies

    def measured(images_dir, mask_dir, names, s, dst):
        masks = upscaled(images_dir, mask_dir, names, s, dst)
        copies.append(sum(f.stat().st_size for f in dst.rglob("*") if f.is_file()))
        return masks

    monkeypatch.setattr(extraction, "_upscaled_copies", measured)
    cams = [{"model": "SIMPLE_RADIAL", "params": "", "images": names, "size": [160, 120], "sift_upscale": 2}]
    db = extraction.extract(blob_small / "images", tmp_path / "features_upsampled.db", cams, SfMConfig(threads=1))
    written = copies[0] + db.stat().st_size
    assert checked[0] >= written, (checked, copies, db.stat().st_size)
    assert checked[0] > extraction.features_bytes(blob_small / "images", names, SfMConfig())


def test_full_disk_during_mvs_is_one_line_and_keeps_no_partial_file(blob_small, small_disk, capsys):
    """numpy's short write (``OSError: N requested and M written``, no errno) on a full disk: the output error
    (exit 8) naming the file and the device, and no half-written file left."""
    disk = small_disk("120k")
    assert main(["-q", "mvs", str(blob_small), "-o", str(disk / "depth"), "--max-size", "160"]) == 8
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert ".npy: no space left on device" in err and str(disk) in err
    assert _hidden_files(disk) == []
    for f in disk.rglob("*.npy"):  # what is kept (finished tasks, for a re-run) is whole
        np.load(f)


def test_write_over_a_file_size_limit_is_the_no_space_error(tmp_path):
    """Without root: RLIMIT_FSIZE (SIGXFSZ ignored) makes writes fail with EFBIG, as a full quota would;
    atomic writes turn that into the one-line OutputError and remove their temporary file."""
    script = (
        "import resource, signal, sys, numpy as np\n"
        "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536))\n"
        "from photorecon.errors import OutputError\n"
        "from photorecon.io.atomic import atomic_path, atomic_write_text\n"
        "for how in ('npy', 'text'):\n"
        "    try:\n"
        "        if how == 'npy':\n"
        "            with atomic_path(sys.argv[1] + '/big.npy') as tmp:\n"
        "                np.save(tmp, np.zeros(100000, np.float32))\n"
        "        else:\n"
        "            atomic_write_text(sys.argv[1] + '/big.txt', 'x' * 200000)\n"
        "    except OutputError as exc:\n"
        "        print(exc)\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-c", script, str(tmp_path)], capture_output=True, text=True, env=env)
    lines = r.stdout.strip().splitlines()
    assert r.returncode == 0 and len(lines) == 2, r.stderr
    assert lines[0].startswith(f"{tmp_path}/big.npy: no space left on device")
    assert lines[1].startswith(f"{tmp_path}/big.txt: no space left on device")
    assert list(tmp_path.iterdir()) == []


# --- eval of a result in another frame than the truth --------------------------------------------------------------
@pytest.fixture
def result_in_sfm_frame(blob_small, tmp_path):
    """A reconstruct-like output whose mesh and cameras are the truth's moved by a similarity (as SfM's frame
    is): mesh.ply and sparse/0 in OUT, the truth with its cameras in DATA."""
    import trimesh
    from scipy.spatial.transform import Rotation

    from photorecon.io.colmap_text import write_colmap_text
    from photorecon.io.dataset import read_model
    from photorecon.scale import apply_similarity

    s, R, t = 0.25, Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix(), np.array([0.3, -0.1, 0.2])
    out = tmp_path / "OUT"
    out.mkdir()
    gt = trimesh.load(blob_small / "gt_mesh.ply", process=False)
    moved = gt.copy()
    moved.vertices = s * np.asarray(gt.vertices) @ R.T + t
    moved.export(out / "mesh.ply")
    write_colmap_text(apply_similarity(read_model(blob_small / "sparse" / "0"), s, R, t), out / "sparse" / "0")
    return out, blob_small


@pytest.fixture
def fewer_samples(monkeypatch):
    """eval's mesh metrics on 5,000 samples per mesh instead of 200,000 (distance queries from far-off samples
    take seconds each)."""
    import functools

    from photorecon import metrics

    monkeypatch.setattr(metrics, "mesh_metrics", functools.partial(metrics.mesh_metrics, n_samples=5000))


def test_eval_aligns_a_result_through_its_cameras(result_in_sfm_frame, fewer_samples, capsys):
    out, data = result_in_sfm_frame
    argv = ["eval", "--mesh", str(out / "mesh.ply"), "--gt", str(data / "gt_mesh.ply")]
    assert main(argv + ["--json", "-"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["alignment"]["views"] == 12 and rep["alignment"]["scale"] == pytest.approx(1 / 0.25, rel=1e-6)
    assert rep["mesh"]["fscore"] > 0.99 and "warnings" not in rep
    assert main(argv) == 0
    assert "aligned through the cameras: 12 shared views" in capsys.readouterr().out


def test_eval_warns_when_frames_differ_and_cannot_be_aligned(result_in_sfm_frame, fewer_samples, tmp_path, capsys):
    import argparse

    import trimesh

    from photorecon.evaluate import align_to_truth

    out, data = result_in_sfm_frame
    gt = str(data / "gt_mesh.ply")
    assert main(["eval", "--mesh", str(out / "mesh.ply"), "--gt", gt, "--no-align-poses", "--json", "-"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["mesh"]["fscore"] < 0.2 and "same frame" in rep["warnings"][0] and "alignment" not in rep
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(out / "mesh.ply", alone / "mesh.ply")  # no cameras beside it
    args = argparse.Namespace(mesh=str(alone / "mesh.ply"), gt=gt, poses=None, ref=None, align_poses=None)
    mesh, truth = trimesh.load(alone / "mesh.ply"), trimesh.load(gt)
    moved, alignment, warning = align_to_truth(mesh, truth, args)
    assert moved is mesh and alignment is None and "bounding box" in warning and "same frame" in warning
    assert align_to_truth(truth, truth, args)[2] is None  # the same frame: no warning
    # cameras given on the command line align it (the result's own, and the truth's)
    args.poses, args.ref = str(out / "sparse" / "0"), str(data / "sparse" / "0")
    moved, alignment, warning = align_to_truth(mesh, truth, args)
    assert alignment["views"] == 12 and warning is None
    assert np.abs(np.asarray(moved.vertices) - np.asarray(truth.vertices)).max() < 1e-6
    assert main(["eval", "--mesh", str(alone / "mesh.ply"), "--gt", gt, "--align-poses"]) == 2
    assert "no cameras beside" in capsys.readouterr().err


def test_eval_warns_when_a_result_without_cameras_lies_far_from_the_truth(blob_small, fewer_samples, tmp_path,
                                                                          capsys):
    """A mesh in another frame without cameras beside it, whose bounding box looks like the truth's (rotated,
    shifted by a third of its size): the F-score near 0 comes with a warning that the frames may differ."""
    import trimesh
    from scipy.spatial.transform import Rotation

    gt = trimesh.load(blob_small / "gt_mesh.ply", process=False)
    c = np.asarray(gt.vertices).mean(0)
    R = Rotation.from_euler("xyz", [70, 0, 120], degrees=True).as_matrix()
    moved = gt.copy()
    diag = np.linalg.norm(np.ptp(np.asarray(gt.vertices), axis=0))
    moved.vertices = (np.asarray(gt.vertices) - c) @ R.T + c + [diag / 3, 0, 0]
    moved.export(tmp_path / "mesh.ply")
    argv = ["eval", "--mesh", str(tmp_path / "mesh.ply"), "--gt", str(blob_small / "gt_mesh.ply"), "--json", "-"]
    assert main(argv) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["mesh"]["fscore"] < 0.3 and "far from the truth" in rep["warnings"][0], rep.get("warnings")
    gt.export(tmp_path / "same.ply")  # the truth itself: no warning
    assert main(["eval", "--mesh", str(tmp_path / "same.ply"), "--gt", str(blob_small / "gt_mesh.ply"), "--json", "-"]) == 0
    assert "warnings" not in json.loads(capsys.readouterr().out)


# --- damaged camera and depth files ---------------------------------------------------------------------------------
@pytest.mark.parametrize("cmd", ["fuse", "mvs", "convert"])
def test_camera_file_that_is_not_text_names_the_file_exit_3(ds, tmp_path, cmd, capsys):
    """A cameras.txt with bytes that are not UTF-8 (a binary file renamed, a damaged copy): exit 3, one line
    naming the file, the dataset unchanged and no output folder left."""
    (ds / "transforms.json").unlink()
    cams = ds / "sparse" / "0" / "cameras.txt"
    cams.write_bytes(cams.read_bytes() + b"\xff\xfe\x80\x00 binary\n")
    before = tree_hash(ds)
    out = tmp_path / "out"
    argv = {"fuse": [str(ds), "-o", str(out)], "mvs": [str(ds), "-o", str(out)],
            "convert": [str(ds / "sparse" / "0"), str(tmp_path / "out.json")]}[cmd]
    assert main(["-q", cmd, *argv]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{cams}: not a COLMAP text file" in err and "UTF-8" in err, err
    assert tree_hash(ds) == before and not out.exists()


def test_depth_map_far_smaller_than_its_camera_names_the_file_and_the_shape(ds, tmp_path, capsys):
    """A (5, 7) depth map for a 160x120 camera (its aspect ratio, but no working resolution): exit 3 naming the
    file and the expected shape, instead of Open3D's failure; no output folder left."""
    np.save(ds / "depth" / "view_003.npy", np.ones((5, 7), np.float32))
    out = tmp_path / "out"
    assert main(["-q", "fuse", str(ds), "-o", str(out)]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "view_003.npy has shape (5, 7)" in err and "(120, 160)" in err, err
    assert not out.exists()


def test_depth_maps_with_a_single_valid_pixel_are_an_empty_mesh(ds, tmp_path, capsys):
    """Depth maps of the right shape whose one valid pixel touches no TSDF block (Open3D refuses such a frame):
    the frame adds nothing, and with every view so the usual empty-mesh error (exit 7)."""
    for f in sorted((ds / "depth").glob("view_???.npy")):
        d = np.load(f)
        one = np.zeros_like(d)
        i, j = np.argwhere(d > 0)[len(np.argwhere(d > 0)) // 2]
        one[i, j] = d[i, j]
        np.save(f, one)
    assert main(["-q", "fuse", str(ds), "-o", str(tmp_path / "out")]) == 7
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no triangle" in err, err


def test_damaged_stage_marker_is_as_if_absent(tmp_path):
    """A stage marker with bytes that are not UTF-8 (a damaged disk): the stage runs again."""
    from photorecon.stages import Stages

    out = tmp_path / "o.txt"
    runs = []

    def make():
        runs.append(1)
        out.write_text("x")
        return {}

    Stages(tmp_path / ".stages").run("s", {"a": 1}, make, outputs=[out])
    (tmp_path / ".stages" / "s.json").write_bytes(b"\xff\xfe{\x00")
    Stages(tmp_path / ".stages").run("s", {"a": 1}, make, outputs=[out])
    assert len(runs) == 2


# --- kill -KILL: the same command resumes and gives the same mesh ------------------------------------------------
@pytest.mark.slow
def test_sigkill_during_depth_resumes_to_the_same_mesh(blob_small, tmp_path):
    """A run killed outright (no clean-up: SIGKILL, a power loss) during the depth stage: the same command
    takes over its lock, keeps the finished depth tasks and gives the mesh of a run never interrupted."""
    import signal
    import time

    import trimesh

    def argv(out):
        return [sys.executable, "-m", "photorecon", "-q", "reconstruct", str(blob_small / "images"), "-o", str(out),
                "--poses", str(blob_small / "transforms.json"), "--n-sources", "4", "--min-consistent", "1"]

    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "2"}
    ref = tmp_path / "ref"
    assert subprocess.run(argv(ref), env=env, capture_output=True, timeout=300).returncode == 0
    out = tmp_path / "out"
    proc = subprocess.Popen(argv(out), env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    work = out / ".work" / "depth"
    while not list(work.glob("*/*/*.npy")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before the depth stage wrote a task"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert (out / ".photorecon.lock").exists() and not (out / "mesh.ply").exists()
    res = subprocess.run([a for a in argv(out) if a != "-q"], env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "is no longer running; taking it over" in res.stderr
    a, b = (trimesh.load(d / "mesh.ply", process=False) for d in (ref, out))
    assert np.array_equal(_triangles(a), _triangles(b))  # the same triangles (the vertex order may differ)


def _triangles(mesh) -> np.ndarray:
    """A mesh's triangles as (F, 9) corner coordinates, each triangle's corners and the triangles in sorted order:
    equal for two meshes with the same triangles whatever their vertex numbering (TSDF's block hash order)."""
    tri = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]  # (F, 3, 3)
    order = np.lexsort(tri.transpose(2, 0, 1)[::-1], axis=-1)  # each triangle's corners by x, then y, then z
    tri = np.take_along_axis(tri, order[..., None], axis=1).reshape(len(tri), 9)
    return tri[np.lexsort(tri.T[::-1])]


@pytest.mark.parametrize("side", ["--mesh", "--gt"])
def test_eval_of_a_mesh_with_nan_vertices_names_them_and_exits_3(tmp_path, capsys, side):
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2)
    v = sphere.vertices.copy()
    v[[17, 30, 31]] = np.nan
    v[40, 2] = np.inf
    trimesh.Trimesh(v, sphere.faces, process=False).export(tmp_path / "bad.ply")
    sphere.export(tmp_path / "good.ply")
    files = {"--mesh": tmp_path / "good.ply", "--gt": tmp_path / "good.ply", side: tmp_path / "bad.ply"}
    assert main(["eval", "--mesh", str(files["--mesh"]), "--gt", str(files["--gt"])]) == 3
    line = _error_line(capsys.readouterr().err)
    assert "Traceback" not in line and "bad.ply" in line
    assert f"4 of {len(v)} vertices have NaN or infinite coordinates (the first: index 17)" in line


@pytest.mark.slow
def test_too_little_confirmed_depth_fails_loudly_with_its_own_message(blob_small, tmp_path, capsys):
    """A depth stage that confirms depth in a small fraction of the pixels makes a fragment of a mesh: exit 6 with
    a line saying how little, instead of a 'successful' run; --method sweep (a rough preview) says so."""
    out = tmp_path / "out"
    argv = ["reconstruct", str(blob_small / "images"), "--poses", str(blob_small / "sparse" / "0"), "-o", str(out),
            "--method", "sweep", "--min-depth-fraction", "0.5"]
    assert main(argv) == 6
    err = capsys.readouterr().err
    assert "--method sweep is a rough preview" in err  # the warning, before the depth stage runs
    line = _error_line(err)
    assert line.startswith("photorecon reconstruct: error: depth: only ")
    mean = float(line.split("only ")[1].split("%")[0])
    assert 0 < mean < 50 and "of the 12 views have a confirmed depth" in line and "at least 50% needed" in line
    assert "use --method patchmatch (the default)" in line
    assert not (out / "depth").exists() and not (out / "mesh.ply").exists()


def test_texture_of_a_folder_without_a_mesh_says_what_to_pass(ds, tmp_path, capsys):
    before = tree_hash(ds.parent)
    assert main(["texture", str(ds), "-o", str(tmp_path / "t")]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{ds}: no mesh.ply" in err and "--mesh" in err, err
    assert not (tmp_path / "t").exists() and tree_hash(ds.parent) == before
