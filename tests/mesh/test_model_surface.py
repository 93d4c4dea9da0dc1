"""The textured model's surface (``--model-surface``, photorecon/mesh/surface.py and model.py): an object capture's
model is its closed surface, the faces its closing invented a glTF primitive of their own (material "invented"),
found on the closed companion and carried through the simplification; an open scene's model is the open mesh.
Checked on a rendered object on a table seen from a ring of cameras above (its underside never seen) and on a
truncated sphere whose cut is the truth."""
import json

import numpy as np
import pytest
import trimesh

from photorecon.mesh import boundary_loops, close_mesh, fill_loops
from photorecon.mesh.model import INVENTED_MATERIAL, MATERIAL_NAME

PLANE_Z = -0.4  # the table top
BUDGET = 1500  # below the closed companion's ~4,000 faces: the model is simplified


# --- the invented faces on a known surface ------------------------------------------------------------------
def _cut_sphere():
    """A unit sphere cut below z = -0.6 (an object's support side, open) with a small hole at its top filled as the
    cleaning fills one (marked ``filled``): the open, cleaned mesh."""
    s = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    c = np.asarray(s.triangles_center)
    keep = (c[:, 2] > -0.6) & (np.linalg.norm(c - [0, 0, 1], axis=1) > 0.12)
    obj = trimesh.Trimesh(s.vertices, np.asarray(s.faces)[keep], process=False)
    obj.remove_unreferenced_vertices()
    V = np.asarray(obj.vertices)
    top = [lp for lp in boundary_loops(obj.faces, len(V)) if V[lp, 2].mean() > 0.5]
    return fill_loops(obj, top)[0]


def test_invented_faces_are_the_closings_not_the_cleanings_and_survive_simplification():
    """On the closed companion, the invented faces are the support side's patch (below the cut, its area near the
    disc's), not the small hole the cleaning filled; simplified to a quarter, the faces carried as invented still
    lie at the cut and cover about the same area."""
    from photorecon.mesh.clean import simplify
    from photorecon.mesh.patch import filled_area
    from photorecon.mesh.surface import carry_marks, invented_faces

    obj = _cut_sphere()
    small = filled_area(obj)
    assert 0 < small < 0.1  # the cleaning's fill: a cap of radius 0.12
    closed = close_mesh(obj, floor=(np.array([0.0, 0.0, 1.0]), -0.7))
    assert closed.is_watertight
    inv = invented_faces(obj, closed, closed.face_attributes["filled"])
    area = np.asarray(closed.area_faces)
    z = np.asarray(closed.triangles_center)[:, 2]
    assert z[inv].max() < -0.55  # all at the support side
    assert area[inv].sum() == pytest.approx(np.pi * 0.8 ** 2, rel=0.25)  # the opening's disc, bulged
    assert area[inv].sum() == pytest.approx(filled_area(closed) - small, rel=1e-6)  # every other fill is the cleaning's
    simple = simplify(closed, len(closed.faces) // 4)
    carried = carry_marks(closed, inv, simple)
    a2, z2 = np.asarray(simple.area_faces), np.asarray(simple.triangles_center)[:, 2]
    assert a2[carried].sum() == pytest.approx(area[inv].sum(), rel=0.1)
    assert a2[carried & (z2 > -0.5)].sum() < 0.02 * a2[carried].sum()


def _textured_box(invented_rows=4):
    from PIL import Image

    rng = np.random.default_rng(2)
    box = trimesh.creation.box()
    atlas = rng.integers(0, 256, (32, 48, 3), dtype=np.uint8)
    mat = trimesh.visual.material.PBRMaterial(name=MATERIAL_NAME, baseColorTexture=Image.fromarray(atlas))
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=rng.random((len(box.vertices), 2)), material=mat))
    invented = np.zeros(len(box.faces), bool)
    invented[:invented_rows] = True
    return mesh, atlas, invented


