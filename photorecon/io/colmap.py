"""The COLMAP binary format's old import path: the same functions as ``io.cameras.colmap_bin``."""
from .cameras.colmap_bin import read_colmap_binary, sparse_from_pycolmap, write_colmap_binary  # noqa: F401
