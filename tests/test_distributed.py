"""Dask: per-view depth and chunked fusion on a 2-worker LocalCluster give what the in-process run gives; a worker
killed mid-run loses nothing; an interrupted cluster run resumes from its finished tasks; chunked TSDF equals
one volume, with no seam and no doubled face at chunk borders."""
import os
import signal
import threading
import time

import numpy as np
import pytest

from photorecon import distributed as dist
from photorecon.depth.mvs import MVSConfig, run_mvs
from photorecon.distributed import ClusterConfig, executor, parse_cluster
from photorecon.errors import BadArgumentError
from photorecon.fusion import FusionConfig, fuse, load_frames, tsdf_fuse, tsdf_fuse_chunked
from photorecon.io.dataset import Dataset
from photorecon.metrics import doubled_shell_fraction, mesh_metrics
from photorecon.testing import synth_scene

# tiny and quick: 8 views of 96x72, two pyramid levels
PM = dict(n_sources=3, pm_levels=2, pm_iterations=3, pm_fine_iterations=1, pm_final_iterations=1, min_consistent=1)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return synth_scene(tmp_path_factory, "tiny8", scene="blob", views=8, width=96, height=72, points=600, seed=3)


@pytest.fixture(scope="module")
def cluster():
    """A 2-worker LocalCluster (processes, 1 thread each on 2 cores), closed after the module."""
    with executor(ClusterConfig("local:2")) as ex:
        yield ex


@pytest.fixture(scope="module")
def in_process_depth(tiny, tmp_path_factory):
    out = tmp_path_factory.mktemp("depth_inproc")
    rep = run_mvs(Dataset.open(tiny), out, MVSConfig(**PM))
    return out, rep


def _depths(folder):
    return {p.stem: np.load(p) for p in sorted(folder.glob("*.npy")) if p.name.count(".") == 1}


def _same_depth(a: dict, b: dict):
    assert a.keys() == b.keys() and len(a) == 8
    for name in a:
        da, db = a[name], b[name]
        assert ((da > 0) == (db > 0)).all(), name
        ok = da > 0
        assert np.abs(da[ok] - db[ok]).max() <= 1e-5 * da[ok].max(), name


def test_cluster_spec_parsing():
    assert parse_cluster("local") == ("local", 2)
    assert parse_cluster("local:3") == ("local", 3)
    assert parse_cluster("tcp://10.0.0.5:8786") == ("remote", "tcp://10.0.0.5:8786")
    for bad in ("local:0", "local:x", "10.0.0.5", "cluster"):
        with pytest.raises(BadArgumentError):
            parse_cluster(bad)


@pytest.mark.cluster
def test_cluster_depth_and_mesh_match_in_process(tiny, cluster, in_process_depth, tmp_path):
    ref_dir, ref_rep = in_process_depth
    ds = Dataset.open(tiny)
    rep = run_mvs(ds, tmp_path / "depth", MVSConfig(**PM), cluster)
    assert rep["workers"] == 2 and rep["views"] == ref_rep["views"] == 8
    _same_depth(_depths(ref_dir), _depths(tmp_path / "depth"))
    assert not (tmp_path / "depth" / ".mvs_work").exists()  # intermediate maps removed on success
    # fusion of those depth maps: one volume in this process vs chunks (32 voxels a side) on the cluster
    cfg = FusionConfig(trunc_voxels=3.0)
    ds_ref, ds_dist = Dataset.open(tiny, ref_dir), Dataset.open(tiny, tmp_path / "depth")
    single = tsdf_fuse(load_frames(ds_ref, cfg), cfg, ds.model.points)
    chunked = fuse(load_frames(ds_dist, cfg), FusionConfig(trunc_voxels=3.0, chunk_voxels=32), ds.model.points,
                   cluster, ds_dist, tmp_path / "work")
    assert chunked.metadata["chunks"] > 4
    diag = float(np.linalg.norm(single.bounds[1] - single.bounds[0]))
    assert mesh_metrics(chunked, single, tau=0.005 * diag, n_samples=30_000).fscore >= 0.999


