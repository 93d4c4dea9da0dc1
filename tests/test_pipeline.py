"""End to end: `photorecon reconstruct` on synthetic images, resume, failure classes and exit codes."""
import json
import re
import time

import numpy as np
import pytest
import trimesh

from conftest import tree_hash
from photorecon.cli import main
from photorecon.io.dataset import read_model
from photorecon.metrics import align_cameras, mesh_metrics


# PatchMatch on one pyramid level with 4 sources: the pipeline is under test here (depth/test_patchmatch.py tests
# the depth itself); the defaults are for 1600-px photos
LIGHT_PM = ["--n-sources", "4", "--pm-levels", "1", "--pm-iterations", "4", "--min-consistent", "1"]


@pytest.fixture(scope="module")
def recon(sphere30, tmp_path_factory):
    out = tmp_path_factory.mktemp("recon") / "out"
    before = tree_hash(sphere30 / "images")
    t0 = time.perf_counter()
    rc = main(["-q", "reconstruct", str(sphere30 / "images"), "-o", str(out), *LIGHT_PM])
    return {"rc": rc, "out": out, "seconds": time.perf_counter() - t0, "before": before}


@pytest.mark.slow
def test_reconstruct_from_images_alone(recon, sphere30):
    assert recon["rc"] == 0
    out = recon["out"]
    for f in ("mesh.ply", "mesh.glb", "preview.png", "report.json", "report.html", "transforms.json",
              "sparse/0/cameras.txt"):
        assert (out / f).is_file(), f
    assert len(list((out / "depth").glob("*.npy"))) >= 30
    rep = json.loads((out / "report.json").read_text())
    assert rep["poses"]["registered"] == 30 and rep["depth"]["source"] == "mvs"
    assert {"poses", "depth", "fusion"} <= set(rep["stages"]) and rep["stages"]["depth"]["peak_mb"] > 0
    html = (out / "report.html").read_text()
    # self-contained: no file fetched from a server (a bare "http" can occur inside the base64 data)
    assert "data:image/png;base64," in html and 'id="prv-data"' in html
    assert not re.search(r"""(src|href)=["']?(https?:)?//|url\(|fetch\(|import\(""", html)
    est, ref = read_model(out / "sparse" / "0").views, read_model(sphere30 / "sparse" / "0").views
    s, R, t = align_cameras(est, ref)
    mesh = trimesh.load(out / "mesh.ply", process=False)
    mesh.vertices = s * np.asarray(mesh.vertices) @ R.T + t
    m = mesh_metrics(mesh, trimesh.load(sphere30 / "gt_mesh.ply", process=False), n_samples=30_000)
    assert m.fscore >= 0.85, m
    assert tree_hash(sphere30 / "images") == recon["before"]


@pytest.mark.slow
def test_rerun_is_a_noop(recon, sphere30):
    mesh_before = (recon["out"] / "mesh.ply").read_bytes()
    t0 = time.perf_counter()
    assert main(["-q", "reconstruct", str(sphere30 / "images"), "-o", str(recon["out"]), *LIGHT_PM]) == 0
    assert time.perf_counter() - t0 < 0.1 * recon["seconds"]
    assert (recon["out"] / "mesh.ply").read_bytes() == mesh_before
    rep = json.loads((recon["out"] / "report.json").read_text())
    assert all(s.get("cached") for s in rep["stages"].values())


@pytest.mark.slow
def test_interrupted_run_resumes(sphere30, tmp_path, monkeypatch, capsys):
    import photorecon.fusion as fusion

    out = tmp_path / "out"
    real = fusion.fuse
    monkeypatch.setattr(fusion, "fuse", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt()))
    args = ["-q", "reconstruct", str(sphere30 / "images"), "-o", str(out), "--mvs", "sweep", "--n-depths", "64",
            "--min-consistent", "1"]
    assert main(args) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not (out / "mesh.ply").exists() and not (out / ".stages" / "fusion.json").exists()
    assert (out / ".stages" / "depth.json").exists()
    monkeypatch.setattr(fusion, "fuse", real)
    assert main(args) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["stages"]["poses"].get("cached") and rep["stages"]["depth"].get("cached")
    assert not rep["stages"]["fusion"].get("cached") and (out / "mesh.ply").is_file()


@pytest.mark.slow
def test_given_poses_and_rendered_depth(blob_small, tmp_path):
    out = tmp_path / "out"
    assert main(["-q", "reconstruct", str(blob_small / "images"), "-o", str(out),
                 "--poses", str(blob_small / "transforms.json"), "--depth", str(blob_small / "depth")]) == 0
    m = mesh_metrics(trimesh.load(out / "mesh.ply", process=False),
                     trimesh.load(blob_small / "gt_mesh.ply", process=False), n_samples=30_000)
    assert m.fscore >= 0.97, m
    rep = json.loads((out / "report.json").read_text())
    assert rep["poses"]["source"].endswith("transforms.json")


