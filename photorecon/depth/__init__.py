"""Per-image depth: images with their cameras and sparse points in, a z-depth map (with confidence, and normals
from PatchMatch) per view out, in ``OUT/depth``.

- ``config``: the stage's settings (``MVSConfig``) and per-view result (``DepthResult``).
- ``mvs``: multi-view stereo on the CPU, the orchestration (``run_mvs``: tasks per view, resume).
- ``select``: the source views of each view and its depth range; ``sweep``: plane-sweep stereo;
  ``patchmatch`` (+ ``_pm_kernels``, numba): PatchMatch stereo; ``planar``: the planar prior and texture tests.
- ``filter``: the multi-view geometric consistency filter.
- ``mono`` + ``align``: monocular ONNX depth models, aligned to the SfM points.
"""
