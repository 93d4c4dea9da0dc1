"""The COLMAP text format's old import path: the same functions as ``io.cameras.colmap_text`` (and
``SparseModel``, from ``io.cameras.model``)."""
from .cameras.colmap_text import (_IMAGE_LINE, _cam_key, _data_lines, _image_key, read_colmap_text,  # noqa: F401
                                  write_colmap_text)
from .cameras.model import SparseModel  # noqa: F401
