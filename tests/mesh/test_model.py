"""The textured model (photorecon/mesh/model.py): reconstruct writes OUT/model.glb by default (the mesh simplified to
--model-faces, textured from the photos), checked against the synthetic scene's true surface and photos; cached
re-runs, --texture off, the atlas repacking and the GLB's embedded JPEG."""
import json

import numpy as np
import pytest
import trimesh

from photorecon.cli import main
from photorecon.io.dataset import Dataset
from photorecon.render import Renderer

BUDGET = 20000


def _run(blob_small, out, *flags):
    assert main(["-q", "reconstruct", str(blob_small / "images"), "-o", str(out), "--poses",
                 str(blob_small / "transforms.json"), "--depth", str(blob_small / "depth"), *flags]) == 0
    rep = json.loads((out / "report.json").read_text())
    return [n for n, s in rep["stages"].items() if not s.get("cached")], rep


@pytest.fixture(scope="module")
def model_run(blob_small, tmp_path_factory):
    """The default reconstruct of blob_small (12 views at 160x120, its rendered depth maps) with a face budget
    below its mesh's ~100k faces, and obj among the formats."""
    out = tmp_path_factory.mktemp("model") / "out"
    names, rep = _run(blob_small, out, "--model-faces", str(BUDGET), "--formats", "ply,glb,obj")
    return out, names, rep


def _load(path):
    m = trimesh.load(path, process=False, force="mesh")
    assert isinstance(m.visual, trimesh.visual.TextureVisuals)
    return m


@pytest.mark.slow
def test_default_reconstruct_writes_a_simplified_textured_model(model_run, blob_small):
    """model.glb loads with its texture (at most 8192 a side), has at most the face budget, lies on the true surface
    (95% of its points within 0.5% of the blob's diagonal of 3.4 scene units, every point within 1.5%), and
    report.json's texture section says what was written."""
    import open3d as o3d

    from photorecon.mesh.convert import raycasting_scene

    out, names, rep = model_run
    assert names == ["poses", "depth", "fusion", "preview", "model"]
    m = _in_reconstruction_frame(_load(out / "model.glb"), rep)
    img = m.visual.material.baseColorTexture
    assert max(img.size) <= 8192 and min(img.size) >= 16
    assert 0.5 * BUDGET <= len(m.faces) <= BUDGET < rep["mesh"]["faces"]
    gt = trimesh.load(blob_small / "gt_mesh.ply", process=False)
    size = float(np.linalg.norm(gt.bounds[1] - gt.bounds[0]))
    pts, _ = trimesh.sample.sample_surface(m, 20000, seed=0)
    d = raycasting_scene(gt).compute_distance(o3d.core.Tensor(np.asarray(pts, np.float32))).numpy() / size
    assert np.percentile(d, 95) < 0.005 and d.max() < 0.015, (np.percentile(d, 95), d.max())  # 0.0021, 0.0042
    t = rep["texture"]
    assert t["faces"] == len(m.faces) and t["faces_in"] == rep["mesh"]["faces"]
    assert t["atlases"] == [list(img.size)] and t["views_used"] == 12
    assert t["file_size"] == (out / "model.glb").stat().st_size and t["cpu_seconds"] > 0
    assert set(t["files"]) == {"model.glb", "model.obj", "model.mtl", "model.png"}
    page = (out / "report.html").read_text()  # the summary lists the files
    # the picture "photo | model" (tests/report/test_textured_view.py checks it), the textured 3D view
    assert (out / "model_view.png").is_file() and t["view"]["file"] == "model_view.png"
    assert t["view"]["photo"] in page and 'id="prv-model-data"' in page and 'id="prv-show-mesh"' in page
    row = page.split("<td>textured model</td><td>", 1)[1].split("</td>", 1)[0]
    assert row.startswith("model.glb (") and "model.obj (" in row and f"atlas {img.size[0]}x{img.size[1]}" in row
    obj = _load(out / "model.obj")  # the OBJ: the same faces, its texture the lossless PNG
    assert len(obj.faces) == len(m.faces) and "map_Kd model.png" in (out / "model.mtl").read_text()
    assert np.array_equal(np.asarray(obj.visual.material.image.convert("RGB")),
                          np.asarray(_png(out / "model.png")))


def _in_reconstruction_frame(model, rep):
    """``model`` (read from model.glb, upright) moved back into the reconstruction's frame, the truth's, by the
    inverse of report.json's ``texture.frame.model_from_reconstruction``."""
    model.apply_transform(np.linalg.inv(np.array(rep["texture"]["frame"]["model_from_reconstruction"])))
    return model


def _png(path):
    from PIL import Image

    return Image.open(path).convert("RGB")


@pytest.mark.slow
def test_model_colours_match_the_photos_from_the_input_views(model_run, blob_small):
    """Rendered unlit from input views, the model shows the photos' colours: on the pixels both cover, a mean
    absolute error under 10 (of 255) per channel and a PSNR of at least 25 dB in every view checked."""
    out, _, rep = model_run
    m = _in_reconstruction_frame(_load(out / "model.glb"), rep)
    ds = Dataset.open(blob_small)
    r = Renderer(m, unlit=True)
    truth = Renderer(trimesh.load(blob_small / "gt_mesh.ply", process=False), seed=3)
    for view in ds.views[::3]:
        got = r.render(view)
        photo = ds.image(view).astype(np.float64)
        mask = got.mask & truth.render(view).mask
        assert mask.mean() > 0.1
        err = np.abs(got.rgb[mask].astype(np.float64) - photo[mask])
        psnr = 10 * np.log10(255.0 ** 2 / (err ** 2).mean())
        assert err.mean() < 10 and psnr >= 25, (view.name, err.mean(), psnr)  # 5.7-6.9 and 27.5-29.6 dB