def test_glb_and_obj_keep_the_invented_faces_apart(tmp_path):
    """model.glb: one glTF mesh of two primitives, the second with the material "invented", both on the one
    embedded atlas; trimesh reads two geometries whose faces rejoin into the closed box. model.obj: a second
    usemtl, model.mtl both materials on model.png."""
    from photorecon.layout import Layout
    from photorecon.mesh.model import Model, export_model

    mesh, atlas, invented = _textured_box()
    files = export_model(Model(mesh, atlas, {}, invented), Layout(tmp_path), ("glb", "obj"))
    assert set(files) == {"model.glb", "model.obj", "model.mtl", "model.png"}
    glb = (tmp_path / "model.glb").read_bytes()
    doc = json.loads(glb[20:20 + int.from_bytes(glb[12:16], "little")])
    assert len(doc["meshes"]) == 1 and len(doc["nodes"]) == 1 and len(doc["images"]) == 1
    prims = doc["meshes"][0]["primitives"]
    assert [doc["materials"][p["material"]]["name"] for p in prims] == [MATERIAL_NAME, INVENTED_MATERIAL]
    assert {m["pbrMetallicRoughness"]["baseColorTexture"]["index"] for m in doc["materials"]} == {0}
    scene = trimesh.load(tmp_path / "model.glb", process=False)
    parts = {g.visual.material.name: g for g in scene.geometry.values()}
    assert set(parts) == {MATERIAL_NAME, INVENTED_MATERIAL} and len(parts[INVENTED_MATERIAL].faces) == 4
    whole = trimesh.util.concatenate([trimesh.Trimesh(g.vertices, g.faces, process=False) for g in parts.values()])
    whole.merge_vertices()
    assert whole.is_watertight and len(whole.faces) == len(mesh.faces)
    text = (tmp_path / "model.obj").read_text()
    assert [ln for ln in text.splitlines() if ln.startswith("usemtl")] == [f"usemtl {MATERIAL_NAME}",
                                                                          f"usemtl {INVENTED_MATERIAL}"]
    mtl = (tmp_path / "model.mtl").read_text()
    assert mtl.count("newmtl") == 2 and mtl.count("map_Kd model.png") == 2
    obj = trimesh.load(tmp_path / "model.obj", process=False)
    assert sorted(len(g.faces) for g in obj.geometry.values()) == [4, 8]
    # the open model: one primitive, one usemtl, as before
    export_model(Model(mesh, atlas, {}, None), Layout(tmp_path / "open"), ("glb", "obj"))
    assert len(trimesh.load(tmp_path / "open" / "model.glb", process=False).geometry) == 1
    assert (tmp_path / "open" / "model.obj").read_text().count("usemtl") == 1


def test_report_row_says_the_surface():
    from photorecon.report.page import summary_facts

    base = {"files": {"model.glb": 1000}, "faces": 10, "atlases": [[8, 8]]}
    closed = summary_facts({"texture": {**base, "surface": "closed", "invented_area_share": 0.25,
                                        "watertight": True}})["textured model"]
    assert "closed surface, 25% of its area invented" in closed and '"invented"' in closed
    assert "; open surface" in summary_facts({"texture": {**base, "surface": "open"}})["textured model"]


def test_model_surface_setting_is_checked():
    from photorecon.errors import BadArgumentError
    from photorecon.mesh.model import ModelConfig

    assert ModelConfig().model_surface == "auto"
    with pytest.raises(BadArgumentError):
        ModelConfig(model_surface="watertight")


# --- reconstruct on an object on a table ------------------------------------------------------------------------
def _scene():
    """A cylinder with a ball sunk into its top (one object) on a table."""
    cyl = trimesh.creation.cylinder(radius=0.3, height=0.5, sections=48)
    cyl.apply_translation((-0.3, 0.0, PLANE_Z + 0.25))
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.22)
    ball.apply_translation((-0.3, 0.0, PLANE_Z + 0.5))
    table = trimesh.creation.box(extents=(2.4, 2.4, 0.02)).apply_translation((0, 0, PLANE_Z - 0.01))
    return trimesh.util.concatenate([cyl, ball, table])


