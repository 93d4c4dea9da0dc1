"""numba, as photorecon's compiled kernels use it: every module with a kernel imports ``njit`` and ``prange``
from here, so the settings below hold whichever kernel runs first.

numba looks for Intel TBB first when a ``parallel=True`` kernel first runs; it finds the older TBB that
Open3D's wheel loads, says in a warning that it will not use it, and runs on its OpenMP or workqueue threads
instead. That note means nothing to a user and breaks ``--quiet``, so it is filtered out (that one message
only).

``PHOTORECON_FASTMATH=0`` (also ``off``, ``false``, ``no``) compiles every kernel without ``fastmath`` (strict
IEEE arithmetic: no reassociation, no fused multiply-add contraction), to check that a result does not hinge on
how the compiler rounds (``tools/bench_stability.py``). numba's cache does not tell kernels compiled with and
without fastmath apart, so with it off the kernels are cached in a folder of their own: ``NUMBA_CACHE_DIR`` (or
the temporary folder) ``/photorecon-nofastmath``; the cache of the default setting is never read or written."""
import os
import tempfile
import warnings

warnings.filterwarnings("ignore", message=".*The TBB threading layer requires")

import numba  # noqa: E402
from numba import njit as _numba_njit, prange  # noqa: E402

__all__ = ["njit", "prange", "FASTMATH", "NOFASTMATH_CACHE"]

FASTMATH = os.environ.get("PHOTORECON_FASTMATH", "1").strip().lower() not in ("0", "off", "false", "no")
NOFASTMATH_CACHE = os.path.join(os.environ.get("NUMBA_CACHE_DIR") or tempfile.gettempdir(), "photorecon-nofastmath")

if not FASTMATH:
    # read when each kernel is decorated (its cache's folder): set before any kernel module is imported
    numba.config.CACHE_DIR = NOFASTMATH_CACHE


def njit(*args, **kwargs):
    """numba's ``njit``; with ``PHOTORECON_FASTMATH=0``, ``fastmath`` off whatever the kernel asks for."""
    if not FASTMATH:
        kwargs["fastmath"] = False
    if len(args) == 1 and callable(args[0]):  # bare @njit
        return _numba_njit(**kwargs)(args[0])
    return _numba_njit(*args, **kwargs)
