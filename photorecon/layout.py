"""The one object that knows every path of a dataset / output folder.

A dataset (written by ``synth``, read by ``mvs``, ``depth``, ``fuse``) and the output of ``reconstruct`` share
one layout; ``reconstruct`` adds the mesh, its previews and reports, and its working folders::

    ROOT/images/NAME.png        images (undistorted, for an output)
    ROOT/depth/NAME.npy         float32 z-depth (+ NAME.conf.npy, NAME.normal.npy, NAME.png preview)
    ROOT/masks/NAME.png         255 = use the pixel
    ROOT/sparse/0/              COLMAP text model
    ROOT/transforms.json        the same cameras, NeRF convention
    ROOT/gt_mesh.ply            ground truth (synthetic datasets)
    ROOT/scene.json             synthetic scene settings and normalisation
    ROOT/mesh.{ply,obj,glb}     the fused, cleaned mesh
    ROOT/mesh_closed.{ply,...}  an object capture's watertight companion of it
    ROOT/model.glb              the mesh simplified and textured from the photos (+ model.obj, .mtl, .png)
    ROOT/model_view.png         one photo beside the textured model rendered from its camera
    ROOT/preview.png            the mesh from four viewpoints
    ROOT/report.json, report.html
    ROOT/colmap/                SfM working files (with its own images/, masks/, sparse/, .stages/)
    ROOT/.stages/               the pipeline's stage markers (the hashes of their outputs); .stages/last/: the
                                last complete result, set aside while a run replaces it

Paths only: a ``Layout`` creates, reads and checks nothing. ``COMMAND_WRITES``: for each command that writes a
folder, the names it writes, replaces or deletes directly in it (what ``--overwrite`` must not find in a folder that
command did not write; ``None``: names that depend on the views, the whole folder counts as the command's).
``WRITTEN_NAMES``: those of ``reconstruct``, whose output holds all the others.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

WRITTEN_NAMES = ("images", "depth", "masks", "sparse", "colmap", "textured", "transforms.json", "gt_mesh.ply",
                 "scene.json", "mesh.ply", "mesh.obj", "mesh.glb", "mesh_closed.ply", "mesh_closed.obj",
                 "model.glb", "model.obj", "model.mtl", "model.png", "model_view.png",
                 "mesh_closed.glb", "preview.png", "preview_mesh.ply", "first_look", "report.json",
                 "report.html", "mvs_report.json", "mono_report.json", ".stages", ".work", ".mvs_work")

COMMAND_WRITES: dict[str, tuple[str, ...] | None] = {
    "reconstruct": WRITTEN_NAMES,
    "synth": ("images", "depth", "masks", "sparse", "transforms.json", "gt_mesh.ply", "scene.json"),
    "sfm": ("images", "masks", "sparse", "transforms.json", "colmap"),
    "fuse": ("mesh.ply", "mesh.obj", "mesh.glb", "mesh_closed.ply", "mesh_closed.obj", "mesh_closed.glb", "preview.png",
             ".work"),
    "texture": ("mesh.obj", "mesh.mtl", "texture.png", "mesh.glb", "preview.png"),
    "convert": ("cameras.txt", "images.txt", "points3D.txt", "cameras.bin", "images.bin", "points3D.bin", "rigs.bin",
                "frames.bin"),
    "mvs": None,  # NAME.npy, NAME.conf.npy, NAME.normal.npy, NAME.png per view, .mvs_work
    "depth": None,  # NAME.npy, NAME.png per view, .mono_work
    "demo": ("scene", "reconstruction", "demo.json", "tsdf.ply", "watertight.ply", "side_by_side.png"),
}
# working folders whose content is complete piece by piece (task outputs, stage markers): kept after a failed run,
# for the next run to reuse
RESUMABLE_NAMES = (".stages", ".work", ".mvs_work", ".mono_work", "colmap")
# a depth map's resolution by its pyramid level below its view's working resolution, as the depth stage's
# mvs_report.json names it per view ("resolution") and the fusion reads it back
DEPTH_RESOLUTIONS = {0: "full", 1: "half", 2: "quarter"}


@dataclass(frozen=True)
class Layout:
    root: Path

    def __init__(self, root: str | Path):
        object.__setattr__(self, "root", Path(root))

    # --- folders ------------------------------------------------------------------------------------------
    @property
    def images(self) -> Path:
        return self.root / "images"

    @property
    def depth(self) -> Path:
        return self.root / "depth"

    @property
    def masks(self) -> Path:
        return self.root / "masks"

    @property
    def sparse(self) -> Path:
        """The COLMAP model folder, ``sparse/0``."""
        return self.root / "sparse" / "0"

    @property
    def colmap(self) -> Path:
        """SfM working folder (database, distorted model, ingested images); reused on a re-run."""
        return self.root / "colmap"

    @property
    def stages(self) -> Path:
        return self.root / ".stages"

    # --- files --------------------------------------------------------------------------------------------
    @property
    def transforms(self) -> Path:
        return self.root / "transforms.json"

    @property
    def gt_mesh(self) -> Path:
        return self.root / "gt_mesh.ply"

    @property
    def scene(self) -> Path:
        return self.root / "scene.json"

    @property
    def preview(self) -> Path:
        return self.root / "preview.png"

    @property
    def viewer_mesh(self) -> Path:
        """The mesh decimated for report.html's and ``photorecon view``'s 3D view."""
        return self.root / "preview_mesh.ply"

    @property
    def work(self) -> Path:
        """Intermediate task outputs (depth and fusion tasks), kept across an interruption for a re-run."""
        return self.root / ".work"

    @property
    def first_look(self) -> Path:
        """A large capture's first look while its depth maps are computed: mesh.ply and preview.png fused from the
        coarse depth maps; removed when the run's result is complete."""
        return self.root / "first_look"

    @property
    def textured(self) -> Path:
        """``photorecon texture``'s default folder: mesh.obj + mesh.mtl + texture.png, mesh.glb."""
        return self.root / "textured"

    @property
    def report_json(self) -> Path:
        return self.root / "report.json"

    @property
    def report_html(self) -> Path:
        return self.root / "report.html"

    def mesh(self, fmt: str = "ply") -> Path:
        """``mesh.ply``, ``mesh.obj`` or ``mesh.glb``."""
        return self.root / f"mesh.{fmt}"

    def model(self, ext: str = "glb") -> Path:
        """``model.glb``: the textured model (simplified mesh, texture from the photos); ``model.obj``,
        ``model.mtl`` and ``model.png`` (its texture) with ``--formats`` including obj."""
        return self.root / f"model.{ext}"

    @property
    def model_view(self) -> Path:
        """``model_view.png``: the photo that sees most of the textured model beside the model rendered from its
        camera (report.html shows it)."""
        return self.root / "model_view.png"

    def mesh_closed(self, fmt: str = "ply") -> Path:
        """``mesh_closed.ply`` (``.obj``, ``.glb``): an object capture's watertight companion of the mesh."""
        return self.root / f"mesh_closed.{fmt}"

    def depth_map(self, name: str) -> Path:
        """``depth/NAME.npy`` (z-depth of view ``name``)."""
        return self.depth / f"{name}.npy"

    def image(self, file: str) -> Path:
        """``images/FILE`` (FILE with its extension, e.g. a view's ``image_file``)."""
        return self.images / file

    def mask(self, name: str) -> Path:
        """``masks/NAME.png``."""
        return self.masks / f"{name}.png"