def _reconstruct(data, out, *flags):
    from photorecon.cli import main

    assert main(["-q", "reconstruct", str(data / "images"), "-o", str(out), "--poses", str(data / "transforms.json"),
                 "--depth", str(data / "depth"), "--model-faces", str(BUDGET), *flags]) == 0
    rep = json.loads((out / "report.json").read_text())
    return [n for n, s in rep["stages"].items() if not s.get("cached")], rep


def _parts(path):
    scene = trimesh.load(path, process=False)
    return {g.visual.material.name: g for g in scene.geometry.values()}


@pytest.fixture(scope="module")
def object_runs(tmp_path_factory):
    """12 views from a ring 25 degrees above the table: ``reconstruct --scene object`` (the model closed by
    default), then the same folder with ``--model-surface open``, then the photos as an open scene."""
    from photorecon.synthetic import SynthConfig, synthesize

    tmp = tmp_path_factory.mktemp("surface")
    _scene().export(tmp / "scene.ply")
    synthesize(SynthConfig(mesh=str(tmp / "scene.ply"), rig="ring", views=12, width=160, height=120, radius=2.6,
                           elevation=25.0, points=500), tmp / "data")
    out = tmp / "out"
    runs = {"closed": _reconstruct(tmp / "data", out, "--scene", "object", "--formats", "ply,glb,obj")}
    runs["closed"] += (_parts(out / "model.glb"), (out / "report.html").read_text(), (out / "model.obj").read_text())
    runs["open"] = _reconstruct(tmp / "data", out, "--scene", "object", "--formats", "ply,glb,obj",
                                "--model-surface", "open") + (_parts(out / "model.glb"),)
    scene_out = tmp / "scene_open"
    runs["scene_open"] = _reconstruct(tmp / "data", scene_out, "--scene", "open") + (_parts(scene_out / "model.glb"),)
    return out, runs


def _back(mesh, rep):
    m = mesh.copy()
    m.apply_transform(np.linalg.inv(np.array(rep["texture"]["frame"]["model_from_reconstruction"])))
    return m


