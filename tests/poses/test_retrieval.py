"""Pair selection for unordered photo sets (retrieval on a visual index of the photos' own features, loop
closing) and the SIFT work chosen per image size."""
import shutil

import cv2
import numpy as np
import pytest

from photorecon.io.dataset import read_model
from photorecon.metrics import pose_metrics
from photorecon.poses.retrieval import transitive_pairs, visual_words
from photorecon.poses.sfm import SfMConfig, run_sfm, sift_first_octave


def _shuffled(dataset, dst, n=None):
    """The dataset's photos under shuffled names (file order says nothing of the capture), and its reference
    cameras renamed to match."""
    ref = read_model(dataset / "sparse" / "0").views[:n]
    dst.mkdir()
    perm = np.random.default_rng(1).permutation(len(ref))
    for v, p in zip(ref, perm):
        shutil.copyfile(dataset / "images" / v.image_file, dst / f"photo_{p:03d}.png")
        v.name = f"photo_{p:03d}"
    return ref


def _matched_pairs(out):
    import pycolmap

    db = pycolmap.Database.open(str(out / "colmap" / "database.db"))
    try:
        return db.num_matched_image_pairs()
    finally:
        db.close()


def test_transitive_pairs_close_loops_through_strong_pairs_only_within_the_budget():
    verified = {(1, 2): 300, (2, 3): 200, (3, 4): 150, (4, 5): 40, (1, 5): 500}
    tried = set(verified) | {(1, 3)}
    # 1-2-3 is tried already; 2-3-4 (weaker side 150), 5-1-2 (300); 3-4-5 has a weak side (40)
    assert transitive_pairs(verified, tried, per_image=5, strong=100) == {(2, 4), (2, 5)}
    # one new pair per photo: the strongest first (2-5 through 1), then 2 is used up
    assert transitive_pairs(verified, tried, per_image=1, strong=100) == {(2, 5)}
    assert transitive_pairs(verified, tried, per_image=5, strong=1000) == set()


def test_visual_words_grow_with_the_set():
    assert visual_words(30) == 1024 and visual_words(200) == 2048 and visual_words(500) == 4096
    assert visual_words(100_000) == 8192


def test_sift_starts_at_the_image_size_where_that_gives_the_features_wanted():
    assert sift_first_octave(1600, 1600, 1600, 8192) == 0  # 2.56 M pixels: 312 per feature
    assert sift_first_octave(6000, 4000, 2400, 8192) == 0  # worked on at 2400x1600
    assert sift_first_octave(6000, 4000, 1600, 8192) == -1  # 1600x1067: too few pixels for 8192 features
    assert sift_first_octave(1280, 1024, 1600, 8192) == -1
    assert sift_first_octave(640, 480, 1600, 8192) == -1 and sift_first_octave(640, 480, 1600, 1024) == 0


@pytest.mark.slow
def test_retrieval_registers_a_shuffled_sphere_from_a_fraction_of_the_pairs(sphere30, tmp_path):
    """30 sphere views under shuffled names matched by retrieval (5 neighbours per photo, then loop-closing
    pairs) all register, as accurately as the views allow, from at most k + k/2 pairs per photo."""
    photos = tmp_path / "photos"
    ref = _shuffled(sphere30, photos)
    out = tmp_path / "out"
    k = 5
    res = run_sfm(photos, out, SfMConfig(matching="retrieval", retrieval_neighbors=k))
    assert len(res.registered) == 30, res.unregistered
    pairs = _matched_pairs(out)
    assert pairs <= 30 * (k + k // 2) < 30 * 29 // 2, pairs
    m = pose_metrics(read_model(out / "sparse" / "0").views, ref)
    assert m["registered"] == 30 and m["rot_mean_deg"] < 0.3 and m["center_mean_rel"] < 0.01, m


@pytest.mark.slow
def test_auto_matching_retrieves_above_exhaustive_max(sphere30, tmp_path):
    """Above --exhaustive-max an unordered set without GPS gets retrieval, and registers whole."""
    import json

    photos = tmp_path / "photos"
    _shuffled(sphere30, photos, n=16)
    out = tmp_path / "out"
    res = run_sfm(photos, out, SfMConfig(exhaustive_max=10, retrieval_neighbors=4))
    report = json.loads((out / "colmap" / "sfm_report.json").read_text())
    assert report["matching"] == "retrieval" and len(res.registered) == 16, res.unregistered
    assert _matched_pairs(out) < 16 * 15 // 2


@pytest.mark.slow
def test_sift_from_the_image_size_keeps_the_features_and_the_registration(sphere30, tmp_path, monkeypatch):
    """Photos large enough for --max-features at their own size skip SIFT's upsampled octave: the feature
    count stays at the cap and every photo registers, as with the upsampled octave."""
    import pycolmap

    from photorecon.poses import extract  # where sift_first_octave reads the threshold

    photos = tmp_path / "photos"
    photos.mkdir()
    ref = read_model(sphere30 / "sparse" / "0").views[:10]
    for v in ref:  # 960x720 copies of 10 neighbouring views
        img = cv2.imread(str(sphere30 / "images" / v.image_file))
        cv2.imwrite(str(photos / v.image_file), cv2.resize(img, (960, 720), interpolation=cv2.INTER_CUBIC))
    cfg = SfMConfig(max_features=1024, matching="exhaustive")
    assert sift_first_octave(960, 720, cfg.max_image_size, cfg.max_features) == 0
    found = {}
    for label, per_feature in (("octave0", extract.OCTAVE0_PIXELS_PER_FEATURE), ("upsampled", 10**9)):
        monkeypatch.setattr(extract, "OCTAVE0_PIXELS_PER_FEATURE", per_feature)
        out = tmp_path / label
        res = run_sfm(photos, out, cfg)
        db = pycolmap.Database.open(str(out / "colmap" / "features.db"))
        try:
            counts = [db.num_keypoints_for_image(im.image_id) for im in db.read_all_images()]
        finally:
            db.close()
        found[label] = (len(res.registered), float(np.mean(counts)))
    assert found["octave0"][0] == found["upsampled"][0] == 10, found
    assert found["octave0"][1] >= 0.8 * found["upsampled"][1], found
