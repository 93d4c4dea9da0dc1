"""Shared fixtures: small synthetic datasets rendered once per test session (no ../shared data)."""
import hashlib
import os

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "2")

from photorecon.testing import synth_scene  # noqa: E402  (after the thread setting: it imports numpy)


def tree_hash(folder):
    """SHA-256 over a folder's relative paths and file bytes: 'unchanged byte for byte'."""
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        h.update(str(p.relative_to(folder)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.fixture(autouse=True, scope="session")
def _quiet_progress():
    from photorecon import progress

    progress.set_enabled(False)


@pytest.fixture(scope="session")
def blob_small(tmp_path_factory):
    """12 sphere views of the blob at 160x120."""
    return synth_scene(tmp_path_factory, "blob_small", scene="blob", views=12, width=160, height=120,
                       points=1500, seed=3)


@pytest.fixture(scope="session")
def blob_fusion(tmp_path_factory):
    """24 sphere views of the blob at 320x240, for fusion accuracy."""
    return synth_scene(tmp_path_factory, "blob_fusion", scene="blob", views=24, width=320, height=240,
                       points=2000, seed=1)


@pytest.fixture(scope="session")
def ring16(tmp_path_factory):
    """16 ring views of the blob at 320x240: enough overlap for SfM."""
    return synth_scene(tmp_path_factory, "ring16", scene="blob", rig="ring", views=16, width=320, height=240,
                       points=800, seed=5)


@pytest.fixture(scope="session")
def sphere30(tmp_path_factory):
    """30 sphere views of the blob at 320x240: all-round coverage for end-to-end reconstruction."""
    return synth_scene(tmp_path_factory, "sphere30", scene="blob", views=30, width=320, height=240, points=800)