@pytest.mark.slow
def test_object_model_is_closed_with_its_unseen_underside_invented(object_runs):
    """The closed model: watertight as a whole (both primitives; measured: 1,500 faces), its invented part (19.6%
    of the area) at the base (100% of it in the lowest tenth of the model's height, 93% facing down) and all of
    the base's downward area; of the surface three or more photos see well, 1.6% is invented (the band the
    support cut took off the side wall, which the closing replaces); the invented faces coloured from around
    them (none black, smoother than the photo texture)."""
    from photorecon.io.dataset import Dataset
    from photorecon.render import Renderer

    out, runs = object_runs
    names, rep, parts, page, obj = runs["closed"]
    t = rep["texture"]
    assert rep["mesh"]["closed"]["watertight"] and t["surface"] == "closed" and t["watertight"]
    assert set(parts) == {MATERIAL_NAME, INVENTED_MATERIAL}
    seen, inv = parts[MATERIAL_NAME], parts[INVENTED_MATERIAL]
    assert len(seen.faces) + len(inv.faces) == t["faces"] <= BUDGET < t["faces_in"] == rep["mesh"]["closed"]["faces"]
    model = trimesh.util.concatenate([trimesh.Trimesh(g.vertices, g.faces, process=False) for g in (seen, inv)])
    model.merge_vertices()
    assert model.is_watertight and model.is_winding_consistent
    whole = trimesh.util.concatenate([trimesh.Trimesh(g.vertices, g.faces, process=False) for g in (seen, inv)])
    invented = np.r_[np.zeros(len(seen.faces), bool), np.ones(len(inv.faces), bool)]
    area = np.asarray(whole.area_faces)
    assert t["invented_area_share"] == pytest.approx(area[invented].sum() / area.sum(), abs=1e-3)
    assert 0.1 < t["invented_area_share"] < 0.3  # measured 0.196
    # the model frame: +Y up, the support plane at Y = 0
    y, ny = np.asarray(whole.triangles_center)[:, 1], np.asarray(whole.face_normals)[:, 1]
    lo, hi = y.min(), y.max()
    below = invented & ((y < lo + 0.1 * (hi - lo)) | (ny < -0.5))
    assert area[below].sum() >= 0.8 * area[invented].sum()  # measured: all of it
    base = (ny < -0.9) & (y < lo + 0.05 * (hi - lo))
    assert area[base].sum() > 0.05 and area[base & invented].sum() >= 0.95 * area[base].sum()  # measured: all
    # what the photos see well (3+ views, not at a grazing angle, unoccluded) is hardly ever invented
    rec = _back(whole, rep)
    pts, face = trimesh.sample.sample_surface(rec, 20000, seed=0)
    r = Renderer(trimesh.Trimesh(rec.vertices, rec.faces, process=False), plain=True)
    normals = np.asarray(rec.face_normals)[face]
    count = sum(r.visible(np.asarray(pts), v, normals, min_cos=0.5)[0].astype(int) for v in Dataset.open(out).views)
    well = count >= 3
    assert well.mean() > 0.6 and (well & invented[face]).sum() < 0.02 * well.sum()  # measured 0.79, 0.016
    # the invented faces' colours: diffused from the seen faces around them
    img = np.asarray(inv.visual.material.baseColorTexture.convert("RGB")).astype(float)

    def colours(m):
        uv = np.asarray(m.visual.uv)[np.asarray(m.faces)].mean(1)
        H, W = img.shape[:2]
        x = np.clip(np.round(uv[:, 0] * W - 0.5).astype(int), 0, W - 1)
        yy = np.clip(np.round((1 - uv[:, 1]) * H - 0.5).astype(int), 0, H - 1)
        return img[yy, x]

    ci, cs = colours(inv), colours(seen)
    assert ci.max(1).min() > 10 and np.all(ci.std(0) < cs.std(0))
    # report.html and model.obj say it
    row = page.split("<td>textured model</td><td>", 1)[1].split("</td>", 1)[0]
    assert "closed surface" in row and "of its area invented" in row
    assert f"usemtl {INVENTED_MATERIAL}" in obj


@pytest.mark.slow
def test_model_surface_open_gives_the_open_model_and_reruns_only_the_model(object_runs):
    """--model-surface open on the same folder: only the model stage runs again; one primitive, no invented
    material, open like mesh.ply, its area near mesh.ply's (the closed model's minus the invented part)."""
    out, runs = object_runs
    names, rep, parts = runs["open"]
    assert names == ["model"]
    t = rep["texture"]
    assert t["surface"] == "open" and "--model-surface open" in t["surface_reason"] and "invented_faces" not in t
    assert list(parts) == [MATERIAL_NAME] and t["faces_in"] == rep["mesh"]["faces"]
    m = parts[MATERIAL_NAME]
    assert not m.is_watertight and len(m.faces) <= BUDGET
    assert m.area == pytest.approx(runs["closed"][2][MATERIAL_NAME].area, rel=0.05)


@pytest.mark.slow
def test_open_scene_gets_the_open_model(object_runs):
    """The same photos as an open scene (--scene open, no closed companion): auto gives the open model."""
    _, runs = object_runs
    names, rep, parts = runs["scene_open"]
    assert rep["mesh"]["closed"] is None
    t = rep["texture"]
    assert t["surface"] == "open" and "no closed companion" in t["surface_reason"]
    assert list(parts) == [MATERIAL_NAME]
