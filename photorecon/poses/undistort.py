"""SfM's last stage, undistortion (``undistort``): the model's images and masks to pinhole cameras; ``publish``
then writes the model as ``OUT/sparse/0`` and ``OUT/transforms.json``."""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from ..io.colmap import sparse_from_pycolmap
from ..io.colmap_text import SparseModel, read_colmap_text, write_colmap_text
from ..io.space import check_space
from ..layout import Layout
from ..progress import running
from ..stages import atomic_dir, replace_dir
from ._colmap import MB, _pycolmap
from .sfm_inputs import _undistort_masks


def undistort(model_dir: Path, images_dir: Path, out: Path, model_out: Path, mask_dir: Path | None = None) -> Path:
    """Undistort the model's images to pinhole cameras: ``out/images`` and the pinhole model (COLMAP text) in
    ``model_out``; and the masks of ``mask_dir`` (COLMAP's layout, NAME.EXT.png) into ``out/masks/NAME.png``
    (removed when there are none). Returns ``model_out``. ``publish`` then copies the model to
    ``out/sparse/0`` and ``out/transforms.json``, where metric scaling may rewrite it: the stage's own copy
    stays unscaled, so scaling never compounds and never invalidates this stage."""
    pycolmap = _pycolmap()
    layout = Layout(out)
    check_space(layout.images, 2 * sum(f.stat().st_size for f in images_dir.iterdir()) + MB)
    with tempfile.TemporaryDirectory(dir=out, prefix=".undistort") as und, running("SfM undistortion"):
        pycolmap.undistort_images(und, str(model_dir), str(images_dir))
        model = sparse_from_pycolmap(pycolmap.Reconstruction(f"{und}/sparse"))
        masks = Path(und) / "masks"
        masks.mkdir()
        n_masks = _undistort_masks(model_dir, model, mask_dir, masks) if mask_dir is not None else 0
        replace_dir(f"{und}/images", layout.images)
        if n_masks:
            replace_dir(masks, layout.masks)
        else:
            shutil.rmtree(layout.masks, ignore_errors=True)
    with atomic_dir(model_out) as tmp:
        write_colmap_text(model, tmp)
    return model_out


def publish(model_dir: Path, out: Path) -> SparseModel:
    """The undistorted model of ``model_dir`` (COLMAP text) as ``out/sparse/0`` and ``out/transforms.json``."""
    from ..io.nerf import write_transforms

    model = read_colmap_text(model_dir)
    layout = Layout(out)
    with atomic_dir(layout.sparse) as tmp:
        write_colmap_text(model, tmp)
    write_transforms(model.views, layout.transforms, world="none")
    return model
