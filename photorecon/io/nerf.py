"""transforms.json and NeRF Blender-synthetic cameras' old import path: the same functions as
``io.cameras.transforms`` and ``io.cameras.blender``."""
from .cameras.blender import read_blender, write_blender  # noqa: F401
from .cameras.common import image_size  # noqa: F401
from .cameras.transforms import (BLENDER_SPLITS, FISHEYE_MODELS, PERSPECTIVE_MODELS, _frame_image,  # noqa: F401
                                 _intr_dict, _lens, read_transforms, write_transforms)