@pytest.mark.slow
def test_cached_rerun_keeps_the_model_and_texture_off_removes_it(model_run, blob_small, tmp_path):
    """The same run again reuses every stage and keeps model.glb as it was; a texture setting reruns the model
    stage alone; --texture off writes no model (and takes away an earlier run's); --texture alone: on."""
    import shutil

    src, _, _ = model_run
    out = tmp_path / "out"
    shutil.copytree(src, out)
    glb = (out / "model.glb").read_bytes()
    flags = ["--model-faces", str(BUDGET), "--formats", "ply,glb,obj"]
    names, rep = _run(blob_small, out, *flags)
    assert names == [] and (out / "model.glb").read_bytes() == glb and rep["texture"]["faces"] <= BUDGET
    assert _run(blob_small, out, *flags, "--padding", "3")[0] == ["model"]
    names, rep = _run(blob_small, out, *flags, "--texture", "off")
    assert names == [] and rep["texture"] == {}
    assert not any((out / n).exists() for n in ("model.glb", "model.obj", "model.mtl", "model.png", "model_view.png"))
    assert 'id="prv-model-data"' not in (out / "report.html").read_text()
    assert not (out / ".stages" / "model.json").exists()
    names, rep = _run(blob_small, out, "--texture", "--model-faces", "5000", "--formats", "ply")
    assert names[-1] == "model" and (out / "model.glb").is_file() and not (out / "model.obj").exists()
    assert len(_load(out / "model.glb").faces) <= 5000


def test_texture_flag_and_api_values():
    """--texture on|off (alone: on); the Python API's former True / False mean on / off; anything else is
    refused naming the flag."""
    from photorecon.errors import BadArgumentError
    from photorecon.pipeline import ReconstructConfig

    assert ReconstructConfig().texture == "on"
    assert ReconstructConfig(texture=False).texture == "off" and ReconstructConfig(texture=True).texture == "on"
    with pytest.raises(BadArgumentError, match=r"--texture"):
        ReconstructConfig(texture="yes")


def test_compact_atlas_keeps_every_face_on_its_texels():
    """Charts scattered over a large atlas, repacked into a small one: the colour under each face's UV
    centroid is the same before and after, and the atlas holds little more than the charts' boxes."""
    from PIL import Image

    from photorecon.mesh.model import compact_atlas

    rng = np.random.default_rng(0)
    N, pad = 1024, 2
    atlas = rng.integers(0, 256, (N, N, 3), dtype=np.uint8)
    verts, faces, uv = [], [], []
    for k in range(40):  # 40 charts: two triangles each, a random 10-40 texel square somewhere in the atlas
        s = rng.integers(10, 40)
        x0, y0 = rng.integers(pad, N - s - pad, 2)
        corners = np.array([[x0, y0], [x0 + s, y0], [x0 + s, y0 + s], [x0, y0 + s]], float)
        base = len(verts)
        verts += [[k, 0, 0], [k + 1, 0, 0], [k + 1, 1, 0], [k, 1, 0]]
        uv += [[(x + 0.5) / N, 1 - (y + 0.5) / N] for x, y in corners]
        faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    mat = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(atlas))
    mesh = trimesh.Trimesh(np.array(verts, float), np.array(faces), process=False,
                           visual=trimesh.visual.TextureVisuals(uv=np.array(uv), material=mat))

    def centroid_colours(m, img):
        H, W = img.shape[:2]
        c = np.asarray(m.visual.uv)[np.asarray(m.faces)].mean(1)
        x = np.floor(c[:, 0] * W).astype(int)
        y = np.floor((1 - c[:, 1]) * H).astype(int)
        return img[y, x]

    new_mesh, new = compact_atlas(mesh, atlas, pad)
    assert new.shape[0] * new.shape[1] < 0.15 * N * N
    assert new.shape[0] <= new.shape[1] <= 1.5 * np.sqrt(new.shape[0] * new.shape[1])
    assert np.array_equal(centroid_colours(new_mesh, new), centroid_colours(mesh, atlas))
    uv2 = np.asarray(new_mesh.visual.uv)
    assert uv2.min() > 0 and uv2.max() < 1


def test_glb_embeds_the_atlas_as_jpeg(tmp_path):
    """model_glb: the JSON says image/jpeg, the image decodes to the atlas within JPEG's error, and the
    geometry reloads unchanged."""
    from PIL import Image

    from photorecon.mesh.model import MATERIAL_NAME, model_glb

    import cv2

    rng = np.random.default_rng(1)  # photo-like content: noise blurred over a few texels
    atlas = np.clip(cv2.GaussianBlur(rng.normal(128, 60, (64, 96, 3)), (0, 0), 2.0), 0, 255).astype(np.uint8)
    box = trimesh.creation.box()
    uv = rng.random((len(box.vertices), 2))
    mat = trimesh.visual.material.PBRMaterial(name=MATERIAL_NAME, baseColorTexture=Image.fromarray(atlas))
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv, material=mat))
    glb = model_glb(mesh, atlas)
    n = int.from_bytes(glb[12:16], "little")
    doc = json.loads(glb[20:20 + n])
    assert [i["mimeType"] for i in doc["images"]] == ["image/jpeg"]
    (tmp_path / "m.glb").write_bytes(glb)
    back = trimesh.load(tmp_path / "m.glb", process=False, force="mesh")
    assert np.allclose(back.vertices, box.vertices) and np.array_equal(back.faces, box.faces)
    assert np.allclose(back.visual.uv, uv, atol=1e-6)
    img = np.asarray(back.visual.material.baseColorTexture.convert("RGB"), np.float64)
    assert img.shape == atlas.shape and np.abs(img - atlas).mean() < 2 and np.abs(img - atlas).max() < 20
