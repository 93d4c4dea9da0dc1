"""SfM through pycolmap on synthetic images; camera import/export; pose metrics; bad image folders."""
import json
import shutil

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from photorecon.cameras import View
from conftest import tree_hash
from photorecon.cli import main
from photorecon.errors import NoImagesError, SfMError
from photorecon.poses.ingest import ingest_folder
from photorecon.io.colmap_text import read_colmap_text
from photorecon.io.convert import convert_cameras
from photorecon.io.dataset import read_model
from photorecon.metrics import pose_metrics
from photorecon.poses.sfm import SfMConfig, run_sfm
from photorecon.testing import synth_scene


@pytest.mark.slow
def test_sfm_registers_all_and_matches_truth(ring16, tmp_path):
    before = tree_hash(ring16 / "images")
    out = tmp_path / "sfm"
    res = run_sfm(ring16 / "images", out, SfMConfig())
    assert len(res.registered) == 16 and not res.unregistered
    est = read_model(out / "sparse" / "0")
    ref = read_model(ring16 / "sparse" / "0")
    m = pose_metrics(est.views, ref.views)
    assert m["registered"] == 16
    assert m["rot_mean_deg"] < 0.3 and m["center_mean_rel"] < 0.004, m
    # transforms.json agrees with sparse/0
    tj = read_model(out / "transforms.json")
    for a, b in zip(tj.views, est.views):
        np.testing.assert_allclose(a.cam_from_world, b.cam_from_world, atol=1e-9)
    # undistorted images exist for every registered view and match their cameras
    for v in est.views:
        img = cv2.imread(str(out / "images" / v.image_file))
        assert img.shape[:2] == (v.intrinsics.height, v.intrinsics.width)
    assert tree_hash(ring16 / "images") == before
    # a re-run reuses every stage
    again = run_sfm(ring16 / "images", out, SfMConfig())
    assert again.cached == ["ingest", "extraction", "matching", "mapping", "undistortion"]


@pytest.mark.slow
def test_sfm_with_given_intrinsics_keeps_them(ring16, tmp_path):
    ref = read_model(ring16 / "sparse" / "0")
    K = ref.views[0].intrinsics.K
    np.savetxt(tmp_path / "K.txt", K)
    out = tmp_path / "sfmK"
    assert main(["-q", "sfm", str(ring16 / "images"), "-o", str(out), "--intrinsics", str(tmp_path / "K.txt")]) == 0
    est = read_model(out / "sparse" / "0")
    for v in est.views:
        np.testing.assert_allclose(v.intrinsics.K, K, atol=1e-6)
    m = pose_metrics(est.views, ref.views)
    assert m["rot_mean_deg"] < 0.2 and m["center_mean_rel"] < 0.003, m


def test_colmap_transforms_colmap_roundtrip_is_exact(blob_small, tmp_path):
    src = read_colmap_text(blob_small / "sparse" / "0")
    convert_cameras(blob_small / "sparse" / "0", tmp_path / "t.json")
    convert_cameras(tmp_path / "t.json", tmp_path / "colmap")
    back = read_colmap_text(tmp_path / "colmap")
    assert [v.name for v in back.views] == [v.name for v in src.views]
    for a, b in zip(src.views, back.views):
        assert a.intrinsics == b.intrinsics
        np.testing.assert_allclose(a.cam_from_world, b.cam_from_world, atol=1e-12)
    # the same through the nerfstudio and instant-ngp world orientations, and binary COLMAP
    for world in ("nerfstudio", "instant-ngp"):
        convert_cameras(blob_small / "sparse" / "0", tmp_path / f"{world}.json", world=world)
        data = json.loads((tmp_path / f"{world}.json").read_text())
        assert data["photorecon_world"] == world
        back = read_model(tmp_path / f"{world}.json")
        for a, b in zip(src.views, back.views):
            np.testing.assert_allclose(a.cam_from_world, b.cam_from_world, atol=1e-12)
    convert_cameras(blob_small / "sparse" / "0", tmp_path / "bin", to="colmap-bin")
    assert (tmp_path / "bin" / "cameras.bin").is_file()
    binm = read_model(tmp_path / "bin")
    for a, b in zip(src.views, binm.views):
        np.testing.assert_allclose(a.cam_from_world, b.cam_from_world, atol=1e-9)
    assert len(binm.points) == len(src.points)


