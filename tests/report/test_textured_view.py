"""report.html with the textured model: the 3D view's payload (UVs and the atlas as JPEG, in the cameras' frame)
when OUT/model.glb exists and not otherwise; OUT/model_view.png, a photo beside the model rendered from its camera;
and in headless Chromium, the textured view drawn in the photos' colours with a toggle to the vertex-coloured mesh.

The result folder: blob_small's 12 photos and cameras, its true surface as mesh.ply (in green vertex colours, so
the two views of the page tell apart) and a textured model made from them by the model stage (``model_output``,
4,000 faces, upright in its own frame) and its picture (``model_view_output``), as ``reconstruct`` makes them."""
from __future__ import annotations

import base64
import json
import re
import shutil
import time
import zlib

import cv2
import numpy as np
import pytest
import trimesh

from photorecon.io.dataset import Dataset
from photorecon.mesh import export

from test_viewer import BACKGROUND, Browser, wait_for

MODEL_FACES = 4000


def _green(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    v = np.asarray(mesh.vertices)
    t = (v[:, 2] - v[:, 2].min()) / max(np.ptp(v[:, 2]), 1e-9)
    rgb = np.c_[30 + 40 * t, 170 + 60 * t, 30 + 40 * t].astype(np.uint8)
    return trimesh.Trimesh(v, mesh.faces, process=False, vertex_colors=np.c_[rgb, np.full(len(v), 255, np.uint8)])


def _report(texture: dict) -> dict:
    return {"photorecon": "test", "input": "x", "stages": {}, "mesh": {}, "texture": texture, "warnings": [],
            "parameters": {}}


@pytest.fixture(scope="module")
def textured(blob_small, tmp_path_factory):
    """(OUT, report.json's texture section) of a result folder with model.glb and model_view.png."""
    from photorecon.mesh.model import ModelConfig, model_output
    from photorecon.report import model_view_output, write_html_report

    out = tmp_path_factory.mktemp("textured") / "out"
    out.mkdir()
    shutil.copytree(blob_small / "images", out / "images")
    shutil.copy(blob_small / "transforms.json", out / "transforms.json")
    export(_green(trimesh.load(blob_small / "gt_mesh.ply", process=False)), out / "mesh.ply")
    info = model_output(out, ModelConfig(model_faces=MODEL_FACES))
    info["view"] = model_view_output(out, info)
    write_html_report(out, _report(info))
    return out, info


def _in_reconstruction_frame(out, info) -> trimesh.Trimesh:
    m = trimesh.load(out / "model.glb", process=False, force="mesh")
    m.apply_transform(np.linalg.inv(np.array(info["frame"]["model_from_reconstruction"])))
    return m


def _script(page: str, ident: str) -> str:
    return re.search(rf'<script type="application/[a-z-]+" id="{ident}">([^<]*)</script>', page).group(1)


def test_page_carries_the_textured_model_in_the_cameras_frame(textured, blob_small):
    """With model.glb the page holds its faces, positions (back in mesh.ply's and the cameras' frame: on the true
    surface, although model.glb stands upright in a frame of its own) and UVs (image order), its atlas as a JPEG
    of at most 2048 a side, a toggle and the picture; the textured part's size is in the payload's meta."""
    from photorecon.report import PAGE_ATLAS_SIDE

    out, info = textured
    page = (out / "report.html").read_text()
    meta = json.loads(_script(page, "prv-meta").replace("\\u003c", "<").replace("\\u003e", ">").replace("\\u0026", "&"))
    mm = meta["model"]
    model = _in_reconstruction_frame(out, info)
    assert not np.allclose(info["frame"]["model_from_reconstruction"], np.eye(4), atol=1e-3)  # a frame of its own
    assert (mm["faces"], mm["vertices"]) == (len(model.faces), len(model.vertices)) and mm["faces"] <= MODEL_FACES
    assert mm["groups"] == [{"start": 0, "count": mm["faces"], "texture": 0}]
    buf = zlib.decompress(base64.b64decode(_script(page, "prv-model-data")))
    nf, nv = mm["faces"], mm["vertices"]
    assert len(buf) == nf * 12 + nv * 10
    faces = np.frombuffer(buf, "<u4", nf * 3).reshape(-1, 3)
    pos = np.asarray(mm["offset"]) + np.frombuffer(buf, "<u2", nv * 3, nf * 12).reshape(-1, 3) * mm["step"]
    uv = np.frombuffer(buf, "<u2", nv * 2, nf * 12 + nv * 6).reshape(-1, 2) / 65535.0
    assert np.array_equal(faces, model.faces)
    assert np.abs(pos - model.vertices).max() <= 0.51 * mm["step"]
    gt = trimesh.load(blob_small / "gt_mesh.ply", process=False)
    import open3d as o3d

    from photorecon.mesh.convert import raycasting_scene

    dist = raycasting_scene(gt).compute_distance(o3d.core.Tensor(pos.astype(np.float32))).numpy()
    assert np.percentile(dist, 95) < 0.01 * np.linalg.norm(np.ptp(gt.vertices, axis=0))
    expect = np.c_[model.visual.uv[:, 0], 1 - model.visual.uv[:, 1]]  # image order: v down
    assert np.abs(uv - expect).max() < 1e-4
    jpeg = base64.b64decode(_script(page, "prv-model-tex-0"))
    atlas = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
    full = np.asarray(model.visual.material.baseColorTexture.convert("RGB"))
    assert atlas.shape == full.shape and max(atlas.shape[:2]) <= PAGE_ATLAS_SIDE  # a small atlas stays whole
    chart = full.max(2) > 0  # the atlas's texels, within JPEG's error (a texel off: several times that)
    err = np.abs(atlas[chart].astype(int) - full[chart]).mean()
    off = np.abs(np.roll(atlas, 1, axis=1)[chart].astype(int) - full[chart]).mean()
    assert err < 5 and err < 0.3 * off, (err, off)
    assert mm["textures"][0]["width"] == atlas.shape[1] and mm["bytes"] == len(_script(page, "prv-model-data")) + len(
        _script(page, "prv-model-tex-0"))
    assert 'id="prv-show-model"' in page and 'id="prv-show-mesh"' in page
    assert "<h2>Photo and model</h2>" in page and info["view"]["photo"] in page and "held-out" in page


def test_page_without_a_model_is_the_mesh_view_alone(textured, tmp_path):
    """Without model.glb (--texture off, an older folder) the page holds no textured part, no toggle and no
    picture; a model over the face budget is left out with a line saying so."""
    from photorecon.report import write_html_report
    from photorecon.report.textured import load_model, model_payload

    src, info = textured
    out = tmp_path / "out"
    shutil.copytree(src, out, ignore=shutil.ignore_patterns("model.glb", "model_view.png", "report.html"))
    for texture in ({}, info):  # --texture off; a folder whose model.glb has gone
        page = write_html_report(out, _report(texture)).read_text()
        assert 'id="prv-data"' in page and '"colored":true' in page
        assert 'id="prv-model-' not in page and 'id="prv-show-' not in page and "Photo and model" not in page
        assert "model" not in json.loads(_script(page, "prv-meta"))
    big = model_payload(load_model(src, info), max_faces=100)
    assert set(big) == {"meta"} and "over the page's 100" in big["meta"]["skipped"]


def _photo_and_render(out, info):
    pic = cv2.imread(str(out / "model_view.png"), cv2.IMREAD_COLOR)[:, :, ::-1]
    ds = Dataset.open(out)
    view = next(v for v in ds.views if v.name == info["view"]["view"])
    return pic, ds, view


def test_model_view_png_is_the_photo_beside_the_model_from_its_camera(textured):
    """model_view.png: the photo (at its own size here, under 720 px) and the model rendered from its camera,
    each with the photo's aspect; over the pixels the model covers (found by ray casting it here) the model half
    is close to the photo: under half the mean absolute difference of a flat grey image, and under half that of
    the model seen from another of the cameras."""
    from photorecon.render import Renderer
    from photorecon.report.model_view import GAP

    out, info = textured
    pic, ds, view = _photo_and_render(out, info)
    photo = ds.image(view)
    H, W = photo.shape[:2]
    assert pic.shape == (H, 2 * W + GAP, 3)
    left, right = pic[:, :W], pic[:, W + GAP:]
    assert np.array_equal(left, photo)
    model = _in_reconstruction_frame(out, info)
    covered = Renderer(model, unlit=True).render(view).mask
    assert covered.mean() > 0.2
    err = np.abs(right[covered].astype(float) - photo[covered]).mean()
    grey = np.abs(128.0 - photo[covered]).mean()
    other = next(v for v in ds.views if v.name != view.name)
    wrong = np.abs(Renderer(model, unlit=True).render(other).rgb[covered].astype(float) - photo[covered]).mean()
    assert err < 0.5 * grey and err < 0.5 * wrong, (err, grey, wrong)
    assert np.all(right[~covered] >= 250)  # white where the model does not reach
    assert abs(info["view"]["mean_abs_difference"] - err) < 2
    assert info["view"]["photo"] == (view.image_file or view.name)


def test_the_photo_is_the_camera_that_sees_most_of_the_model(textured):
    """The chosen camera sees at least as much of the model (share of the model's faces drawn in its render) as
    every other camera, within 3 points: another measure than the one that chose it."""
    from photorecon.render import Renderer

    out, info = textured
    model = _in_reconstruction_frame(out, info)
    r = Renderer(model, plain=True)
    ds = Dataset.open(out)
    area = np.asarray(model.area_faces)
    seen = {v.name: area[np.unique(r.render(v).triangle)[1:]].sum() / area.sum() for v in ds.views}
    assert seen[info["view"]["view"]] >= max(seen.values()) - 0.03, seen


@pytest.mark.browser
def test_textured_view_draws_the_photos_colours_and_toggles_to_the_mesh(textured, tmp_path):
    """In headless Chromium: the view opens on the textured model (many colours, not one flat colour, and not
    the mesh's green), and the toggle switches to the vertex-coloured mesh (green), drawn where the model was
    (the model moved back into the mesh's frame), and back. The picture "photo | model" shrinks to a narrow
    window's width."""
    out, _ = textured
    W, H = 640, 480
    b = Browser(tmp_path / "profile", W, H)

    def shot():
        time.sleep(0.5)  # a frame or two after the click
        img = b.screenshot()
        drawn = np.abs(img.astype(int) - BACKGROUND).max(2) > 12
        drawn[:60] = False  # the button bar
        return img, drawn

    try:
        b.open((out / "report.html").as_uri() + "#viewer")
        state = wait_for(lambda: b.eval("document.getElementById('prv-canvas').dataset.state") or None, 30,
                         "the viewer")
        assert state == "drawn", b.eval("document.getElementById('prv-msg').textContent")
        assert b.eval("document.getElementById('prv-canvas').dataset.shown") == "model"
        model_img, model_px = shot()
        b.eval("document.getElementById('prv-show-mesh').click()")
        assert wait_for(lambda: b.eval("document.getElementById('prv-canvas').dataset.shown") == "mesh" or None, 5,
                        "the mesh")
        assert b.eval("document.getElementById('prv-show-mesh').getAttribute('aria-pressed')") == "true"
        mesh_img, mesh_px = shot()
        b.eval("document.getElementById('prv-show-model').click()")
        assert wait_for(lambda: b.eval("document.getElementById('prv-canvas').dataset.shown") == "model" or None, 5,
                        "the model again")
        # the picture "photo | model" (328 px wide here) within a 300-pixel window, its aspect kept
        b.call("Emulation.setDeviceMetricsOverride", width=300, height=480, deviceScaleFactor=1, mobile=False)
        b.open((out / "report.html").as_uri())
        probe = ("(() => { const i = document.querySelector('figure.model-view img'); if (!i || !i.complete || "
                 "document.readyState !== 'complete' || innerWidth !== 300) return null; const r = "
                 "i.getBoundingClientRect(); return [r.right, r.width, r.height, i.naturalWidth, i.naturalHeight, "
                 "document.documentElement.scrollWidth]; })()")
        right, w, h, nw, nh, scroll = wait_for(lambda: b.eval(probe), 20, "the picture")
    finally:
        b.close()
    cv2.imwrite(str(tmp_path / "model.png"), model_img[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "mesh.png"), mesh_img[:, :, ::-1])
    assert model_px.mean() > 0.1 and mesh_px.mean() > 0.1
    assert (model_px & mesh_px).sum() > 0.9 * (model_px | mesh_px).sum()  # one frame: the same silhouette
    px = model_img[model_px].astype(float)
    assert len(np.unique(model_img[model_px], axis=0)) > 1000 and px.std(0).min() > 15  # the photos' texture
    greenness = lambda p: (p[:, 1] - (p[:, 0] + p[:, 2]) / 2).mean()
    mesh = mesh_img[mesh_px].astype(float)
    assert greenness(mesh) > 60 and greenness(px) < 30, (greenness(mesh), greenness(px))
    assert nw > 300 and right <= 300 and scroll <= 300 and abs(h / w - nh / nw) < 0.02, (right, w, h, nw, nh, scroll)


def _with_report_json(textured, tmp_path):
    """A copy of the textured result folder with its report.json (as ``reconstruct`` writes it)."""
    import json

    out, info = textured
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    (copy / "report.json").write_text(json.dumps(_report(info)))
    return copy, info


def test_live_view_places_the_textured_model_in_the_cameras_frame(textured, tmp_path):
    """``photorecon view``'s node for model.glb (scale, rotation, position from report.json's frame) puts the
    model's points where the report's own reading of it has them: on mesh.ply's surface, in the cameras' frame."""
    from scipy.spatial.transform import Rotation

    from photorecon.report.live import model_placement
    from photorecon.report.result import result_model

    out, info = _with_report_json(textured, tmp_path)
    glb, placement = result_model(out)
    assert glb == (out / "model.glb").read_bytes()
    for k, v in model_placement(info).items():
        assert np.allclose(placement[k], v)
    raw = trimesh.load(out / "model.glb", process=False, force="mesh")
    R = Rotation.from_quat(placement["wxyz"], scalar_first=True).as_matrix()
    moved = placement["scale"] * np.asarray(raw.vertices) @ R.T + placement["position"]
    assert np.allclose(moved, _in_reconstruction_frame(out, info).vertices, atol=1e-5)
    assert result_model(out / "mesh.ply") is None  # a mesh file: no model


def test_live_view_serves_the_textured_model_with_a_switch_to_the_mesh(textured, tmp_path):
    """The live viewer of a result with model.glb sends the model's GLB besides the mesh; a result
    without one, or whose report has no readable frame (a warning; the mesh is shown), sends the mesh only."""
    import json

    from test_view_security import receives_all
    from photorecon.report import load_result, start_viewer_server, stop_viewer_server
    from photorecon.report.result import result_model

    out, info = _with_report_json(textured, tmp_path)
    mesh, cams, images = load_result(out)
    sizes = {}
    for name, model in (("model", result_model(out)), ("mesh", None)):
        srv = start_viewer_server(mesh, cams, {}, "127.0.0.1", 0, lighting="plain", model=model)
        try:
            port = srv.get_port()
            sizes[name] = receives_all(port, f"http://127.0.0.1:{port}")
        finally:
            stop_viewer_server(srv)
    # the GLB goes over the WebSocket compressed (0.87 of its size measured)
    assert sizes["model"] >= sizes["mesh"] + 0.5 * (out / "model.glb").stat().st_size, sizes
    bad = tmp_path / "bad"
    shutil.copytree(out, bad)  # report.json's frame a mirror
    report = json.loads((bad / "report.json").read_text())
    report["texture"]["frame"]["model_from_reconstruction"] = np.diag([1.0, 1.0, -1.0, 1.0]).tolist()  # a mirror
    (bad / "report.json").write_text(json.dumps(report))
    assert result_model(bad) is None
