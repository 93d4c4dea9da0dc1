"""Incremental mapping is not run again with relaxed thresholds for images that no mapping can register."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

pycolmap = pytest.importorskip("pycolmap")

from photorecon.poses.mapping import _unmatchable  # noqa: E402


class _Model:
    """What ``_unmatchable`` reads of a pycolmap Reconstruction: its registered image ids."""

    def __init__(self, ids):
        self.ids = list(ids)
        self.images = {i: SimpleNamespace(image_id=i) for i in self.ids}

    def num_reg_images(self):
        return len(self.ids)

    def reg_image_ids(self):
        return self.ids


def _database(path, inliers: dict) -> list[int]:
    """Three images; verified matches between the pairs of ``inliers`` ((a, b) -> count)."""
    db = pycolmap.Database.open(str(path))
    try:
        cam = db.write_camera(pycolmap.Camera(model="SIMPLE_PINHOLE", width=64, height=64, params=[100, 32, 32]))
        ids = [db.write_image(pycolmap.Image(name=f"v{k}.png", camera_id=cam)) for k in range(3)]
        for (a, b), count in inliers.items():
            g = pycolmap.TwoViewGeometry()
            g.config = 2  # calibrated
            g.inlier_matches = np.stack([np.arange(count), np.arange(count)], 1).astype(np.uint32)
            db.write_two_view_geometry(ids[a], ids[b], g)
    finally:
        db.close()
    return ids


def test_images_left_out_without_matches_are_not_mapped_again(tmp_path):
    ids = _database(tmp_path / "database.db", {(0, 1): 40, (0, 2): 5})
    db = tmp_path / "database.db"
    # v2 has 5 verified matches, fewer than the mapper's 15: no thresholds register it
    assert _unmatchable(pycolmap, db, [_Model(ids[:2])], 15) == ["v2.png"]
    # with 5 enough, v2 could register: map again
    assert _unmatchable(pycolmap, db, [_Model(ids[:2])], 5) == []
    # v1 left out too, and it has 40 matches with v0: map again
    assert _unmatchable(pycolmap, db, [_Model(ids[:1])], 15) == []
    # the largest model is the one asked about
    assert _unmatchable(pycolmap, db, [_Model(ids[:1]), _Model(ids[:2])], 15) == ["v2.png"]


@pytest.mark.slow
def test_hierarchical_mapping_registers_a_capture_split_in_clusters(sphere30, tmp_path, monkeypatch, caplog):
    """Hierarchical mapping with clusters of at most 12 of 30 sphere views registers every view as accurately as
    one incremental mapping; when it registers too small a share of the matched images, the same call maps them
    incrementally instead and says so."""
    import json
    import logging

    from photorecon.io.dataset import read_model
    from photorecon.metrics import pose_metrics
    from photorecon.poses import mapping
    from photorecon.poses.sfm import SfMConfig, run_sfm

    monkeypatch.setattr(mapping, "HIERARCHICAL_LEAF_MAX", 12)
    out = tmp_path / "out"
    ref = read_model(sphere30 / "sparse" / "0").views
    run_sfm(sphere30 / "images", out, SfMConfig(mapper="hierarchical"))
    assert json.loads((out / "colmap" / "sfm_report.json").read_text())["mapper"] == "hierarchical"
    m = pose_metrics(read_model(out / "sparse" / "0").views, ref)
    assert m["registered"] == 30 and m["rot_mean_deg"] < 0.2 and m["center_mean_rel"] < 0.01, m

    monkeypatch.setattr(mapping, "HIERARCHICAL_MIN_SHARE", 1.01)  # no hierarchical model is accepted
    db, images = out / "colmap" / "database.db", out / "colmap" / "images"
    with caplog.at_level(logging.INFO, logger="photorecon"):
        model = mapping.map_model(db, images, tmp_path / "again", SfMConfig(), False, "hierarchical")
    assert "mapping them incrementally instead" in caplog.text
    assert pycolmap.Reconstruction(str(model)).num_reg_images() == 30