@pytest.mark.cluster
def test_worker_killed_during_depth_stage_run_completes(tiny, cluster, in_process_depth, tmp_path):
    ds = Dataset.open(tiny)
    pids = list(cluster.client.run(os.getpid).values())
    result, errors = {}, []

    def work():
        try:
            result["rep"] = run_mvs(ds, tmp_path / "depth", MVSConfig(**PM), cluster, tmp_path / "work")
        except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
            errors.append(exc)

    t = threading.Thread(target=work)
    t.start()
    deadline = time.time() + 60
    while time.time() < deadline and not list((tmp_path / "work").rglob("r0/*.depth.npy")):
        time.sleep(0.02)
    assert t.is_alive(), "the run ended before a worker could be killed"
    os.kill(pids[0], signal.SIGKILL)  # mid-run: Dask reschedules its tasks, the nanny starts a new worker
    t.join(180)
    assert not errors, errors
    assert result["rep"]["views"] == 8
    _same_depth(_depths(in_process_depth[0]), _depths(tmp_path / "depth"))


class _Interrupt:
    """A progress bar that raises KeyboardInterrupt (Ctrl-C) after ``after`` tasks have completed."""

    def __init__(self, after):
        self.after, self.n = after, 0

    def __call__(self, *a, **k):
        return self

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, k=1):
        self.n += k
        if self.n >= self.after:
            raise KeyboardInterrupt


@pytest.mark.cluster
def test_interrupted_cluster_reconstruct_resumes(tiny, cluster, tmp_path, monkeypatch):
    from photorecon.pipeline import ReconstructConfig, StageConfigs, reconstruct

    # the fixture's scheduler, reached by address as a remote one would be
    cfgs = StageConfigs(run=ReconstructConfig(poses=str(tiny / "sparse" / "0"), masks=str(tiny / "masks")),
                        mvs=MVSConfig(**PM),
                        cluster=ClusterConfig(cluster.client.scheduler.address))
    out = tmp_path / "rec"
    monkeypatch.setattr(dist, "bar", _Interrupt(after=12))  # Ctrl-C during the depth stage, 12 of 32 tasks done
    with pytest.raises(KeyboardInterrupt):
        reconstruct(tiny / "images", out, cfgs)
    assert not (out / "depth").exists() and not (out / "mesh.ply").exists()  # nothing incomplete kept
    assert len(list((out / ".work").rglob("*.depth.npy"))) >= 10  # the finished tasks' maps are kept
    monkeypatch.undo()
    rep = reconstruct(tiny / "images", out, cfgs)
    assert rep["stages"]["poses"].get("cached")
    mvs = __import__("json").loads((out / "depth" / "mvs_report.json").read_text())
    assert mvs["reused_tasks"] >= 10  # resumed: the interrupted run's finished tasks are not run again
    assert rep["mesh"]["faces"] > 300 and not (out / ".work").exists()
    # the resumed depth maps are those of an uninterrupted in-process run on the same inputs
    run_mvs(Dataset.open(out), tmp_path / "fresh", MVSConfig(**PM))
    _same_depth(_depths(tmp_path / "fresh"), _depths(out / "depth"))


@pytest.mark.slow
def test_chunked_fusion_equals_single_volume(tiny, tmp_path):
    """Rendered depth of the blob: chunks of 32 voxels (many borders) stitched = one volume, face for face."""
    ds = Dataset.open(tiny)
    cfg = FusionConfig()
    frames = load_frames(ds, cfg)
    single = tsdf_fuse(frames, cfg)
    chunked = tsdf_fuse_chunked(ds, frames, cfg, chunk_voxels=32, work_dir=tmp_path / "w")
    assert chunked.metadata["chunks"] >= 20
    diag = float(np.linalg.norm(single.bounds[1] - single.bounds[0]))
    assert mesh_metrics(chunked, single, tau=0.005 * diag, n_samples=50_000).fscore >= 0.999
    # no doubled face at a chunk border: every triangle once, as in the single volume ...
    _, vid = np.unique(np.concatenate([single.vertices, chunked.vertices]).round(6), axis=0, return_inverse=True)
    vid = vid.ravel()
    tris_single = np.unique(np.sort(vid[single.faces], axis=1), axis=0)
    tris_chunked = np.unique(np.sort(vid[len(single.vertices) + chunked.faces], axis=1), axis=0)
    assert len(tris_chunked) == len(chunked.faces) == len(single.faces)
    assert (tris_chunked == tris_single).all()
    assert doubled_shell_fraction(chunked, 0.005 * diag, n_samples=20_000) <= 0.001
    # ... and no seam: borders welded, so the mesh has as many open edges as the single volume's
    open_edges = lambda m: int((np.bincount(m.edges_unique_inverse) == 1).sum())  # noqa: E731
    assert open_edges(chunked) == open_edges(single)
    assert not (tmp_path / "w").exists()
