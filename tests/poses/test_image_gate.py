"""The image gate before SfM: every photo decoded once and checked (readable, EXIF orientation applied, a size
and shape COLMAP's SIFT takes, not one flat colour); what is left out named in one warning; no input on which
a library crashes reaches it. Also: implausible EXIF focal lengths, masks that exclude everything, names COLMAP's
text format cannot hold, videos with frames that do not decode."""
import logging
import subprocess
import sys

import cv2
import numpy as np
import pytest
from PIL import Image, ImageOps

from photorecon.errors import InputDataError, NoImagesError
from photorecon.poses.ingest import MAX_ASPECT, MIN_SIDE, ingest_folder, video_frames


def _noise(h, w, seed=0):
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (max(1, h // 4), max(1, w // 4), 3), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


def _warnings(caplog):
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


@pytest.fixture(scope="module")
def ring12(tmp_path_factory):
    """12 ring views of the blob at 240x180 (SfM in a few seconds)."""
    from photorecon.testing import synth_scene

    return synth_scene(tmp_path_factory, "gate_ring12", scene="blob", rig="ring", views=12, width=240, height=180,
                       points=300, seed=5)


def test_photos_sift_cannot_take_are_left_out_in_one_warning(tmp_path, caplog):
    """A 1x1 photo, a 20000x20 strip, a 2000x40 one (50:1), a flat grey one and a file that is no image, among
    good photos: only the good ones are ingested; one warning names each left-out file with its reason."""
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(3):
        cv2.imwrite(str(photos / f"good_{i}.jpg"), _noise(180, 240, i))
    cv2.imwrite(str(photos / "dot.png"), np.full((1, 1, 3), 200, np.uint8))
    cv2.imwrite(str(photos / "strip.png"), _noise(20, 20000))
    cv2.imwrite(str(photos / "narrow.jpg"), _noise(40, 2000))
    cv2.imwrite(str(photos / "grey.png"), np.full((180, 240, 3), 128, np.uint8))
    (photos / "broken.jpg").write_bytes(b"\xff\xd8\xff\xe0 not a jpeg")
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        ing = ingest_folder(photos, tmp_path / "work")
    assert [im.name for im in ing.images] == ["good_0.jpg", "good_1.jpg", "good_2.jpg"]
    assert sorted(p.name for p in (tmp_path / "work").iterdir()) == ["good_0.jpg", "good_1.jpg", "good_2.jpg"]
    assert sorted(ing.skipped) == ["broken.jpg", "dot.png", "grey.png", "narrow.jpg", "strip.png"]
    warn = _warnings(caplog)
    assert len(warn) == 1 and "\n" not in warn[0], warn
    w = warn[0]
    assert w.startswith("left out 5 of 8 file(s)")
    assert f"under {MIN_SIDE} pixels a side (too small for SIFT): dot.png (1x1), strip.png (20000x20)" in w, w
    assert f"longer than {MAX_ASPECT:g}:1 (too narrow for SIFT): narrow.jpg (2000x40)" in w, w
    assert "a single flat colour (nothing to match in them): grey.png" in w
    assert "not readable images: broken.jpg" in w


def test_the_sizes_that_crash_sift_are_left_out_and_an_oriented_one_is_judged_upright(tmp_path):
    """The limits where COLMAP's SIFT crashes (under 16 px a side as it works on the image): a photo of
    MIN_SIDE x MIN_SIDE passes, one pixel less does not; a 600x31 photo turned on its side by its EXIF is
    31 wide either way."""
    photos = tmp_path / "photos"
    photos.mkdir()
    cv2.imwrite(str(photos / "a_ok.png"), _noise(MIN_SIDE, MIN_SIDE))
    cv2.imwrite(str(photos / "b_small.png"), _noise(MIN_SIDE - 1, 100))
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(_noise(MIN_SIDE - 1, 600)).save(photos / "c_turned.jpg", exif=exif.tobytes(), quality=95)
    ing = ingest_folder(photos, tmp_path / "work")
    assert [im.name for im in ing.images] == ["a_ok.png"]
    assert sorted(ing.skipped) == ["b_small.png", "c_turned.jpg"]


_EXTRACT = """
import sys
from pathlib import Path
from photorecon.poses.sfm import SfMConfig, camera_groups, extract
from photorecon.poses.ingest import IngestedImage
d = Path(sys.argv[1])
cfg = SfMConfig(max_image_size=64, threads=1)
ims = [IngestedImage(p.name, p, *map(int, p.stem.split("x")[-2:])) for p in sorted((d / "images").iterdir())]
extract(d / "images", d / "features.db", camera_groups(ims, cfg), cfg)
print("extracted")
"""


def test_extraction_never_downsizes_a_photo_below_what_sift_takes(tmp_path):
    """A 640x32 photo passes the gate (20:1), but --max-image-size 64 would make it 64x3 for SIFT, where COLMAP
    crashes the process (SIGSEGV): extraction keeps its short side at 32 pixels. In a subprocess, so a crash
    is a failed test and not a dead test run."""
    (tmp_path / "images").mkdir()
    cv2.imwrite(str(tmp_path / "images" / "640x32.png"), _noise(32, 640))
    run = subprocess.run([sys.executable, "-c", _EXTRACT, str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and "extracted" in run.stdout, (run.returncode, run.stderr[-2000:])


@pytest.mark.slow
def test_reconstruct_leaves_out_the_photos_sift_would_crash_on(ring12, tmp_path):
    """A 1x1 photo and a 20000x20 strip among 12 good photos: `photorecon sfm` registers the 12, names the two
    in its warning, and does not crash in COLMAP's SIFT (exit 139 before)."""
    import shutil

    photos = tmp_path / "photos"
    shutil.copytree(ring12 / "images", photos)
    cv2.imwrite(str(photos / "dot.png"), np.full((1, 1, 3), 90, np.uint8))
    cv2.imwrite(str(photos / "strip.png"), _noise(20, 20000))
    run = subprocess.run([sys.executable, "-m", "photorecon", "sfm", str(photos), "-o", str(tmp_path / "out")],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, (run.returncode, run.stderr[-2000:])
    assert "dot.png (1x1)" in run.stderr and "strip.png (20000x20)" in run.stderr
    assert "12 of 12 images registered" in run.stderr + run.stdout


# --- EXIF focal lengths ---------------------------------------------------------------------------------------
def _focal_photos(src, dst, f35, n=None):
    dst.mkdir()
    for p in sorted(src.glob("*.png"))[:n]:
        exif = Image.Exif()
        exif.get_ifd(0x8769)[0xA405] = f35  # FocalLengthIn35mmFilm
        Image.open(p).convert("RGB").save(dst / f"{p.stem}.jpg", quality=95, exif=exif.tobytes())
    return dst


def test_an_implausible_exif_focal_length_is_not_a_prior(ring12, tmp_path, caplog):
    """10000 mm equivalent (a 0.2-degree field of view): the gate names the photos and gives no prior; the
    camera COLMAP makes from the same EXIF at extraction loses it too (COLMAP reads EXIF itself). 28 mm stays."""
    import pycolmap

    from photorecon.poses.sfm import SfMConfig, camera_groups, extract

    photos = _focal_photos(ring12 / "images", tmp_path / "photos", 10000, n=2)
    with caplog.at_level(logging.WARNING, logger="photorecon"):
        ing = ingest_folder(photos, tmp_path / "work")
    assert [im.focal_prior_px for im in ing.images] == [None, None]
    warn = [w for w in _warnings(caplog) if "EXIF focal length" in w]
    assert len(warn) == 1 and "view_000.jpg (1e+04 mm equivalent, 0.21 degrees across)" in warn[0], warn
    assert "view_001.jpg" in warn[0]
    cfg = SfMConfig(threads=1, max_features=500)
    extract(tmp_path / "work", tmp_path / "f.db", camera_groups(ing.images, cfg), cfg)
    db = pycolmap.Database.open(str(tmp_path / "f.db"))
    try:
        (cam,) = db.read_all_cameras()
    finally:
        db.close()
    assert not cam.has_prior_focal_length and cam.mean_focal_length() == pytest.approx(1.2 * 240)

    ok = _focal_photos(ring12 / "images", tmp_path / "photos28", 28, n=1)
    assert ingest_folder(ok, tmp_path / "work28").images[0].focal_prior_px == pytest.approx(28 / 36 * 240)


@pytest.mark.slow
def test_photos_with_a_10000_mm_exif_focal_length_reconstruct(ring12, tmp_path):
    """All 12 photos claim 10000 mm: before, the prior let 29 pairs match and no model start (exit 5 after a
    minute of retries); now it is not trusted and every photo registers."""
    from photorecon.poses.sfm import run_sfm

    photos = _focal_photos(ring12 / "images", tmp_path / "photos", 10000)
    res = run_sfm(photos, tmp_path / "out")
    assert len(res.registered) == 12


def test_no_model_message_says_pairs_matched(ring12, tmp_path):
    """When mapping starts no model, the message says whether any pairs were matched: 'do the photos overlap?'
    is wrong when they were."""
    from photorecon.poses.sfm import SfMConfig, camera_groups, extract, match, no_model_message

    ing = ingest_folder(ring12 / "images", tmp_path / "work")
    cfg = SfMConfig(threads=1, max_features=1000)
    names = {"view_000.png", "view_001.png", "view_002.png"}
    ims = [im for im in ing.images if im.name in names]
    extract(tmp_path / "work", tmp_path / "f.db", camera_groups(ims, cfg), cfg)
    match(tmp_path / "f.db", tmp_path / "d.db", "exhaustive", cfg)
    msg = no_model_message(tmp_path / "d.db", 3)
    assert "image pairs were matched (" in msg and "inlier matches), but no model could be started" in msg, msg
    assert "overlap" not in msg
    assert "no two images could be matched" in no_model_message(tmp_path / "f.db", 3)  # features, no matches


# --- masks ---------------------------------------------------------------------------------------------------
def test_masks_that_exclude_every_pixel_are_named_before_any_work(ring12, tmp_path, capsys):
    """12 all-zero masks: exit 3 naming them (not exit 5, 'do the photos overlap?'), nothing written; with
    only some all-zero, those photos are left out by the gate."""
    from photorecon.cli import main
    from photorecon.poses.sfm_inputs import sfm_masks

    masks = tmp_path / "masks"
    masks.mkdir()
    for i in range(12):
        cv2.imwrite(str(masks / f"view_{i:03d}.png"), np.zeros((180, 240), np.uint8))
    out = tmp_path / "out"
    assert main(["-q", "sfm", str(ring12 / "images"), "--masks", str(masks), "-o", str(out)]) == 3
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "the masks exclude every pixel of 12 photo(s) (view_000.png, view_001.png" in err, err
    assert "inverted" in err and not out.exists()
    for i in range(2, 12):
        cv2.imwrite(str(masks / f"view_{i:03d}.png"), np.full((180, 240), 255, np.uint8))
    found, empty = sfm_masks(ring12 / "images", masks)
    assert len(found) == 12 and empty == ["view_000.png", "view_001.png"]
    ing = ingest_folder(ring12 / "images", tmp_path / "work", left_out={n: "their masks exclude every pixel"
                                                                        for n in empty})
    assert len(ing.images) == 10 and "view_000.png" in ing.skipped


# --- names ---------------------------------------------------------------------------------------------------
def test_a_photo_name_with_a_line_break_is_refused_before_any_work(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(3):
        cv2.imwrite(str(photos / f"p{i}.jpg"), _noise(180, 240, i))
    cv2.imwrite(str(photos / "two\nlines.jpg"), _noise(180, 240, 7))
    with pytest.raises(InputDataError, match=r"two\\nlines.jpg: the photo's name holds a line break") as exc:
        ingest_folder(photos, tmp_path / "work")
    assert "\n" not in str(exc.value) and "rename it" in str(exc.value)
    assert not (tmp_path / "work").exists()


# --- videos --------------------------------------------------------------------------------------------------
def test_a_video_with_frames_that_do_not_decode_says_how_many_did(tmp_path, caplog):
    """A 12-frame MJPEG video whose middle third is zeroed: the frames that decode are taken and a warning
    says how many of the 12 could be decoded (before: 'video: 4 of 4 frames taken', no warning)."""
    path = tmp_path / "clip.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (160, 120))
    for i in range(12):
        w.write(_noise(120, 160, i))
    w.release()
    data = bytearray(path.read_bytes())
    starts = [i for i in range(len(data) - 1) if data[i] == 0xFF and data[i + 1] == 0xD8]
    assert len(starts) == 12
    data[starts[4]:starts[8]] = bytes(starts[8] - starts[4])
    path.write_bytes(bytes(data))
    with caplog.at_level(logging.INFO, logger="photorecon"):
        ing = video_frames(path, tmp_path / "frames", every=1)
    warn = _warnings(caplog)
    assert 4 <= len(ing.images) < 12
    assert len(warn) == 1 and f"{len(ing.images)} of 12 frames could be decoded" in warn[0], warn


def test_a_video_of_frames_too_small_for_sift_is_refused(tmp_path):
    path = tmp_path / "tiny.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (24, 16))
    for i in range(3):
        w.write(_noise(16, 24, i))
    w.release()
    with pytest.raises(NoImagesError, match=r"tiny.avi: its frames are 24x16, under 32 pixels a side"):
        video_frames(path, tmp_path / "frames", every=1)
    assert not list((tmp_path / "frames").glob("*.png"))


# --- orientation and colour ------------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".jpg", ".png", ".tif"])
def test_every_exif_orientation_is_applied_once(tmp_path, suffix):
    """Orientations 1-8 in JPEG, PNG and TIFF: each photo's working copy is the picture upright (as Pillow's
    exif_transpose shows it), its size the upright one; a TIFF on its side (5-8) is read (OpenCV refuses it)."""
    photos = tmp_path / "photos"
    photos.mkdir()
    rgb = _noise(48, 64, 3)
    want = {}
    for o in range(1, 9):
        exif = Image.Exif()
        exif[0x0112] = o
        path = photos / f"o{o}{suffix}"
        Image.fromarray(rgb).save(path, exif=exif.tobytes(), **({"quality": 98} if suffix == ".jpg" else {}))
        want[path.name] = np.asarray(ImageOps.exif_transpose(Image.open(path)).convert("RGB"), np.float64)
    ing = ingest_folder(photos, tmp_path / "work")
    assert [im.name for im in ing.images] == sorted(want)
    for im in ing.images:
        got = cv2.imread(str(tmp_path / "work" / im.name), cv2.IMREAD_COLOR)[..., ::-1].astype(np.float64)
        assert got.shape == want[im.name].shape and (im.width, im.height) == (got.shape[1], got.shape[0])
        err = np.abs(got - want[im.name]).mean()
        assert err < 8, (im.name, err)  # a JPEG is encoded once more
        if im.name[1] != "1" and got.shape == rgb.shape:  # not the picture as stored (2-4 keep its shape)
            assert err < np.abs(got - rgb).mean() / 3, im.name
        # the copy holds no orientation that a reader could apply a second time
        assert Image.open(tmp_path / "work" / im.name).getexif().get(0x0112, 1) == 1


def test_a_turned_photo_keeps_its_gps_and_its_alpha_turned_with_it(tmp_path):
    """A phone photo stored on its side: the upright working copy keeps its EXIF GPS (spatial matching reads
    it); an RGBA PNG's alpha (its mask) is turned with its pixels."""
    from photorecon.io.images import read_alpha
    from photorecon.poses.scale import read_gps
    from photorecon.testing import write_gps_jpeg

    photos = tmp_path / "photos"
    photos.mkdir()
    write_gps_jpeg(photos / "a.jpg", (48.85, 2.35, 35.0), _noise(48, 64))
    with Image.open(photos / "a.jpg") as im:
        exif = im.getexif()
        exif[0x0112] = 6
        im.save(photos / "b.jpg", exif=exif.tobytes(), quality=95)
    rgba = np.dstack([_noise(48, 64), np.zeros((48, 64), np.uint8)])
    rgba[:10, :, 3] = 255  # the top rows used
    e = Image.Exif()
    e[0x0112] = 6  # shown turned 90 degrees clockwise: the stored top rows become the right columns
    Image.fromarray(rgba).save(photos / "c.png", exif=e.tobytes())
    alpha = read_alpha(photos / "c.png")
    assert alpha.shape == (64, 48) and alpha[:, -10:].min() == 255 and alpha[:, :-10].max() == 0
    ing = ingest_folder(photos, tmp_path / "work")
    assert [(im.name, im.width, im.height) for im in ing.images] == [("a.jpg", 64, 48), ("b.jpg", 48, 64),
                                                                     ("c.png", 48, 64)]
    assert read_gps(tmp_path / "work" / "b.jpg") == pytest.approx(read_gps(photos / "a.jpg"))
    assert np.array_equal(read_alpha(tmp_path / "work" / "c.png"), alpha)


def test_cmyk_and_icc_profiled_jpegs_pass_the_gate(tmp_path):
    """A CMYK JPEG (print workflows) and one with an ICC profile: both ingested at their size, not left out."""
    from PIL import ImageCms

    photos = tmp_path / "photos"
    photos.mkdir()
    rgb = _noise(120, 160, 5)
    Image.fromarray(rgb).convert("CMYK").save(photos / "cmyk.jpg", quality=95)
    icc = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    Image.fromarray(rgb).save(photos / "icc.jpg", quality=95, icc_profile=icc)
    ing = ingest_folder(photos, tmp_path / "work")
    assert [(im.name, im.width, im.height) for im in ing.images] == [("cmyk.jpg", 160, 120), ("icc.jpg", 160, 120)]
    got = cv2.imread(str(tmp_path / "work" / "cmyk.jpg"))[..., ::-1].astype(float)
    assert np.abs(got - rgb).mean() < 12


def test_all_flat_photos_are_still_named_as_such(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(3):
        cv2.imwrite(str(photos / f"black_{i}.png"), np.zeros((120, 160, 3), np.uint8))
    with pytest.raises(NoImagesError, match=r"all 3 photo\(s\) are a single flat colour"):
        ingest_folder(photos, tmp_path / "work")


@pytest.mark.parametrize("suffix", [".png", ".tif", ".jpg"])
def test_given_cameras_triangulation_reads_photos_upright(tmp_path, suffix):
    """The triangulation of given cameras reads each photo upright by its EXIF orientation, as ingest_given and
    the depth stage do (it read them as stored: a mirrored or turned picture against upright cameras), its alpha
    turned with it."""
    from photorecon.poses.triangulate import _read_rgb_alpha

    rgba = np.dstack([_noise(24, 40, 2), np.zeros((24, 40), np.uint8)])
    rgba[:6, :, 3] = 255
    for o in range(1, 9):
        exif = Image.Exif()
        exif[0x0112] = o
        path = tmp_path / f"o{o}{suffix}"
        im = Image.fromarray(rgba if suffix == ".png" else rgba[..., :3])  # (OpenCV premultiplies a TIFF's alpha)
        im.save(path, exif=exif.tobytes(), **({"quality": 98} if suffix == ".jpg" else {}))
        upright = ImageOps.exif_transpose(Image.open(path))
        want = np.asarray(upright.convert("RGB"))[..., ::-1].astype(float)
        got, alpha = _read_rgb_alpha(path)
        assert got.shape == want.shape and np.abs(got - want).mean() < 1, o
        if suffix == ".png":
            assert np.array_equal(alpha, np.asarray(upright.getchannel("A"))), o