def test_pytorch3d_export(blob_small, tmp_path):
    from photorecon.cameras import project

    assert main(["-q", "convert", str(blob_small), str(tmp_path / "p3d.json"), "--to", "pytorch3d"]) == 0
    cams = json.loads((tmp_path / "p3d.json").read_text())["cameras"]
    model = read_colmap_text(blob_small / "sparse" / "0")
    v = model.views[0]
    c = cams[0]
    R, T, K = np.array(c["R"]), np.array(c["T"]), np.array(c["K_ndc"])
    X = model.points[:20]
    h = np.c_[X @ R + T, np.ones(20)] @ K.T
    ndc = h[:, :2] / h[:, 3:]
    H, W = c["image_size"]
    s = min(H, W) / 2
    uv_p3d = np.c_[W / 2 - ndc[:, 0] * s - 0.5, H / 2 - ndc[:, 1] * s - 0.5]
    uv, _ = project(X, v.intrinsics, v.cam_from_world)
    np.testing.assert_allclose(uv_p3d, uv, atol=1e-6)


def test_pose_metrics_recovers_similarity():
    rng = np.random.default_rng(4)
    ref = []
    for i in range(10):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=i).as_matrix()
        T[:3, 3] = rng.normal(size=3)
        ref.append(View(f"v{i}", None, T))  # intrinsics unused here
    # estimate = reference in another world: X_est = s R X_ref + t
    s, Rw, t = 2.5, Rotation.random(random_state=99).as_matrix(), np.array([1.0, -2, 3])
    est = []
    for v in ref:
        C = s * Rw @ v.center + t
        R_cam = v.cam_from_world[:3, :3] @ Rw.T
        T = np.eye(4)
        T[:3, :3] = R_cam
        T[:3, 3] = -R_cam @ C
        est.append(View(v.name, None, T))
    m = pose_metrics(est, ref)
    assert m["rot_max_deg"] < 1e-5 and m["center_max"] < 1e-9 and m["sim3_scale"] == pytest.approx(1 / s)
    # a perturbed camera shows up with its error
    bad = est[3].cam_from_world.copy()
    C = est[3].center
    bad[:3, :3] = Rotation.from_rotvec([0, 0, np.radians(2.0)]).as_matrix() @ bad[:3, :3]
    bad[:3, 3] = -bad[:3, :3] @ C  # same centre, rotated 2 degrees
    est[3] = View("v3", None, bad)
    m = pose_metrics(est, ref)
    assert m["per_image"]["v3"]["rot_deg"] == pytest.approx(2.0, abs=1e-6)


def test_ingest_exif_orientation_and_focal(tmp_path):
    from PIL import Image

    src = tmp_path / "in"
    src.mkdir()
    arr = np.zeros((40, 60, 3), np.uint8)
    arr[:10, :] = 255
    img = Image.fromarray(arr)
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 90 degrees clockwise when displayed
    exif[0xA405] = 36  # 36 mm equivalent: focal = long side
    img.save(src / "a.JPG", exif=exif.tobytes())
    Image.fromarray(arr).save(src / "b.png")
    (src / "notes.txt").write_text("not an image")
    (src / "broken.jpg").write_bytes(b"\xff\xd8\xff\xe0 garbage")
    ing = ingest_folder(src, tmp_path / "work")
    names = [i.name for i in ing.images]
    assert names == ["a.JPG", "b.png"]
    assert sorted(ing.skipped) == ["broken.jpg", "notes.txt"]
    a = ing.images[0]
    assert (a.width, a.height) == (40, 60)  # orientation applied
    assert a.focal_prior_px == pytest.approx(60.0)
    assert cv2.imread(str(tmp_path / "work" / "a.JPG")).shape[:2] == (60, 40)


