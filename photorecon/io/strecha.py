"""Strecha cameras' old import path: the same functions as ``io.cameras.strecha``."""
from .cameras.strecha import CAMERA_SUFFIX, read_strecha, read_strecha_camera  # noqa: F401