@pytest.mark.slow
def test_failure_classes_and_exit_codes(tmp_path, blob_small, capsys):
    import cv2

    def run(*args):
        rc = main(["-q", "reconstruct", *map(str, args)])
        return rc, capsys.readouterr().err.strip()

    empty = tmp_path / "empty"
    empty.mkdir()
    rc, err = run(empty, "-o", tmp_path / "o1")
    assert rc == 4 and "no readable image" in err and err.count("\n") == 0
    noise = tmp_path / "noise"
    noise.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(noise / f"n{i}.png"), cv2.resize(rng.integers(0, 255, (30, 40, 3), dtype=np.uint8), (320, 240)))
    rc, err = run(noise, "-o", tmp_path / "o2")
    assert rc == 5 and "registered" in err
    nodepth = tmp_path / "nodepth"
    nodepth.mkdir()
    rc, err = run(blob_small / "images", "-o", tmp_path / "o3", "--poses", blob_small / "transforms.json",
                  "--depth", nodepth)
    assert rc == 6 and "no depth map" in err
    rc, err = run(blob_small / "images", "-o", tmp_path / "o4", "--poses", blob_small / "transforms.json",
                  "--depth", blob_small / "depth", "--crop", "50,50,50,51,51,51")
    assert rc == 7 and "no triangle" in err
    rc, err = run(blob_small / "images", "-o", tmp_path / "o5", "--formats", "stl")
    assert rc == 2 and "--formats" in err
    with pytest.raises(SystemExit) as e:
        main(["reconstruct", str(blob_small / "images"), "-o", str(tmp_path / "o6"), "--mesher", "voronoi"])  # not a mesher: argparse, exit 2
    assert e.value.code == 2
    capsys.readouterr()
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "mine.txt").write_text("x")
    rc, err = run(blob_small / "images", "-o", foreign)
    assert rc == 8 and "--overwrite" in err
    rc, err = run(blob_small / "images", "-o", blob_small / "images" / "out")
    assert rc == 8 and "inside the input" in err


def test_transforms_paths_are_confined(blob_small, tmp_path, capsys):
    data = json.loads((blob_small / "transforms.json").read_text())
    data["frames"][0]["file_path"] = "../../etc/passwd"
    bad = tmp_path / "t"
    bad.mkdir()
    (bad / "transforms.json").write_text(json.dumps(data))
    rc = main(["-q", "reconstruct", str(blob_small / "images"), "-o", str(tmp_path / "o"), "--poses",
               str(bad / "transforms.json")])
    assert rc == 3 and "leaves" in capsys.readouterr().err
    data["frames"][0]["file_path"] = "/etc/passwd"
    (bad / "transforms.json").write_text(json.dumps(data))
    assert main(["-q", "convert", str(bad / "transforms.json"), str(tmp_path / "c")]) == 3


@pytest.mark.slow
def test_stages_rerun_when_their_inputs_or_settings_change(blob_small, tmp_path):
    """Each stage is keyed on its settings and input files; a stage that runs again runs the later
    ones too, and only those."""
    import shutil

    images, depth, out = tmp_path / "images", tmp_path / "depth", tmp_path / "out"
    shutil.copytree(blob_small / "images", images)
    shutil.copytree(blob_small / "depth", depth)

    def ran(*flags):
        assert main(["-q", "reconstruct", str(images), "-o", str(out), "--poses", str(blob_small / "transforms.json"),
                     "--depth", str(depth), *flags]) == 0
        rep = json.loads((out / "report.json").read_text())
        return [name for name, s in rep["stages"].items() if not s.get("cached")], rep

    assert ran()[0] == ["poses", "depth", "fusion", "preview", "model"]
    assert ran()[0] == []
    assert ran("--trunc-voxels", "4")[0] == ["fusion", "preview", "model"]
    faces = ran("--trunc-voxels", "4")[1]["mesh"]["faces"]
    assert faces > 0  # the reused stage's facts are still reported

    # a depth map rewritten with the same bytes (a newer time): depth runs; it writes the same depth maps, so what
    # follows is still complete
    np.save(depth / "view_000.npy", np.load(depth / "view_000.npy"))
    assert ran("--trunc-voxels", "4")[0] == ["depth"]
    # a depth map changed: the mesh follows it
    d = np.load(depth / "view_001.npy")
    np.save(depth / "view_001.npy", np.zeros_like(d))
    names, rep = ran("--trunc-voxels", "4")
    assert names == ["depth", "fusion", "preview", "model"] and rep["mesh"]["faces"] != faces
    # an input image rewritten: everything
    (images / "view_002.png").write_bytes((images / "view_003.png").read_bytes())
    assert ran("--trunc-voxels", "4")[0] == ["poses", "depth", "fusion", "preview", "model"]
    # a deleted output: its stage only (the preview loads the mesh from its file), and the stages after it when it
    # comes out other than it was (the model follows the preview)
    (out / "preview.png").unlink()
    assert ran("--trunc-voxels", "4")[0] in (["preview"], ["preview", "model"]) and (out / "preview.png").is_file()
    assert ran("--trunc-voxels", "4", "--formats", "ply")[0] == ["fusion", "preview", "model"]
    assert ran("--trunc-voxels", "4", "--formats", "ply", "--force")[0] == ["poses", "depth", "fusion", "preview",
                                                                           "model"]


@pytest.mark.slow
def test_reconstruct_returns_a_typed_result(blob_small, tmp_path):
    """The Python API returns a dataclass (fields typed and documented) that is report.json."""
    from photorecon.pipeline import ReconstructConfig, ReconstructResult, StageConfigs, reconstruct

    cfgs = StageConfigs(ReconstructConfig(poses=str(blob_small / "transforms.json"), depth=str(blob_small / "depth")))
    res = reconstruct(blob_small / "images", tmp_path / "out", cfgs)
    assert isinstance(res, ReconstructResult)
    assert res.poses["registered"] == len(list((blob_small / "images").iterdir())) and res.mesh["faces"] > 1000
    assert res.depth["source"] == str(blob_small / "depth") and res.units == "arbitrary"
    assert json.loads((tmp_path / "out" / "report.json").read_text()) == json.loads(json.dumps(res.to_dict()))
    assert res["mesh"] is res.mesh and "nonsense" not in res
    with pytest.raises(KeyError):
        res["nonsense"]