def _noise_image(path, seed, size=(240, 320)):
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (size[0] // 8, size[1] // 8, 3), dtype=np.uint8)
    cv2.imwrite(str(path), cv2.resize(small, (size[1], size[0]), interpolation=cv2.INTER_CUBIC))


@pytest.mark.slow
def test_bad_image_folders(tmp_path, blob_small):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(NoImagesError, match="no readable image"):
        run_sfm(empty, tmp_path / "o1")
    assert main(["-q", "sfm", str(empty), "-o", str(tmp_path / "o1b")]) == 4
    others = tmp_path / "others"
    others.mkdir()
    (others / "readme.md").write_text("x")
    (others / "bad.jpg").write_bytes(b"not a jpeg")
    assert main(["-q", "sfm", str(others), "-o", str(tmp_path / "o2")]) == 4
    one = tmp_path / "one"
    one.mkdir()
    shutil.copy(blob_small / "images" / "view_000.png", one)
    with pytest.raises(SfMError, match="only one readable image"):
        run_sfm(one, tmp_path / "o3")
    same = tmp_path / "same"
    same.mkdir()
    for i in range(4):
        shutil.copy(blob_small / "images" / "view_000.png", same / f"img{i}.png")
    with pytest.raises(SfMError, match="all 4 photos are the same picture"):  # said before any matching
        run_sfm(same, tmp_path / "o4")
    apart = tmp_path / "apart"
    apart.mkdir()
    for i in range(4):
        _noise_image(apart / f"n{i}.png", i)
    before = tree_hash(apart)
    assert main(["-q", "sfm", str(apart), "-o", str(tmp_path / "o5")]) == 5
    assert tree_hash(apart) == before
    assert not (tmp_path / "o5" / "sparse" / "0").exists()


@pytest.mark.slow
def test_mixed_resolutions_get_one_camera_per_size(ring16, tmp_path):
    src = tmp_path / "mixed"
    src.mkdir()
    for i, p in enumerate(sorted((ring16 / "images").glob("*.png"))):
        img = cv2.imread(str(p))
        if i % 2:
            img = cv2.resize(img, (256, 192), interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(src / p.name), img)
    res = run_sfm(src, tmp_path / "out", SfMConfig())
    assert len(res.registered) >= 14
    cams = (tmp_path / "out" / "colmap" / "sfm_report.json")
    assert cams.is_file()
    import pycolmap

    rec = pycolmap.Reconstruction(str(tmp_path / "out" / "colmap" / "sparse"))
    sizes = {(c.width, c.height) for c in rec.cameras.values()}
    assert sizes == {(320, 240), (256, 192)}


def _write_video(path, frames, fps=10):
    h, w = frames[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    assert vw.isOpened()
    for f in frames:
        vw.write(f)
    vw.release()


def test_video_frames_every_kth(tmp_path):
    from photorecon.poses.ingest import video_frames

    frames = [np.full((48, 64, 3), i * 9, np.uint8) for i in range(25)]
    _write_video(tmp_path / "clip.avi", frames)
    ing = video_frames(tmp_path / "clip.avi", tmp_path / "frames", every=10)
    assert [i.name for i in ing.images] == ["frame_00000.png", "frame_00010.png", "frame_00020.png"]
    assert cv2.imread(str(tmp_path / "frames" / "frame_00010.png")).shape == (48, 64, 3)
    (tmp_path / "bad.mp4").write_bytes(b"not a video")
    with pytest.raises(NoImagesError, match="bad.mp4"):
        video_frames(tmp_path / "bad.mp4", tmp_path / "f2")


@pytest.mark.slow
def test_sfm_from_a_video(ring16, tmp_path):
    frames = [cv2.imread(str(p)) for p in sorted((ring16 / "images").glob("*.png"))]
    _write_video(tmp_path / "orbit.avi", frames)
    assert main(["-q", "sfm", str(tmp_path / "orbit.avi"), "-o", str(tmp_path / "out"), "--video-every", "1"]) == 0
    assert len(read_model(tmp_path / "out" / "sparse" / "0").views) >= 14


@pytest.fixture(scope="module")
def ring_tiny(tmp_path_factory):
    """16 ring views of the blob at 240x180: SfM in about 3 s."""
    return synth_scene(tmp_path_factory, "ring_tiny", scene="blob", rig="ring", views=16, width=240,
                       height=180, points=300, seed=5)


def _database(out):
    """(camera models, COLMAP-convention parameters of the first camera, matched image pairs) of OUT's database."""
    import pycolmap

    db = pycolmap.Database.open(str(out / "colmap" / "database.db"))
    try:
        cams = db.read_all_cameras()
        return {c.model.name for c in cams}, list(cams[0].params), db.num_matched_image_pairs()
    finally:
        db.close()


@pytest.mark.slow
def test_sfm_caches_are_keyed_on_their_settings(ring_tiny, tmp_path, capsys):
    """A re-run with other intrinsics, camera model or matcher recomputes what they change (and what
    follows), and reuses the rest."""
    out = tmp_path / "out"

    def sfm(*flags):
        assert main(["-q", "sfm", str(ring_tiny / "images"), "-o", str(out), *flags]) == 0
        printed = capsys.readouterr().out
        return printed.split("(reused: ")[1].split(")")[0].split(", ") if "(reused: " in printed else []

    assert sfm() == []
    models, _, pairs = _database(out)
    assert models == {"SIMPLE_RADIAL"} and pairs == 16 * 15 // 2  # auto -> exhaustive for 16 images
    assert sfm() == ["ingest", "extraction", "matching", "mapping", "undistortion"]

    # given intrinsics: the database camera and the written cameras are those, not the earlier estimate
    assert sfm("--fx", "300", "--fy", "310", "--cx", "119.5", "--cy", "89.5") == ["ingest"]
    models, params, _ = _database(out)
    assert models == {"PINHOLE"} and params == pytest.approx([300, 310, 120, 90])  # COLMAP: centre + 0.5
    cams = (out / "sparse" / "0" / "cameras.txt").read_text()
    for v in read_colmap_text(out / "sparse" / "0").views:
        assert (v.intrinsics.fx, v.intrinsics.fy, v.intrinsics.cx, v.intrinsics.cy) == pytest.approx(
            (300, 310, 119.5, 89.5))
    assert sfm("--fx", "300", "--fy", "310", "--cx", "119.5", "--cy", "89.5") != ["ingest"]  # all reused now

    # another camera model to self-calibrate: extraction and everything after it run again
    assert sfm("--camera-model", "PINHOLE") == ["ingest"]
    models, params, _ = _database(out)
    assert models == {"PINHOLE"} and params[0] != pytest.approx(300)
    assert (out / "sparse" / "0" / "cameras.txt").read_text() != cams

    # another matching: the features are reused, the matches are new
    assert sfm("--camera-model", "PINHOLE", "--matching", "sequential", "--sequential-overlap", "3") == \
        ["ingest", "extraction"]
    _, _, seq_pairs = _database(out)
    assert seq_pairs < pairs
    assert json.loads((out / "colmap" / "sfm_report.json").read_text())["matching"] == "sequential"
    marker = json.loads((out / "colmap" / ".stages" / "matching.json").read_text())
    assert marker["params"] == {"matching": "sequential", "pairing": {"overlap": 3, "loops": True}, "seed": 0} \
        and marker["seconds"] > 0


@pytest.mark.slow
def test_sfm_reruns_when_the_images_change(ring_tiny, tmp_path):
    src = tmp_path / "photos"
    shutil.copytree(ring_tiny / "images", src)
    out = tmp_path / "out"
    assert len(run_sfm(src, out, SfMConfig()).registered) == 16
    (src / "view_015.png").unlink()
    res = run_sfm(src, out, SfMConfig())
    assert res.cached == [] and len(res.registered) == 15
    assert not (out / "colmap" / "images" / "view_015.png").exists()
    assert sorted(p.name for p in (out / "images").iterdir()) == [f"view_{i:03d}.png" for i in range(15)]


@pytest.mark.slow
def test_reconstruct_reruns_sfm_with_new_intrinsics(ring_tiny, tmp_path):
    """Reconstruct's poses stage is keyed on the SfM settings, and SfM's own caches too."""
    out = tmp_path / "out"
    args = ["-q", "reconstruct", str(ring_tiny / "images"), "-o", str(out), "--mvs", "sweep", "--n-depths", "32"]
    assert main(args) == 0
    before = read_colmap_text(out / "sparse" / "0").views[0].intrinsics
    assert main(args + ["--fx", "300", "--fy", "300"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert not any(s.get("cached") for s in rep["stages"].values())
    assert rep["poses"]["sfm_seconds"]["ingest"] == 0 and rep["poses"]["sfm_seconds"]["extraction"] > 0
    for v in read_colmap_text(out / "sparse" / "0").views:
        assert (v.intrinsics.fx, v.intrinsics.fy, v.intrinsics.cx, v.intrinsics.cy) == pytest.approx(
            (300, 300, 119.5, 89.5))
    assert before.fx != pytest.approx(300, abs=1)


def test_choice_of_matching_and_mapper_by_count_video_and_gps():
    from photorecon.errors import BadArgumentError
    from photorecon.poses.sfm import choose_mapper, choose_matching

    cfg = SfMConfig(exhaustive_max=80, global_min=500)
    assert choose_matching(cfg, 80, 0) == "exhaustive" and choose_matching(cfg, 80, 80) == "exhaustive"
    assert choose_matching(cfg, 80, 0, video=True) == "exhaustive"
    assert choose_matching(cfg, 81, 81) == "spatial"  # every photo geotagged
    assert choose_matching(cfg, 81, 80) == "retrieval"  # one without GPS: it would get no spatial pairs
    assert choose_matching(cfg, 81, 0) == "retrieval"  # an unordered set: file names say nothing
    assert choose_matching(cfg, 81, 0, video=True) == "sequential"  # frames in capture order
    assert choose_matching(SfMConfig(matching="retrieval"), 10, 10) == "retrieval"
    assert choose_matching(SfMConfig(matching="exhaustive"), 5000, 5000) == "exhaustive"
    with pytest.raises(BadArgumentError, match="1 of 90 photos carry EXIF GPS"):
        choose_matching(SfMConfig(matching="spatial"), 90, 1)
    assert choose_mapper(cfg, 99) == "incremental" and choose_mapper(cfg, 100) == "hierarchical"
    assert choose_mapper(cfg, 499) == "hierarchical" and choose_mapper(cfg, 500) == "global"
    assert choose_mapper(SfMConfig(mapper="incremental"), 10_000) == "incremental"


@pytest.mark.slow
def test_sequential_and_spatial_matching_register_every_view_like_exhaustive(ring_tiny, tmp_path):
    """An ordered capture (a ring, file names in capture order, as JPEGs with EXIF GPS) matched
    sequentially (3 neighbours by name) or spatially (4 nearest by GPS) registers every view as accurately as
    exhaustive matching, from far fewer pairs; auto above --exhaustive-max picks spatial for geotagged photos."""
    from photorecon.io.images import read_image
    from photorecon.poses.scale import geodetic_from_enu
    from photorecon.testing import write_gps_jpeg

    ref = read_model(ring_tiny / "sparse" / "0").views
    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(0)
    for v in ref:  # 10 m per scene unit (a 30 m ring), 1 m of GPS noise
        lla = geodetic_from_enu(v.center * 10 + rng.normal(size=3), (46.52, 6.63, 400.0))[0]
        write_gps_jpeg(photos / f"{v.name}.jpg", lla, read_image(ring_tiny / "images" / v.image_file))
    out = tmp_path / "out"  # one folder: the features are extracted once, each choice re-matches
    found = {}
    for matching in ("exhaustive", "sequential", "spatial"):
        res = run_sfm(photos, out, SfMConfig(matching=matching, sequential_overlap=3, spatial_neighbors=4))
        assert len(res.registered) == 16, (matching, res.unregistered)
        found[matching] = (pose_metrics(read_model(out / "sparse" / "0").views, ref), _database(out)[2])
    ex, ex_pairs = found["exhaustive"]
    assert ex_pairs == 16 * 15 // 2
    for matching in ("sequential", "spatial"):
        m, pairs = found[matching]
        assert m["registered"] == 16 and pairs <= 16 * 6, (matching, pairs)
        assert m["rot_mean_deg"] <= 1.5 * ex["rot_mean_deg"] + 0.05, (matching, m["rot_mean_deg"], ex["rot_mean_deg"])
        assert m["center_mean_rel"] <= 1.5 * ex["center_mean_rel"] + 0.001, (matching, m, ex)
    # auto, above --exhaustive-max: every photo geotagged -> spatial (the same pairs: the matches are reused)
    res = run_sfm(photos, out, SfMConfig(exhaustive_max=8, spatial_neighbors=4))
    report = json.loads((out / "colmap" / "sfm_report.json").read_text())
    assert report["matching"] == "spatial" and report["photos_with_gps"] == 16 and "matching" in res.cached
