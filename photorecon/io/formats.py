"""IDR / NeuS and LLFF cameras' old import path: the same functions as ``io.cameras.neus`` and
``io.cameras.llff``."""
from .cameras.common import sorted_images  # noqa: F401
from .cameras.llff import LLFF_FROM_GL, llff_bounds, read_llff, write_llff  # noqa: F401
from .cameras.neus import (NEUS_FILES, NEUS_IMAGES, NEUS_MASKS, NEUS_WORLDS, decompose_projection,  # noqa: F401
                           neus_scale_mat, read_neus, write_neus)
