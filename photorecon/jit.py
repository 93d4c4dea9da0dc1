"""numba, as photorecon's compiled kernels use it: every module with a kernel imports ``njit`` and ``prange``
from here, so the settings below hold whichever kernel runs first.

numba looks for Intel TBB first when a ``parallel=True`` kernel first runs; it finds the older TBB that
Open3D's wheel loads, says in a warning that it will not use it, and runs on its OpenMP or workqueue threads
instead. That note means nothing to a user and breaks ``--quiet``, so it is filtered out (that one message
only)."""
import warnings

warnings.filterwarnings("ignore", message=".*The TBB threading layer requires")

from numba import njit, prange  # noqa: E402

__all__ = ["njit", "prange"]
