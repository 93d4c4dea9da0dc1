"""The depth-method registry (photorecon.depth.methods): the settings, run_mvs and the pipeline read it, and a new
depth method is a module plus one registry line. Here a toy method, the synthetic scene's true depth, runs end to
end through run_mvs (plan, task graph, geometric filter, files) and reconstruct."""
import types

import numpy as np
import pytest

from photorecon.depth import work
from photorecon.depth.methods import REGISTRY, method, names, register, stage_method, unregister
from photorecon.depth.mvs import MVSConfig, run_mvs
from photorecon.errors import BadArgumentError
from photorecon.io.dataset import Dataset
from photorecon.synthetic import SynthConfig, synthesize
from photorecon.tasks import Task


def truth_method(truth_dir):
    """A per-view depth method in a few lines: each view's depth is the scene's true depth (confidence 1)."""
    def tasks(ctx):
        last = {n: f"truth:{n}" for n in ctx.plan}
        return [Task(last[n], ("truth", n)) for n in ctx.plan], last

    def run_task(ctx, name):
        depth = np.load(truth_dir / f"{name}.npy")
        work.finish_depth(ctx, name, depth, np.ones_like(depth), None)
        return {"seconds": 0.0, "cpu_seconds": 0.0}

    return types.SimpleNamespace(DEPTH_RANGE=(0.5, 2.0), SEEDS=False, tasks=tasks, run_task=run_task)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("registry_scene")
    synthesize(SynthConfig(scene="blob", rig="ring", views=8, width=96, height=72, points=400, seed=1), root, overwrite=True)
    return root


@pytest.fixture
def truth(scene):
    register("truth", "view", truth_method(scene / "depth"), "the scene's true depth")
    yield
    unregister("truth")


def test_the_registry_holds_every_depth_method_and_the_settings_read_it():
    assert names("view") == ("patchmatch", "sweep") and names("stage") == ("mono", "given")
    for name, entry in REGISTRY.items():
        m = method(name)
        if entry.kind == "view":
            near, far = m.DEPTH_RANGE
            assert 0 < near < 1 < far and callable(m.tasks) and callable(m.run_task)
        else:
            assert m.SOURCE and callable(m.run_stage) and callable(m.check) and callable(m.inputs)
    with pytest.raises(BadArgumentError, match="depth method: expected one of patchmatch, sweep, mono, given, got 'nope'"):
        method("nope")
    with pytest.raises(BadArgumentError, match="MVSConfig.method .*--method.*: expected one of patchmatch, sweep, got 'truth'"):
        MVSConfig(method="truth")


def test_the_reconstruct_settings_select_a_whole_stage_method_or_none():
    from photorecon.pipeline import ReconstructConfig

    assert stage_method(ReconstructConfig()) is None  # MVS, with --method METHOD
    assert stage_method(ReconstructConfig(depth="somewhere")).SOURCE == "folder"
    assert stage_method(ReconstructConfig(depth_model="m.onnx")).SOURCE == "mono"


def test_a_registered_method_is_a_setting_and_a_command_line_choice(truth, capsys):
    from photorecon.cli import main

    assert MVSConfig(method="truth").method == "truth"
    with pytest.raises(SystemExit):
        main(["mvs", "--help"])
    assert "{patchmatch,sweep,truth}" in capsys.readouterr().out
    unregister("truth")
    with pytest.raises(BadArgumentError):
        MVSConfig(method="truth")


def test_a_toy_method_runs_through_run_mvs(truth, scene, tmp_path):
    ds = Dataset.open(scene)
    rep = run_mvs(ds, tmp_path / "d", MVSConfig(method="truth", n_sources=3, min_consistent=1))
    assert rep.method == "truth" and rep.views == len(ds.views) and not rep.skipped
    # the task graph: one toy task per view, then the filter
    assert {k.split(":")[0] for k in rep.task_seconds} == {"truth", "filter"}
    # true depths agree with one another: the filter keeps nearly all (measured 0.988), and what it keeps is the truth
    assert rep.consistency["kept_fraction"] > 0.95
    for v in ds.views:
        d, gt = np.load(tmp_path / "d" / f"{v.name}.npy"), np.load(scene / "depth" / f"{v.name}.npy")
        kept = d > 0
        assert kept.sum() > 0.9 * (gt > 0).sum() and np.array_equal(d[kept], gt[kept])


@pytest.mark.slow
def test_a_toy_method_runs_through_the_pipeline(truth, scene, tmp_path):
    from photorecon.pipeline import ReconstructConfig, StageConfigs, reconstruct

    cfgs = StageConfigs(ReconstructConfig(poses=str(scene / "transforms.json"), formats="ply"),
                        mvs=MVSConfig(method="truth", n_sources=3, min_consistent=1))
    res = reconstruct(scene / "images", tmp_path / "out", cfgs)
    assert res.depth["source"] == "mvs" and res.parameters["mvs"]["method"] == "truth"
    assert res.depth["views"] == 8 and res.depth["confirmed_fraction"] > 0.2 and res.mesh["faces"] > 100
    # report.json: each depth map's resolution and size (8 views: no coarse cover, every one full)
    assert len(res.depth["resolution"]) == 8 and all(r.startswith("full ") for r in res.depth["resolution"].values())
    v = "view_000"
    d, gt = np.load(tmp_path / "out" / "depth" / f"{v}.npy"), np.load(scene / "depth" / f"{v}.npy")
    assert np.array_equal(d[d > 0], gt[d > 0])
